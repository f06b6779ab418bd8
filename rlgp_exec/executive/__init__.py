"""The executive: sense-plan-act with monitors, faults, replanning and recordings; the daemon."""

from rlgp_exec.executive.executive import Executive, TaskResult, TaskStatus
from rlgp_exec.executive.monitors import Reaction, Tolerances, Violation
from rlgp_exec.executive.recorder import Recorder, Recording, read_recording
from rlgp_exec.executive.states import ExecState, StateMachine, Transition
from rlgp_exec.executive.world import ObjectSource, ScenePoses, SimMocap, ZenohMocap, update_scene

__all__ = [
    "ExecState",
    "Executive",
    "ObjectSource",
    "Reaction",
    "Recorder",
    "Recording",
    "ScenePoses",
    "SimMocap",
    "StateMachine",
    "TaskResult",
    "TaskStatus",
    "Tolerances",
    "Transition",
    "Violation",
    "ZenohMocap",
    "read_recording",
    "update_scene",
]

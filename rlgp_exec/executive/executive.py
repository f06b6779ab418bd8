"""The executive: SENSE -> PLAN -> TIME -> ACT -> VERIFY for one task, as an explicit state machine,
with replanning from where the robot is after a failed grasp, a moved object or a stopped segment.

``Executive.run(goal)`` never raises for an expected failure: the ``TaskResult`` says what happened
(``TaskStatus``) and why. Real errors in the inputs (an invalid goal) are results too, so a daemon
keeps serving. Every run is recorded when a ``Recorder`` is given.
"""

from __future__ import annotations

import enum
import logging
import time
from collections.abc import Callable, Sequence
from dataclasses import dataclass, field, replace
from typing import NamedTuple

import numpy as np

from rlgp_exec.errors import RlgpError, SceneError
from rlgp_exec.executive.act import Actor, ActOutcome, ActStatus, Signals, gripper_action
from rlgp_exec.executive.monitors import Reaction, Tolerances, Violation
from rlgp_exec.executive.recorder import RecordSink
from rlgp_exec.executive.recovery import release_knob
from rlgp_exec.executive.states import LATCHED, ExecState, IllegalTransitionError, StateMachine, Transition
from rlgp_exec.executive.world import ObjectSource, drawer_openings, update_scene
from rlgp_exec.hal.interface import RobotInterface
from rlgp_exec.hal.types import Lifecycle, RobotState
from rlgp_exec.planning import registry
from rlgp_exec.planning.drawers import drawer_views
from rlgp_exec.planning.limits import DEFAULT_LIMITS, PlanLimits
from rlgp_exec.planning.memory import PlannerMemory
from rlgp_exec.planning.plan import Plan
from rlgp_exec.planning.validate import Phase, goal_holds
from rlgp_exec.robot.model import FloatArray
from rlgp_exec.scene import Scene, scene_to_dict
from rlgp_exec.scene.literals import parse_goal
from rlgp_exec.scene.types import Goal, Literal
from rlgp_exec.timing import TimingError, Trajectory, to_trajectory

__all__ = ["Executive", "TaskResult", "TaskStatus"]

log = logging.getLogger(__name__)
S = ExecState
PLAN_TRIES = 2  # planner calls (different seeds) per planning attempt before giving up
FRESH_POSES_S = 0.5  # [s] sensing waits this long for object poses as new as the robot state
ROBOT_WAIT_S = 10.0  # [s] a task starting without fresh robot state waits this long (a robot reconnecting)


class TaskStatus(enum.Enum):
    SUCCEEDED = "succeeded"  # goal verified in the sensed world (or, without sensing, executed as planned)
    INVALID_GOAL = "invalid_goal"
    INFEASIBLE = "infeasible"  # the planner proved there is no plan (an unreachable object, a conflict)
    FAILED = "failed"  # no plan found in time, replans exhausted, timing failed, goal not met after execution
    CANCELLED = "cancelled"
    ESTOPPED = "estopped"
    FAULT = "fault"


@dataclass(frozen=True)
class TaskResult:
    status: TaskStatus
    detail: str
    goal: tuple[str, ...]
    actions: tuple[str, ...] = ()  # the last plan's
    plans: int = 0
    replans: int = 0
    planning_time_s: float = 0.0
    execution_time_s: float = 0.0
    time_to_first_motion_s: float | None = None
    base_distance_m: float = 0.0
    verified: bool = False  # the goal was checked against sensed object poses
    #: the actions carried out, over every plan in order (a replan's too): an action counts once the phase that
    #: ends at its keyframe has run, with its gripper event
    executed: tuple[str, ...] = ()
    recording_error: str | None = None  # the run's recording stopped early (a full disk, ...): why

    @property
    def ok(self) -> bool:
        return self.status is TaskStatus.SUCCEEDED

    def as_dict(self) -> dict[str, object]:
        return {
            "status": self.status.value,
            "detail": self.detail,
            "goal": list(self.goal),
            "actions": list(self.actions),
            "plans": self.plans,
            "replans": self.replans,
            "planning_time_s": self.planning_time_s,
            "execution_time_s": self.execution_time_s,
            "time_to_first_motion_s": self.time_to_first_motion_s,
            "base_distance_m": self.base_distance_m,
            "verified": self.verified,
            "executed": list(self.executed),
            "recording_error": self.recording_error,
        }


class Executive:
    """One robot (a HAL backend, configured here), one world model, one task at a time."""

    def __init__(
        self,
        hal: RobotInterface,
        scene: Scene,
        objects: ObjectSource,
        *,
        planner: str = "rlgp",
        recorder: RecordSink | None = None,
        period: float = 0.01,
        tolerances: Tolerances | None = None,
        max_replans: int = 3,
        seed: int = 0,
        robot_wait_s: float = ROBOT_WAIT_S,
        limits: PlanLimits = DEFAULT_LIMITS,
    ) -> None:
        if scene.robot.name != hal.model.name:
            raise RlgpError(
                f"scene {scene.name!r} is for robot {scene.robot.name!r}, the HAL drives {hal.model.name!r}"
            )
        self.hal, self.model = hal, hal.model
        self.scene = scene  # the world model: updated by every SENSE
        self.objects = objects
        self.planner, self.seed, self.max_replans = planner, seed, max_replans
        self.limits = limits  # every plan and replan's CPU-time budget and search expansions
        self.robot_wait_s = robot_wait_s
        self.memory = PlannerMemory()  # the planners' graphs, kept (and improved) across plans and replans
        self.tol = tolerances or Tolerances()
        self.signals = Signals()
        self.sm = StateMachine()
        self.sm.listeners.append(self._record_transition)
        self.recorder: RecordSink | None = None
        self.recording_error: str | None = None  # why the last recording stopped early
        #: called (from the thread that was writing) when a recording stops on a write error
        self.on_recording_error: Callable[[str], None] | None = None
        self.actor = Actor(hal, self.signals, None, period, self.tol)
        self.attach(recorder)
        self.held: str | None = None  # the object in the hand
        self.T_tool_obj: FloatArray | None = None  # how it sits in the hand, as grasped (4, 4)
        self.knob: str | None = None  # the cabinet whose knob the hand holds
        self.openings: dict[str, float] = {}  # [m] sensed drawer openings
        #: objects the goal names that the camera has not seen (why): planned on their prior pose, verified
        #: when the camera sees them (a move beyond the tolerance replans), looked for again on a replan
        self.unverified: dict[str, str] = {}
        self.verified: dict[str, str] = {}  # the task's objects once unverified, and how the camera saw them
        self.last_look: object | None = None  # the last look_for's result (the camera's LookResult)
        self.last_plan: Plan | None = None
        #: T_world_object (4, 4) of what the world checks saw while acting, newest last: what SENSE falls
        #: back on for an object whose estimate aged out since (one put down far from where the robot ends)
        self._seen_acting: dict[str, FloatArray] = {}

    # ------------------------------------------------------------------ requests (any thread)
    def estop(self) -> None:
        """Latch the e-stop: the control loop latches the HAL's within one cycle; outside it, at once."""
        self.signals.estop.set()
        if not self.actor.looping:
            self._latch_estop("e-stop requested")

    def rearm(self) -> None:
        """Release the e-stop (an operator's request): back to IDLE; the next task activates the HAL again."""
        if self.sm.state is not S.ESTOPPED:
            raise RlgpError(f"rearm: the executive is {self.sm.state.name}, not ESTOPPED")
        if self.hal.lifecycle is Lifecycle.ESTOPPED:
            self.hal.rearm()
        self.signals.estop.clear()
        self.sm.release(S.IDLE, "re-armed")

    def cancel(self) -> None:
        self.signals.cancel.set()

    def reset(self) -> None:
        """FAULT -> IDLE once an operator has looked (an operator's request; the HAL must be healthy again to
        move). With the e-stop still latched, FAULT -> ESTOPPED: rearm is the next request."""
        if self.sm.state is not S.FAULT:
            raise RlgpError(f"reset: the executive is {self.sm.state.name}, not FAULT")
        if self.signals.estop.is_set() or self.hal.lifecycle is Lifecycle.ESTOPPED:
            self.sm.to(S.ESTOPPED, "fault reset; the e-stop is still latched: rearm next")
        else:
            self.sm.release(S.IDLE, "fault reset")

    def robot_ready(self) -> bool:
        """Fresh robot state (the heartbeat holds): a task may start."""
        self.actor.clock.keepalive()
        try:
            return self.hal.heartbeat_ok()
        except Exception as e:  # a transport in trouble is simply not ready
            log.debug("heartbeat: %s", e)
            return False

    def _latch_estop(self, why: str) -> None:
        if self.hal.lifecycle in (Lifecycle.INACTIVE, Lifecycle.ACTIVE):
            try:
                self.hal.estop()
            except Exception as e:  # the executive's latch holds even when the transport does not answer
                log.error("e-stop: the HAL refused it: %s", e)
        self.sm.to(S.ESTOPPED, why)

    # ------------------------------------------------------------------ recording
    def attach(self, recorder: RecordSink | None) -> None:
        """Record from now on into ``recorder`` (None: stop recording; the caller closes it). A write error
        stops that recording, never the task: it is logged, kept in ``recording_error``, handed to
        ``on_recording_error`` and said in the task's result."""
        self.recorder = self.actor.recorder = recorder
        if recorder is not None:
            self.recording_error = None
            recorder.on_error = self._recording_failed

    def _recording_failed(self, why: str) -> None:
        self.recording_error = why
        log.error("executive: recording stopped, the task goes on: %s", why)
        if self.on_recording_error is not None:
            try:
                self.on_recording_error(why)
            except Exception:
                log.exception("on_recording_error failed")

    def _record_transition(self, tr: Transition) -> None:
        if self.recorder is not None:
            self.recorder.write("/transitions", tr.as_dict(), tr.t_wall)

    # ------------------------------------------------------------------ stages
    def _event(self, kind: str, **data: object) -> None:
        if self.recorder is not None:
            self.recorder.write("/events", {"kind": kind, **data})

    def _robot_state(self, wait_s: float = 0.0) -> RobotState:
        """The robot's state; with ``wait_s`` [s], waits that long for a fresh one (a robot reconnecting),
        then fails the task; without, stale state is a FAULT (the robot was lost while in use)."""
        end = time.monotonic() + wait_s
        while not self.robot_ready():
            if time.monotonic() >= end:
                why = f"no fresh robot state within {self.hal.heartbeat_timeout} s"
                if wait_s > 0.0:
                    raise _FailedError(f"{why} (waited {wait_s:.0f} s for the robot; nothing moved)")
                raise _FaultError(why)
            time.sleep(0.05)
        st = self.hal.read_state()
        if st is None:
            raise _FaultError("no robot state received")
        return st

    def sense(self, wait_s: float = 0.0) -> Scene:
        """Update the world model from the robot's state and the object source (``wait_s``: see
        ``_robot_state``)."""
        st = self._robot_state(wait_s)
        poses = self._poses_since(st.stamp)
        self._record_detections(poses)
        remembered = {n: T for n, T in self._seen_acting.items() if n != self.held and n not in poses}
        if remembered:
            log.info("not sensed now, at their last pose seen while acting: %s", sorted(remembered))
        poses = {**remembered, **poses}
        self._seen_acting = {}
        self.openings = drawer_openings(self.scene, poses)
        if not self.objects.senses and self.held is not None:
            poses.pop(self.held, None)  # assumed poses know nothing of the grasp: it is as executed
        self.scene = update_scene(self.scene, self.model, st, poses, self.held, self.openings, self.T_tool_obj)
        if self.recorder is not None:
            self.recorder.write("/scene", scene_to_dict(self.scene))
        return self.scene

    def _poses_since(self, stamp: float) -> dict[str, FloatArray]:
        """The object poses observed no earlier than the robot state at ``stamp`` [s] (a motion-capture
        stream lags the joint states: a pose from before a release is where the hand was). Waits up to
        FRESH_POSES_S; poses still older count as not sensed now."""
        end = time.monotonic() + FRESH_POSES_S
        while True:
            t = self.objects.stamp()
            if t is None or t >= stamp:
                return self.objects.poses()
            if time.monotonic() >= end:
                log.warning("object poses at t = %.3f s are older than the robot state at t = %.3f s after "
                            "%.1f s: not sensed now", t, stamp, FRESH_POSES_S)
                return {}
            time.sleep(0.01)

    def _look_for(self, goal: Goal) -> bool:
        """A source that can look (the camera): point the head until every object the goal names is seen,
        or say which were not (those are planned on their prior pose, unverified). False when the source
        cannot look."""
        names = sorted({a for lit in goal.literals for a in lit.args} & {o.name for o in self.scene.objects})
        found = self.objects.look_for(names, self.hal)
        if found is None:
            return False
        self.last_look = found
        whys = dict(found.undetectable)
        for n in sorted(set(self.unverified) - found.unverified):
            self.verified[n] = f"seen looking for it ({found.views} head views)"
        self.unverified = {n: whys.get(n, "not seen") for n in sorted(found.unverified)}
        self._event("look_for", seen=sorted(found.seen), missing=sorted(found.missing), views=found.views,
                    elapsed_s=found.elapsed_s, detail=found.detail, unverified=dict(self.unverified))
        (log.info if found.ok else log.warning)(
            "sensing by camera: %s (%.2f s, %d head views)", found.detail, found.elapsed_s, found.views
        )
        if self.unverified:
            log.info("planning on the scene's poses of %s (unverified): verified when the camera sees them",
                     sorted(self.unverified))
        return True

    def _verified(self, poses: dict[str, FloatArray]) -> None:
        """Unverified objects the camera now sees are verified (the world check compares them with the plan)."""
        for name in sorted(set(self.unverified) & set(poses)):
            del self.unverified[name]
            self.verified[name] = f"seen during {self.sm.state.name.lower()}"
            log.info("camera: %s seen (verified), %.3f m from its planned pose", name, float(np.linalg.norm(
                poses[name][:3, 3] - self.scene.object(name).T[:3, 3])))
            self._event("verified", object=name)

    def _goal(self, literals: Sequence[str] | None) -> Goal:
        if literals is None:
            return self.scene.goal

        def fail(where: str, msg: str) -> SceneError:
            return SceneError("goal", where, msg)

        if isinstance(literals, str) or not all(isinstance(x, str) for x in literals):
            raise SceneError("goal", "literals", f"expected a list of literal strings, got {literals!r}")
        if not literals:
            raise SceneError("goal", "literals", "empty goal")
        return Goal(parse_goal(list(literals), self.scene, fail))

    def _unmet(self, goal: Goal) -> list[str]:
        poses = {o.name: o.T for o in self.scene.objects}
        return [
            f"{lit}: {self.held} is in the hand" if self.held in lit.args else why
            for lit in goal.literals
            for ok, why in [goal_holds(self.scene, lit, poses, self.openings)]
            if not ok or self.held in lit.args
        ]

    def _time(self, plan: Plan) -> list[Trajectory | None]:
        try:
            return list(to_trajectory(plan, self.model).trajectories)
        except TimingError as e:
            raise _FailedError(str(e)) from e

    def _record_detections(self, poses: dict[str, FloatArray]) -> None:
        if self.recorder is not None:
            self.recorder.write("/detections", {"source": type(self.objects).__name__, "poses": dict(poses)})

    def _world_check(self, plan_scene: Scene, phases: Sequence[Phase]):
        """Before and during every phase (at the actor's world-check rate), with a sensing source: the
        sensed poses (objects, drawers) are recorded, so a replay shows the world moving; and every object
        the plan has not grasped yet must still stand where the plan assumed it (the one phase k grasps,
        and the obstacles its paths were checked against: a standing block pushed 12 cm by a held one once
        went unnoticed for a minute, until its own pick). Objects in a drawer (they ride with it) and the
        start's held object are left out; a placed object lands where it lands."""
        openings = dict(plan_scene.start.openings)
        poses0 = {o.name: o.T for o in plan_scene.objects}
        in_drawer = {
            o.name for o in plan_scene.objects for c in drawer_views(plan_scene)
            if goal_holds(plan_scene, Literal("in", (o.name, c)), poses0, openings)[0]
        }
        touched_before: list[set[str]] = [set() for _ in phases]  # grasped in an earlier phase (or held at the start)
        seen: set[str] = {plan_scene.start.held} if plan_scene.start.held else set()
        for k, ph in enumerate(phases):
            touched_before[k] = set(seen)
            if ph.grasp is not None:
                seen.add(ph.grasp)

        def check(k: int, ph: Phase, st: RobotState) -> Violation | None:
            if not self.objects.senses:
                return None
            poses = self.objects.poses()
            self._record_detections(poses)
            self._seen_acting.update(poses)
            if self.unverified:
                self._verified(poses)
            for o in plan_scene.objects:
                if o.name in touched_before[k] or o.name in in_drawer:
                    continue
                T = poses.get(o.name)
                if T is None:
                    continue  # not seen now: go on the last estimate
                d = float(np.linalg.norm(T[:2, 3] - np.asarray(o.pose[:2])))
                if d > self.tol.object_moved:
                    what = "to be grasped" if o.name == ph.grasp else "standing"
                    return Violation(
                        "object_moved", Reaction.REPLAN, f"{o.name} ({what}) moved {d * 1000:.0f} mm since planning"
                    )
            return None

        return check

    # ------------------------------------------------------------------ the task
    def run(self, goal_literals: Sequence[str] | None = None) -> TaskResult:
        """Achieve ``goal_literals`` (default: the scene's goal). Returns when done, failed or stopped.

        Never raises: an unexpected exception anywhere in the task brings the robot to rest and ends in
        FAULT with its reason (recorded, and published by the state machine's listeners)."""
        t_start = time.perf_counter()
        self.signals.cancel.clear()
        first_motion: list[float] = []
        self.actor._on_first_motion = lambda: first_motion.append(time.perf_counter() - t_start)
        prog = _Progress(goal_text=(
            tuple(goal_literals) if goal_literals is not None else tuple(str(x) for x in self.scene.goal.literals)
        ), d0=self.actor.base_distance_m)

        def result(end: _End) -> TaskResult:
            r = TaskResult(
                end.status,
                end.detail,
                prog.goal_text,
                prog.actions,
                prog.plans,
                prog.replans,
                prog.planning_time_s,
                prog.execution_time_s,
                first_motion[0] if first_motion else None,
                self.actor.base_distance_m - prog.d0,
                end.verified,
                tuple(prog.executed),
                self.recording_error,
            )
            self._event("result", **r.as_dict())
            log.info("task %s: %s", end.status.value, end.detail)
            return r

        state = self.sm.state
        if state is S.ESTOPPED:
            return result(_End(TaskStatus.ESTOPPED, "e-stop latched: rearm first"))
        if state is S.FAULT:
            return result(_End(TaskStatus.FAULT, f"in FAULT ({self.sm.reason}): reset first"))
        if state is not S.IDLE:
            return result(_End(TaskStatus.FAILED, f"busy ({state.name})"))
        try:
            end = self._task(goal_literals, prog)
        except IllegalTransitionError as e:
            if not e.preempted:
                end = self._internal_error(e)
            else:  # latched by another request meanwhile: the task ends as that latch
                end = _End(_LATCH_STATUS[e.source], f"{e.source.value} while {prog.stage}: {self.sm.reason}")
        except _FaultError as e:
            self._fault(str(e))
            end = _End(TaskStatus.FAULT, str(e))
        except _FailedError as e:
            end = _End(TaskStatus.FAILED, str(e))
        except SceneError as e:  # the sensed world is not plannable (an object fell, ...)
            end = _End(TaskStatus.FAILED, f"sensed world: {e}", "bad sensed world")
        except Exception as e:
            end = self._internal_error(e)
        if end.status not in _LATCH_STATUS.values():
            final = self.sm.settle(S.IDLE, end.reason or end.detail)
            if final in LATCHED:  # an e-stop or fault latched as the task ended: it ends as that latch
                end = _End(_LATCH_STATUS[final], f"{final.value}: {self.sm.reason} (the task: {end.detail})")
        return result(end)

    def _task(self, goal_literals: Sequence[str] | None, prog: _Progress) -> _End:
        """The task from IDLE; how it ends (the caller settles the state machine back to IDLE)."""
        sm = self.sm
        sm.to(S.SENSING, f"task {' '.join(prog.goal_text)}")
        try:
            goal = self._goal(goal_literals)
        except SceneError as e:
            return _End(TaskStatus.INVALID_GOAL, str(e), "invalid goal")
        self._event("goal", literals=[str(g) for g in goal.literals])
        self.unverified, self.verified = {}, {}
        self.sense(wait_s=self.robot_wait_s)
        if self._look_for(goal):
            self.sense()
        for attempt in range(self.max_replans + 1):
            if self.signals.estop.is_set():
                self._latch_estop("e-stop requested")
                return _End(TaskStatus.ESTOPPED, "e-stop")
            if self.signals.cancel.is_set():
                return _End(TaskStatus.CANCELLED, "cancelled before motion", "cancelled")
            if self.knob is not None:  # stopped while driving a drawer: let go first
                stopped = self._release_knob(self.knob, prog)
                if stopped is not None:
                    return stopped
            unmet = self._unmet(goal)
            if not unmet:
                if self.objects.senses:
                    return _End(TaskStatus.SUCCEEDED, "goal holds in the sensed world", "goal holds", True)
                return _End(TaskStatus.SUCCEEDED, "goal holds in the world model (poses not sensed)", "goal holds")
            prog.stage = "planning"
            sm.to(S.PLANNING, f"attempt {attempt + 1}")
            scene = replace(self.scene, goal=goal)

            for k in range(PLAN_TRIES):  # the planners sample: another seed may find what one did not
                plan = registry.plan(  # looked up per call: a test stands a planner in
                    scene, self.planner, seed=self.seed + 101 * attempt + k, memory=self.memory, limits=self.limits
                )
                prog.plans += 1
                prog.planning_time_s += plan.planning_time_s
                if plan.success or self.signals.estop.is_set():
                    break
                self._event("plan_failed", planner=self.planner, seed=self.seed + 101 * attempt + k,
                            time_s=plan.planning_time_s, reason=plan.reason)
            self.last_plan = plan
            if self.recorder is not None:
                self.recorder.write(
                    "/plan",
                    {
                        **plan.summary(),
                        "phases": [
                            {"path": ph.path, "held": ph.held, "grasp": ph.grasp, "release": ph.release}
                            for ph in plan.phases
                        ],
                    },
                )
            if not plan.success:
                return _End(_plan_failure(plan.reason), f"{self.planner}: {plan.reason}", "no plan")
            prog.actions = plan.actions
            if self.signals.cancel.is_set():  # cancelled while planning: no motion starts
                return _End(TaskStatus.CANCELLED, "cancelled before motion", "cancelled")
            trajectories = self._time(plan)
            prog.stage = "executing"
            sm.to(S.EXECUTING, " ".join(plan.actions))
            outcome, seconds = self._act(plan, trajectories, scene)
            prog.execution_time_s += seconds
            prog.executed += _carried_out(plan, outcome.phases_done)
            self._hand_after(plan, outcome, scene)
            if outcome.status is ActStatus.ESTOPPED:
                self._latch_estop("e-stop during motion")
                return _End(TaskStatus.ESTOPPED, f"e-stop during phase {outcome.phases_done}")
            if outcome.status is ActStatus.CANCELLED:
                return _End(TaskStatus.CANCELLED, f"cancelled during phase {outcome.phases_done}; at rest", "cancelled")
            if outcome.status is ActStatus.DONE:
                prog.stage = "verifying"
                sm.to(S.SENSING, "verify")
                self._look_for(goal)
                self.sense()
                unmet = self._unmet(goal)
                if not self.objects.senses:
                    return _End(
                        TaskStatus.SUCCEEDED,
                        "executed as planned; goal not verified (poses not sensed)",
                        "executed (not verified: no object sensing)",
                    )
                if not unmet:
                    return _End(TaskStatus.SUCCEEDED, "goal holds in the sensed world", "goal verified", True)
                sm.to(S.RECOVERING, "goal not met: " + "; ".join(unmet))
                self._event("violation", monitor="verify", reaction="replan", detail="; ".join(unmet))
            else:
                v = outcome.violation
                assert v is not None
                self._event("violation", monitor=v.monitor, reaction=v.reaction.value, detail=v.detail)
                if v.reaction is Reaction.FAULT:
                    raise _FaultError(str(v))
                sm.to(S.RECOVERING, str(v))
            prog.replans += 1
            prog.stage = "sensing"
            sm.to(S.SENSING, "replan from the current state")
            if self.unverified:  # the robot has moved since: they may be in view, or large enough, now
                self._look_for(goal)
            self.sense()
        return _End(TaskStatus.FAILED, f"goal not reached after {self.max_replans} replans", "replans exhausted")

    def _internal_error(self, e: BaseException) -> _End:
        """An exception no stage expects: log it whole, bring the robot to rest, latch FAULT with its reason."""
        log.error("executive: internal error", exc_info=e)
        why = f"internal error: {type(e).__name__}: {e}"
        self._fault(why)
        return _End(TaskStatus.FAULT, why)

    def _release_knob(self, cabinet: str, prog: _Progress) -> _End | None:
        """Open the hand on ``cabinet``'s knob and back off (``recovery.release_knob``), in RECOVERING, then
        sense again. None when the hand is free; else how the task ends (e-stop, cancel, refused)."""
        self.sm.to(S.RECOVERING, f"let go of the knob of {cabinet!r}")
        release = release_knob(self.model, self.scene, cabinet)
        if not release.success:
            raise _FailedError(f"the hand holds the knob of {cabinet!r} and cannot let go: {release.reason}")
        self._event("recovery", action="release_knob", cabinet=cabinet)
        outcome, seconds = self._act(release, self._time(release), self.scene)
        prog.execution_time_s += seconds
        self._hand_after(release, outcome, self.scene)
        if outcome.status is ActStatus.ESTOPPED:
            self._latch_estop("e-stop while letting go of a knob")
            return _End(TaskStatus.ESTOPPED, "e-stop while letting go of the knob")
        if outcome.status is ActStatus.CANCELLED:
            return _End(TaskStatus.CANCELLED, "cancelled while letting go of the knob; at rest", "cancelled")
        if outcome.status is ActStatus.VIOLATION:
            v = outcome.violation
            assert v is not None
            self._event("violation", monitor=v.monitor, reaction=v.reaction.value, detail=v.detail)
            if v.reaction is Reaction.FAULT:
                raise _FaultError(str(v))
            raise _FailedError(f"letting go of the knob of {cabinet!r}: {v}")
        self.sm.to(S.SENSING, "let go of the knob")
        self.sense()
        return None

    def _act(self, plan: Plan, trajectories: list[Trajectory | None], scene: Scene) -> tuple[ActOutcome, float]:
        st = self._robot_state()
        if self.hal.lifecycle is Lifecycle.INACTIVE:
            self.hal.activate()
        self.actor.start(st)
        c0 = self.actor.cycles
        out = self.actor.run_phases(list(plan.phases), trajectories, self.held, self._world_check(scene, plan.phases))
        return out, (self.actor.cycles - c0) * self.actor.period

    def _hand_after(self, plan: Plan, outcome: ActOutcome, scene: Scene) -> None:
        """What the hand holds after (part of) a plan ran: an object, and how it sits in the hand (the grasp
        as planned, T_tool_obj at its grasp keyframe, for when the object is not sensed), or a knob."""
        if outcome.held is not None and outcome.held != self.held:
            k = max(i for i, ph in enumerate(plan.phases[: outcome.phases_done + 1]) if ph.grasp == outcome.held)
            tool = self.model.manipulator().tool_frame
            T_world_tool = self.model.fk(plan.phases[k].path[-1], tool)
            self.T_tool_obj = np.linalg.inv(T_world_tool) @ scene.object(outcome.held).T
        elif outcome.held is None:
            self.T_tool_obj = None
        self.held = outcome.held
        for k in range(outcome.phases_done):  # the gripper actions that ran
            a = gripper_action(list(plan.phases), k)
            if a is not None and a.knob:
                self.knob = a.target if a.grasp else None

    def _fault(self, why: str) -> None:
        """Bring the robot to rest and latch FAULT; never raises (it is the last line of supervision)."""
        log.error("executive fault: %s", why)
        try:
            self._event("fault", detail=why)
        except Exception:
            log.exception("fault event not recorded")
        if self.hal.lifecycle is Lifecycle.ACTIVE:
            try:
                self.hal.deactivate()  # hold position, stop the base (if the robot still listens)
            except Exception as e:
                log.error("deactivate during fault failed (%s): latching the HAL's e-stop", e)
                try:
                    self.hal.estop()
                except Exception as e2:
                    log.error("e-stop during fault failed: %s", e2)
        self.sm.to(S.FAULT, why)  # allowed from every state


@dataclass
class _Progress:
    """What a task has done so far (for its result)."""

    goal_text: tuple[str, ...]
    d0: float  # [m] the base's distance travelled when the task began
    stage: str = "sensing"  # for messages: what the task was doing
    actions: tuple[str, ...] = ()  # the last plan's
    executed: list[str] = field(default_factory=list)
    plans: int = 0
    replans: int = 0
    planning_time_s: float = 0.0
    execution_time_s: float = 0.0


class _End(NamedTuple):
    status: TaskStatus
    detail: str
    reason: str = ""  # the transition's reason when the task settles to IDLE (default: detail)
    verified: bool = False


_LATCH_STATUS = {S.ESTOPPED: TaskStatus.ESTOPPED, S.FAULT: TaskStatus.FAULT}


def _carried_out(plan: Plan, phases_done: int) -> list[str]:
    """The actions of ``plan`` whose phases up to their keyframes are among the first ``phases_done``."""
    return [plan.actions[ph.action] for ph in plan.phases[:phases_done] if ph.action is not None]


def _plan_failure(reason: str) -> TaskStatus:
    """The planners' reasons start with what kind of failure it is: a proof ("infeasible: ..."), a bad goal
    ("invalid goal: ...") or neither (a time budget spent, candidates exhausted): then it simply failed."""
    if reason.startswith("invalid goal"):
        return TaskStatus.INVALID_GOAL
    if reason.startswith("infeasible"):
        return TaskStatus.INFEASIBLE
    return TaskStatus.FAILED


class _FaultError(Exception):
    pass


class _FailedError(Exception):
    pass

"""rlgp-exec: a sense-plan-act executive for mobile manipulators (Toyota HSR, PR2).

The public API, in the order of the data flow::

    import rlgp_exec as rx

    scene = rx.shipped_scene("pick_place_pr2")        # or rx.load_scene("my_task.toml")
    plan = rx.plan(scene, planner="rlgp", seed=0)      # validated: replayed, collision and goal checked
    timed = rx.to_trajectory(plan, scene.robot.name)   # what the executive streams to the robot
    hal = rx.make_backend("sim", scene.robot.name, scene=scene)

Names are loaded on first use, so ``import rlgp_exec`` stays light.
"""

from __future__ import annotations

import importlib
from typing import TYPE_CHECKING, Any

from rlgp_exec.errors import ModelError, RlgpError, SceneError

if TYPE_CHECKING:
    from rlgp_exec.executive import Executive, ObjectSource, ScenePoses, SimMocap, TaskResult, TaskStatus
    from rlgp_exec.hal import RobotInterface, RobotState
    from rlgp_exec.hal.factory import make_backend
    from rlgp_exec.planning.limits import PlanLimits
    from rlgp_exec.planning.plan import Plan
    from rlgp_exec.planning.registry import plan, planner_names
    from rlgp_exec.planning.validate import Phase, Validation
    from rlgp_exec.scene import Scene, load_scene
    from rlgp_exec.scene.shipped import shipped_scene, shipped_scenes
    from rlgp_exec.timing import TimedPlan, Trajectory, to_trajectory

__all__ = [
    "Executive",
    "ModelError",
    "ObjectSource",
    "Phase",
    "Plan",
    "PlanLimits",
    "RlgpError",
    "RobotInterface",
    "RobotState",
    "Scene",
    "SceneError",
    "ScenePoses",
    "SimMocap",
    "TaskResult",
    "TaskStatus",
    "TimedPlan",
    "Trajectory",
    "Validation",
    "__version__",
    "load_scene",
    "make_backend",
    "plan",
    "planner_names",
    "shipped_scene",
    "shipped_scenes",
    "to_trajectory",
]
__version__ = "0.1.0"

_LAZY = {
    "Executive": "rlgp_exec.executive", "ObjectSource": "rlgp_exec.executive", "ScenePoses": "rlgp_exec.executive",
    "SimMocap": "rlgp_exec.executive", "TaskResult": "rlgp_exec.executive", "TaskStatus": "rlgp_exec.executive",
    "RobotInterface": "rlgp_exec.hal", "RobotState": "rlgp_exec.hal", "make_backend": "rlgp_exec.hal.factory",
    "PlanLimits": "rlgp_exec.planning.limits", "Plan": "rlgp_exec.planning.plan",
    "plan": "rlgp_exec.planning.registry", "planner_names": "rlgp_exec.planning.registry",
    "Phase": "rlgp_exec.planning.validate", "Validation": "rlgp_exec.planning.validate",
    "Scene": "rlgp_exec.scene", "load_scene": "rlgp_exec.scene",
    "shipped_scene": "rlgp_exec.scene.shipped", "shipped_scenes": "rlgp_exec.scene.shipped",
    "TimedPlan": "rlgp_exec.timing", "Trajectory": "rlgp_exec.timing", "to_trajectory": "rlgp_exec.timing",
}


def __getattr__(name: str) -> Any:
    module = _LAZY.get(name)
    if module is None:
        raise AttributeError(f"module 'rlgp_exec' has no attribute {name!r}; public: {__all__}")
    value = getattr(importlib.import_module(module), name)
    globals()[name] = value
    return value


def __dir__() -> list[str]:
    return sorted(__all__)

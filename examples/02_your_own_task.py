"""Write a task of your own, plan it, and run it on the simulated robot through the HAL.

A cup on a low table goes onto a plate on a desk, with the HSR. The scene is the same TOML a file holds
(see the README's scene format); here it is written from Python.

    python examples/02_your_own_task.py
"""

import sys
import tempfile
from pathlib import Path

import rlgp_exec as rx

SCENE = """
[scene]
name = "cup_to_desk"
robot = "hsr"

[robot]
base = [0.0, 0.0, 0.0]

[[fixture]]
name = "low_table"
size = [0.5, 0.5, 0.40]
pose = [0.8, 0.0, 0.20, 0.0]

[[fixture]]
name = "desk"
size = [0.6, 0.8, 0.70]
pose = [0.0, 1.3, 0.35, 0.0]

[[region]]
name = "plate"
on = "desk"
size = [0.2, 0.2]
offset = [0.0, -0.15]
color = "blue"

[[object]]
name = "cup"
shape = "cylinder"
size = [0.06, 0.06, 0.10]
pose = [0.75, 0.0, 0.45, 0.0]
color = "red"

[goal]
literals = ["(on cup plate)"]
"""

with tempfile.TemporaryDirectory() as tmp:
    path = Path(tmp) / "cup_to_desk.toml"
    path.write_text(SCENE)
    scene = rx.load_scene(path)  # a bad file raises SceneError naming the table and field

plan = rx.plan(scene, planner="rlgp", seed=0)
print(f"{scene.name}: {plan.reason if not plan.success else 'planned'}; actions: {' '.join(plan.actions)}")
if not plan.success:
    sys.exit(1)

hal = rx.make_backend("sim", scene.robot.name, scene=scene)  # PyBullet standing in for the robot
hal.configure()
try:
    executive = rx.Executive(hal, scene, rx.SimMocap(hal))  # senses, plans, times, acts, verifies
    result = executive.run()
finally:
    hal.shutdown()
print(f"task {result.status.value}: {result.detail}")
print(f"verified by sensing: {result.verified}; base driven {result.base_distance_m:.2f} m")
sys.exit(0 if result.status is rx.TaskStatus.SUCCEEDED else 1)

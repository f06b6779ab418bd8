"""URDF preparation: resolve the source, rewrite ``package://`` paths, prepend the planar base.

Both robots get the same treatment, so that pinocchio and PyBullet see one kinematic tree:

    world --base_x (prismatic x)--> base_x_link --base_y (prismatic y)--> base_y_link
          --base_yaw (about z)--> <the robot's root link> ...

Two texts come out: one for PyBullet (``base_yaw`` and the robot's continuous joints stay
continuous, so they are unlimited) and one for pinocchio, where continuous joints become
revolute joints with wide limits so that every joint has nq = nv = 1 and q holds plain angles
(pinocchio would otherwise use (cos, sin) pairs). Joint limits are not taken from pinocchio:
:class:`~rlgp_exec.robot.limits.JointLimits` carries them, continuous joints unlimited.

A third text is PyBullet's for worlds that only check collisions: without the links that carry no
collision shape on a fixed joint and nothing below them that does (sensor, tool and LED frames, the
PR2's casters: 41 of its 85 links; 2 of the HSR's 20). PyBullet recomputes every link's transform at
each joint reset, so the PR2's reset takes ~29 us instead of ~62; what collides is the same.
"""

from __future__ import annotations

import hashlib
import json
import os
import site
import sys
import tempfile
import xml.etree.ElementTree as ET
from collections.abc import Mapping
from dataclasses import dataclass
from pathlib import Path
from types import MappingProxyType

from rlgp_exec.errors import ModelError
from rlgp_exec.robot.config import BASE_JOINTS, RobotConfig

__all__ = ["MimicJoint", "PreparedUrdf", "UrdfJoint", "example_robot_data_dir", "prepare_urdf"]

_ERD_PREFIX = "example-robot-data:"
_WIDE = 1.0e4  # [rad] stand-in limit for continuous joints in pinocchio's text
_FORMAT = 3  # of the prepared texts kept on disk: bump when prepare_urdf changes what it writes


@dataclass(frozen=True)
class UrdfJoint:
    name: str
    type: str  # revolute | continuous | prismatic | fixed | ...
    parent: str
    child: str
    lower: float | None
    upper: float | None
    velocity: float | None


@dataclass(frozen=True)
class MimicJoint:
    """``q[joint] = multiplier * q[primary] + offset``."""

    joint: str
    primary: str
    multiplier: float
    offset: float


@dataclass(frozen=True)
class PreparedUrdf:
    pinocchio_xml: str
    pybullet_path: Path  # a file: PyBullet loads URDFs from disk
    root_link: str  # the robot's own root link (below the planar base)
    joints: tuple[UrdfJoint, ...]
    mimics: tuple[MimicJoint, ...]
    links_with_collision: frozenset[str]
    collision_path: Path  # PyBullet's text without the ``pruned`` links (module docstring)
    pruned: Mapping[str, str]  # a link left out of collision_path's -> its nearest ancestor kept there


def example_robot_data_dir() -> Path:
    """``.../cmeel.prefix/share/example-robot-data`` of the installed example-robot-data wheel."""
    roots = [*sys.path, *site.getsitepackages(), site.getusersitepackages()]
    for root in roots:
        cand = Path(root) / "cmeel.prefix" / "share" / "example-robot-data"
        if cand.is_dir():
            return cand
    raise ModelError(
        "the example-robot-data wheel is not installed (no cmeel.prefix/share/example-robot-data on "
        "sys.path); install the project with `make test` or `pip install example-robot-data`"
    )


def _source_text(cfg: RobotConfig) -> str:
    if cfg.urdf.startswith(_ERD_PREFIX):
        erd = example_robot_data_dir()
        path = erd / cfg.urdf[len(_ERD_PREFIX) :]
        text = path.read_text() if path.is_file() else None
        if text is None:
            raise ModelError(f"{cfg.name}: URDF {path} not found in the example-robot-data wheel")
        # package://example-robot-data/robots/... -> absolute paths inside the wheel
        return text.replace("package://example-robot-data/", f"{erd.as_posix()}/")
    path = cfg.folder / cfg.urdf
    try:
        return path.read_text()
    except OSError as e:
        raise ModelError(f"{cfg.name}: cannot read URDF {path}: {e}") from e


def _float(el: ET.Element | None, attr: str) -> float | None:
    if el is None or el.get(attr) is None:
        return None
    return float(el.get(attr))  # type: ignore[arg-type]


def _virtual_link(name: str) -> ET.Element:
    link = ET.Element("link", name=name)
    inertial = ET.SubElement(link, "inertial")
    ET.SubElement(inertial, "origin", xyz="0 0 0", rpy="0 0 0")
    ET.SubElement(inertial, "mass", value="0.01")
    ET.SubElement(inertial, "inertia", ixx="1e-4", iyy="1e-4", izz="1e-4", ixy="0", ixz="0", iyz="0")
    return link


def _base_joint(name: str, jtype: str, parent: str, child: str, axis: str, vel: float) -> ET.Element:
    j = ET.Element("joint", name=name, type=jtype)
    ET.SubElement(j, "parent", link=parent)
    ET.SubElement(j, "child", link=child)
    ET.SubElement(j, "origin", xyz="0 0 0", rpy="0 0 0")
    ET.SubElement(j, "axis", xyz=axis)
    lim = {"effort": "1000", "velocity": f"{vel}"}
    if jtype != "continuous":
        lim.update(lower=f"{-_WIDE}", upper=f"{_WIDE}")
    ET.SubElement(j, "limit", attrib=lim)
    return j


def _root_link(robot: ET.Element) -> str:
    children = {j.find("child").get("link") for j in robot.findall("joint")}  # type: ignore[union-attr]
    roots = [lk.get("name") for lk in robot.findall("link") if lk.get("name") not in children]
    if len(roots) != 1:
        raise ModelError(f"URDF must have exactly one root link, found {roots}")
    return str(roots[0])


def _cache_paths(name: str, key: str) -> tuple[Path, Path, Path]:
    """Where the PyBullet, pinocchio and collision-only PyBullet texts of a prepared URDF with inputs
    ``key`` are kept."""
    folder = Path(tempfile.gettempdir()) / "rlgp-exec-urdf"
    return (folder / f"{name}-{key}.urdf", folder / f"{name}-{key}.pinocchio.urdf",
            folder / f"{name}-{key}.collision.urdf")


def _prunable(robot: ET.Element) -> dict[str, str]:
    """The links (name -> nearest ancestor that stays) hanging on a fixed joint with no collision shape of
    their own and none below them: nothing of them can collide, and nothing they carry moves."""
    parent = {str(j.find("child").get("link")): (str(j.find("parent").get("link")), j.get("type"))  # type: ignore[union-attr]
              for j in robot.findall("joint")}
    children: dict[str, list[str]] = {}
    for child, (par, _) in parent.items():
        children.setdefault(par, []).append(child)
    shaped = {str(lk.get("name")) for lk in robot.findall("link") if lk.find("collision") is not None}
    out: set[str] = set()

    def prune(link: str) -> bool:  # post-order: a link goes when it and everything below it may
        below = [prune(c) for c in children.get(link, [])]
        ok = all(below) and link not in shaped and parent.get(link, ("", ""))[1] == "fixed"
        if ok:
            out.add(link)
        return ok

    prune(_root_link(robot))
    kept_ancestor = {}
    for link in out:
        anc = parent[link][0]
        while anc in out:
            anc = parent[anc][0]
        kept_ancestor[link] = anc
    return kept_ancestor


def _without(robot: ET.Element, links: Mapping[str, str]) -> str:
    """``robot``'s text without ``links`` and the joints to them."""
    tree = ET.fromstring(ET.tostring(robot, encoding="unicode"))
    for lk in tree.findall("link"):
        if str(lk.get("name")) in links:
            tree.remove(lk)
    for j in tree.findall("joint"):
        if str(j.find("child").get("link")) in links:  # type: ignore[union-attr]
            tree.remove(j)
    return ET.tostring(tree, encoding="unicode")


def _write_atomic(path: Path, text: str) -> None:
    path.parent.mkdir(parents=True, exist_ok=True)
    tmp = path.with_name(f".{path.name}.{os.getpid()}.tmp")
    tmp.write_text(text)
    os.replace(tmp, path)  # atomic: parallel workers never read a half-written file


def prepare_urdf(cfg: RobotConfig) -> PreparedUrdf:
    """Load ``cfg``'s URDF, prepend the planar base and produce the pinocchio/PyBullet texts."""
    source = _source_text(cfg)
    try:
        robot = ET.fromstring(source)
    except ET.ParseError as e:
        raise ModelError(f"{cfg.name}: URDF is not valid XML: {e}") from e
    root = _root_link(robot)
    for name in BASE_JOINTS:
        if robot.find(f"joint[@name='{name}']") is not None:
            raise ModelError(f"{cfg.name}: URDF already has a joint named {name!r}")

    bx, by, byaw = BASE_JOINTS
    vel = cfg.base.velocity
    extra = [
        _virtual_link("world"),
        _virtual_link("base_x_link"),
        _virtual_link("base_y_link"),
        _base_joint(bx, "prismatic", "world", "base_x_link", "1 0 0", vel[0]),
        _base_joint(by, "prismatic", "base_x_link", "base_y_link", "0 1 0", vel[1]),
        _base_joint(byaw, "continuous", "base_y_link", root, "0 0 1", vel[2]),
    ]
    for i, el in enumerate(extra):
        robot.insert(i, el)

    joints: list[UrdfJoint] = []
    mimics: list[MimicJoint] = []
    for j in robot.findall("joint"):
        lim = j.find("limit")
        joints.append(
            UrdfJoint(
                name=str(j.get("name")),
                type=str(j.get("type")),
                parent=str(j.find("parent").get("link")),  # type: ignore[union-attr]
                child=str(j.find("child").get("link")),  # type: ignore[union-attr]
                lower=_float(lim, "lower"),
                upper=_float(lim, "upper"),
                velocity=_float(lim, "velocity"),
            )
        )
        m = j.find("mimic")
        if m is not None:
            mimics.append(
                MimicJoint(
                    joint=str(j.get("name")),
                    primary=str(m.get("joint")),
                    multiplier=float(m.get("multiplier", "1")),
                    offset=float(m.get("offset", "0")),
                )
            )
    with_collision = frozenset(
        str(lk.get("name")) for lk in robot.findall("link") if lk.find("collision") is not None
    )

    # the three texts are kept on disk by what they are made from (serialising the PR2's tree takes ~0.1 s,
    # every process that loads the robot paid it)
    inputs = json.dumps([source, list(vel), _WIDE, _FORMAT])
    bullet_path, pin_path, collision_path = _cache_paths(cfg.name, hashlib.sha256(inputs.encode()).hexdigest()[:16])
    pruned = _prunable(robot)
    try:
        pin_text = pin_path.read_text() if bullet_path.is_file() and collision_path.is_file() else None
    except OSError:
        pin_text = None
    if pin_text is None:
        _write_atomic(bullet_path, ET.tostring(robot, encoding="unicode"))
        _write_atomic(collision_path, _without(robot, pruned))
        for j in robot.findall("joint"):
            if j.get("type") == "continuous":
                j.set("type", "revolute")
                lim = j.find("limit")
                if lim is None:
                    lim = ET.SubElement(j, "limit", effort="100", velocity="1")
                lim.set("lower", f"{-_WIDE}")
                lim.set("upper", f"{_WIDE}")
        pin_text = ET.tostring(robot, encoding="unicode")
        _write_atomic(pin_path, pin_text)
    return PreparedUrdf(
        pinocchio_xml=pin_text,
        pybullet_path=bullet_path,
        root_link=root,
        joints=tuple(joints),
        mimics=tuple(mimics),
        links_with_collision=with_collision,
        collision_path=collision_path,
        pruned=MappingProxyType(pruned),
    )

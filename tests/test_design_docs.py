"""The design documents against the code they describe: every public name, subcommand, ``plan --json``
field, scene key, wire key and CAN node is in ``docs/design.md``, its layers table is pyproject's
contract, every planner is described, and every file path the documents name exists."""

from __future__ import annotations

import argparse
import ast
import re
import tomllib
from pathlib import Path

import numpy as np
import pytest

ROOT = Path(__file__).resolve().parents[1]
DOCS = ("design.md", "rlgp.md", "gnpp.md", "hal.md")
# where a path written relative to a package ("nlp/keyframes.py", "reach/query.py") is looked up
SEARCH = ("", "rlgp_exec", "rlgp_exec/planning", "rlgp_exec/planning/gnpp", "rlgp_exec/planning/symbolic")


def _doc(name: str) -> str:
    return (ROOT / "docs" / name).read_text()


def _named(text: str, name: str) -> bool:
    """``name`` written as code: `name`, `name(...)` or `name = ...` inside backticks."""
    return re.search(r"`" + re.escape(name) + r"[`( =]", text) is not None


def _section(text: str, heading: str) -> str:
    start = text.index(f"\n## {heading}\n")
    end = text.find("\n## ", start + 1)
    return text[start : end if end > 0 else None]


def test_every_public_name_is_listed():
    import rlgp_exec

    api = _section(_doc("design.md"), "Public API")
    missing = [n for n in rlgp_exec.__all__ if not _named(api, n)]
    assert not missing, f"docs/design.md, Public API lacks {missing}"


def test_every_subcommand_is_listed():
    from rlgp_exec.cli import build_parser

    sub = next(a for a in build_parser()._actions if isinstance(a, argparse._SubParsersAction))
    cli = _section(_doc("design.md"), "Command line")
    missing = [c for c in sub.choices if f"| `{c}" not in cli]
    assert not missing, f"docs/design.md, Command line lacks {missing}"


def test_every_plan_json_field_is_listed():
    from rlgp_exec.planning.plan import Level3Stats, Plan

    plan = Plan(False, "rlgp", (), np.zeros((0, 0)), (), 0.0, 0, 0, None, "why",
                counters={"n0": 1}, level3=Level3Stats(), stages={"setup": 0.1})
    fields = _section(_doc("design.md"), "`plan --json`")
    missing = [k for k in plan.summary() if not _named(fields, k)]
    assert not missing, f"docs/design.md, plan --json lacks {missing}"


def _loader_keys() -> set[str]:
    """Every key the scene loader accepts: the literal sets handed to ``_Reader.table`` and TOP_KEYS."""
    tree = ast.parse((ROOT / "rlgp_exec" / "scene" / "loader.py").read_text())
    keys: set[str] = set()
    for node in ast.walk(tree):
        if isinstance(node, ast.Call) and isinstance(node.func, ast.Attribute) and node.func.attr == "table":
            allowed = node.args[2]
            if isinstance(allowed, ast.Set):
                keys |= {e.value for e in allowed.elts if isinstance(e, ast.Constant)}
        if isinstance(node, ast.Assign) and any(getattr(t, "id", "") == "TOP_KEYS" for t in node.targets):
            keys |= {e.value for e in node.value.elts if isinstance(e, ast.Constant)}  # type: ignore[attr-defined]
    return keys


def test_every_scene_key_is_listed():
    keys = _loader_keys()
    assert {"scene", "fixture", "drawer", "knob_height", "random", "offset", "literals"} <= keys  # the parse works
    # a key is listed when it is a word of some code span: `name`, `[[fixture]]`, `{ travel, knob_height }`
    spans = re.findall(r"`([^`]+)`", _section(_doc("design.md"), "Scene files"))
    words = {w for span in spans for w in re.findall(r"[A-Za-z_]+", span)}
    missing = sorted(keys - words)
    assert not missing, f"docs/design.md, Scene files lacks {missing}"


@pytest.mark.parametrize("robot", ["hsr", "pr2"])
def test_every_zenoh_key_is_listed(robot):
    from rlgp_exec.hal.zenoh_keys import load_key_map

    keys = load_key_map(robot)
    wire = _section(_doc("design.md"), "Wire protocols")
    expected = [t.key for t in keys.topics.values()] + [t.type for t in keys.topics.values()]
    expected += [keys.alive_robot, keys.alive_executive, keys.stats, keys.heartbeat]
    missing = sorted({k for k in expected if f"`{k}`" not in wire})
    assert not missing, f"docs/design.md, Wire protocols lacks {robot}'s {missing}"


def test_every_can_node_is_listed():
    nodes = tomllib.loads((ROOT / "robots" / "hsr" / "can_nodes.toml").read_text())["node"]
    wire = _section(_doc("design.md"), "Wire protocols")
    for node in nodes:
        assert re.search(rf"\| {node['id']} \| ", wire), f"CAN node {node['id']} not in docs/design.md"
        if "joint" in node:
            assert f"`{node['joint']}`" in wire, f"CAN joint {node['joint']} not in docs/design.md"


def test_layers_table_is_the_import_contract():
    contract = tomllib.loads((ROOT / "pyproject.toml").read_text())["tool"]["importlinter"]["contracts"][0]
    rows = [line for line in _section(_doc("design.md"), "Layers").splitlines() if line.startswith("| ")][1:]
    found = []
    for layer in contract["layers"]:
        modules = [m.strip() for m in layer.split(":")]
        where = {i for m in modules for i, row in enumerate(rows) if f"`{m}`" in row.split("|")[2]}
        assert len(where) == 1, f"layer {modules}: in rows {sorted(where)} of the layers table, not one"
        found.append(where.pop())
    assert found == sorted(found) and len(set(found)) == len(found), "layers out of the contract's order"


def test_every_planner_is_described():
    from rlgp_exec.planning.registry import planner_names

    text = _doc("rlgp.md") + _doc("gnpp.md")
    missing = [p for p in planner_names() if f"`{p}`" not in text]
    assert not missing, f"docs/rlgp.md and docs/gnpp.md do not describe {missing}"


@pytest.mark.parametrize("doc", DOCS)
def test_named_files_exist(doc):
    text = _doc(doc)
    paths = set(re.findall(r"`([A-Za-z0-9_./-]+\.(?:py|toml|pddl|md))`", text))
    missing = sorted(p for p in paths if not any((ROOT / base / p).exists() for base in SEARCH))
    assert not missing, f"docs/{doc} names files that do not exist: {missing}"

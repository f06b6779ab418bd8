"""The package's shape: one installed import name, and modules that import each other without circles
(the layers themselves are `lint-imports`' contract in pyproject.toml, run by `make lint`)."""

from __future__ import annotations

import json
import subprocess
import sys
from pathlib import Path

import grimp
import networkx as nx

ROOT = Path(__file__).resolve().parents[1]


def test_no_module_imports_itself_through_others():
    graph = grimp.build_graph("rlgp_exec")
    g = nx.DiGraph([(m, i) for m in graph.modules for i in graph.find_modules_directly_imported_by(m)])
    circles = [sorted(c) for c in nx.strongly_connected_components(g) if len(c) > 1]
    assert circles == []


def test_everything_is_imported_under_rlgp_exec(tmp_path):
    """A lab's own ``sim``, ``perception`` or ``robots`` module never clashes with ours: importing every
    module of the package, from a folder outside the repository, loads no top-level module of those names."""
    code = (
        "import importlib, json, pkgutil, sys, rlgp_exec\n"
        "for m in pkgutil.walk_packages(rlgp_exec.__path__, 'rlgp_exec.'):\n"
        "    m.name.endswith('__main__') or importlib.import_module(m.name)\n"
        "print(json.dumps(sorted(n for n in sys.modules if n.split('.')[0] in ('sim', 'perception', 'robots'))))\n"
    )
    env = {"PATH": "/usr/bin:/bin", "PYTHONPATH": str(ROOT), "OPENBLAS_NUM_THREADS": "1"}
    out = subprocess.run([sys.executable, "-c", code], cwd=tmp_path, env=env, capture_output=True, text=True,
                         timeout=300, check=True)
    assert json.loads(out.stdout.strip().splitlines()[-1]) == []

"""The package's shape: one installed import name, and modules that import each other without circles
(the layers themselves are `lint-imports`' contract in pyproject.toml, run by `make lint`)."""

from __future__ import annotations

import ast
import json
import re
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


#: the mark of an import kept inside a function, with its reason
_JUSTIFIED = re.compile(r"#\s*local:\s*\S")


def _is_type_checking(test: ast.expr) -> bool:
    return (isinstance(test, ast.Name) and test.id == "TYPE_CHECKING") or (
        isinstance(test, ast.Attribute) and test.attr == "TYPE_CHECKING")


def unexplained_local_imports(source: str) -> list[int]:
    """The lines of the imports inside a function body that carry no ``# local: why`` comment, on their own
    lines or the line above their run of imports (imports under ``if TYPE_CHECKING:`` are for type checkers
    and not counted)."""
    lines = source.splitlines()
    bare: list[int] = []

    def visit(node: ast.AST, in_function: bool) -> None:
        for field in ("body", "orelse", "finalbody", "handlers", "cases"):
            stmts = getattr(node, field, None)
            if not isinstance(stmts, list):
                continue
            if field == "body" and isinstance(node, ast.If) and _is_type_checking(node.test):
                continue
            first = 0  # the start of the current run of import statements
            for i, child in enumerate(stmts):
                if not isinstance(child, (ast.Import, ast.ImportFrom)):
                    first = i + 1
                elif in_function:
                    span = lines[max(stmts[first].lineno - 2, 0): child.end_lineno or child.lineno]
                    if not any(_JUSTIFIED.search(line) for line in span):
                        bare.append(child.lineno)
                visit(child, in_function or isinstance(child, (ast.FunctionDef, ast.AsyncFunctionDef, ast.Lambda)))

    visit(ast.parse(source), False)
    return bare


def test_function_local_imports_say_why():
    """An import inside a function says why it is not at the top: a heavy or optional dependency, or a module
    that imports this one (``# local: ...``)."""
    bare = [f"{path.relative_to(ROOT)}:{n}: {path.read_text().splitlines()[n - 1].strip()}"
            for folder in ("rlgp_exec", "perception", "sim", "robots")
            for path in sorted((ROOT / folder).rglob("*.py"))
            for n in unexplained_local_imports(path.read_text())]
    assert bare == []


def test_an_unexplained_local_import_is_found():
    code = ("import os\n\n\ndef f():\n    import json\n\n    # local: heavy\n    import csv\n    import zlib\n"
            "    x = 1\n    import re\n    import glob  # local: optional\n    if TYPE_CHECKING:\n        import abc\n"
            "    else:\n        import ast\n\n\nclass C:\n    def g(self):\n        from a import (\n"
            "            b,  # local: a imports this module\n        )\n")
    assert unexplained_local_imports(code) == [5, 11, 16]

"""The functional core imports no sockets, clocks, selectors, threads or pymavlink."""

from __future__ import annotations

import ast
from pathlib import Path

import pytest

SRC = Path(__file__).resolve().parents[3] / "mavlink_router" / "src" / "mavlink_router"
PURE = ["frames.py", "routing.py", "dedup.py", "signing.py", "core.py", "config.py"]
FORBIDDEN = {"socket", "selectors", "asyncio", "time", "threading", "pymavlink", "serial", "signal", "subprocess"}


@pytest.mark.parametrize("name", PURE)
def test_pure_module_imports(name: str) -> None:
    tree = ast.parse((SRC / name).read_text())
    imported = set()
    for node in ast.walk(tree):
        if isinstance(node, ast.Import):
            imported |= {alias.name.split(".")[0] for alias in node.names}
        elif isinstance(node, ast.ImportFrom) and node.module:
            imported.add(node.module.split(".")[0])
    assert not imported & FORBIDDEN, f"{name} imports {sorted(imported & FORBIDDEN)}"


@pytest.mark.parametrize("name", [p.name for p in SRC.glob("*.py") if p.name not in ("cli.py", "__main__.py")])
def test_library_code_never_prints_or_exits(name: str) -> None:
    tree = ast.parse((SRC / name).read_text())
    for node in ast.walk(tree):
        if isinstance(node, ast.Call) and isinstance(node.func, ast.Name):
            assert node.func.id not in ("print", "exit", "quit"), f"{name}:{node.lineno}"
        if isinstance(node, ast.Attribute) and isinstance(node.value, ast.Name):
            assert (node.value.id, node.attr) != ("sys", "exit"), f"{name}:{node.lineno}"

"""The autonomy core imports only numpy, OpenCV, the stdlib and uav_common/uav_autonomy."""

from __future__ import annotations

import ast
from pathlib import Path

import pytest

CORE = Path(__file__).resolve().parents[3] / "catkin_ws/src/uav_autonomy/src/uav_autonomy/core"
MODULES = ["features", "mcdm", "planning", "patterns", "controller", "controller_modes", "grid_geometry", "geometry2d"]
FORBIDDEN = {"rospy", "genpy", "pymavlink", "socket", "time", "datetime", "threading", "random", "subprocess"}


@pytest.mark.parametrize("module", MODULES)
def test_core_module_is_pure(module: str) -> None:
    tree = ast.parse((CORE / f"{module}.py").read_text())
    imported = set()
    for node in ast.walk(tree):
        if isinstance(node, ast.Import):
            imported |= {a.name.split(".")[0] for a in node.names}
        elif isinstance(node, ast.ImportFrom) and node.module:
            imported.add(node.module.split(".")[0])
    assert not imported & FORBIDDEN, f"{module} imports {imported & FORBIDDEN}"
    assert not any(name.endswith("_msgs") for name in imported)

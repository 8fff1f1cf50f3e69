"""The layering of the whole project holds, and the checker sees each kind of violation.

The rules and the one declared allow-list are ``tests/helpers/layering.py``. The first test walks
every package of the project; the others build a small tree with one violation each and show that
the checker reports exactly that, so the first test cannot pass by not looking.
"""

from __future__ import annotations

import textwrap
from pathlib import Path

import pytest
from helpers.layering import Package, Violation, check, project_packages
from helpers.paths import REPO


def test_the_project_has_no_layering_violation() -> None:
    packages = project_packages(REPO)
    assert {p.name for p in packages} >= {
        "uav_common",
        "sitl",
        "mavlink_router",
        "uav_sim_bridge",
        "uav_autonomy",
        "uav_perception",
        "uav_scenarios",
    }
    violations = check(packages)
    assert not violations, "\n".join(str(v) for v in violations)


def test_every_python_package_has_a_pure_core_the_checker_walks() -> None:
    for pkg in project_packages(REPO):
        if pkg.name == "uav_common":
            continue  # uav_common is a library of pure modules (PURE_COMMON) plus ros/ and shell/
        assert (pkg.root / "core" / "__init__.py").is_file(), f"{pkg.name} has no core/ package"


# ---------------------------------------------------------------------------------------------- synthetic trees


def write(root: Path, files: dict[str, str]) -> None:
    for rel, text in files.items():
        path = root / rel
        path.parent.mkdir(parents=True, exist_ok=True)
        path.write_text(textwrap.dedent(text))


PACKAGE_XML = """<?xml version="1.0"?>
<package format="2"><name>{name}</name><version>0.1.0</version><description>x</description>
<maintainer email="a@example.org">a</maintainer><license>BSD-3-Clause</license>
<buildtool_depend>catkin</buildtool_depend>{deps}</package>
"""


def tree(tmp_path: Path, files: dict[str, str], *, may_import: set[str] | None = None, deps: str = "") -> list[Package]:
    """A catkin package ``alpha`` (and a plain package ``beta``) with the given files over clean defaults."""
    base = {
        "ws/src/alpha/package.xml": PACKAGE_XML.format(name="alpha", deps=deps),
        "ws/src/alpha/src/alpha/__init__.py": "",
        "ws/src/alpha/src/alpha/errors.py": "class AlphaError(Exception):\n    pass\n",
        "ws/src/alpha/src/alpha/core/__init__.py": "",
        "ws/src/alpha/src/alpha/core/algo.py": "import math\n\ndef f(x):\n    return math.sqrt(x)\n",
        "ws/src/alpha/src/alpha/ros/__init__.py": "",
        "ws/src/alpha/src/alpha/shell/__init__.py": "",
        "beta/src/beta/__init__.py": "",
        "beta/src/beta/core/__init__.py": "",
        "beta/src/beta/core/pure.py": "def g():\n    return 1\n",
        "beta/src/beta/shell/__init__.py": "",
        "beta/src/beta/shell/io.py": "import socket\n",
    }
    write(tmp_path, {**base, **files})
    allowed = frozenset({"beta", "numpy"} | (may_import or set()))
    return [
        Package("alpha", tmp_path / "ws/src/alpha/src", allowed, tmp_path / "ws/src/alpha"),
        Package("beta", tmp_path / "beta/src", frozenset()),
    ]


def rules(violations: list[Violation]) -> list[str]:
    return sorted({v.rule for v in violations})


def test_a_clean_tree_has_no_violation(tmp_path: Path) -> None:
    assert check(tree(tmp_path, {})) == []


@pytest.mark.parametrize(
    ("source", "what"),
    [
        ("import socket\n", "imports socket"),
        ("import time\n\ndef now():\n    return time.monotonic()\n", "imports time"),
        ("def f():\n    import subprocess\n    return subprocess\n", "imports subprocess"),  # function-level
        ("from matplotlib import pyplot\n", "imports matplotlib"),
        ("import rospy\n", "imports rospy"),
        ("from std_msgs.msg import Header\n", "imports std_msgs.msg"),
        ("from beta.shell.io import x\n", "imports beta.shell.io, which is not pure"),
        ("from alpha.ros import conv\n", "imports alpha.ros"),
        ("import numpy as np\n\ndef f():\n    return np.random.rand()\n", "global np.random.rand"),
        ("print('hello')\n", "calls print()"),
    ],
)
def test_an_impure_core_is_reported(tmp_path: Path, source: str, what: str) -> None:
    found = check(
        tree(tmp_path, {"ws/src/alpha/src/alpha/core/bad.py": source}, may_import={"rospy", "std_msgs", "matplotlib"})
    )
    assert any(what in v.what for v in found), "\n".join(map(str, found))
    assert all("core/bad.py" in v.where for v in found if v.rule == "pure-core")


def test_an_import_outside_the_allow_list_is_reported(tmp_path: Path) -> None:
    found = check(tree(tmp_path, {"ws/src/alpha/src/alpha/shell/sim.py": "import jsbsim\n"}))
    assert rules(found) == ["allow-list"]
    assert "alpha may not import" in found[0].what


def test_ros_outside_the_ros_nodes_and_cli_folders_is_reported(tmp_path: Path) -> None:
    files = {
        "ws/src/alpha/src/alpha/shell/node.py": "import rospy\n",
        "ws/src/alpha/src/alpha/ros/ok.py": "import rospy\n",
        "ws/src/alpha/src/alpha/nodes/__init__.py": "",
        "ws/src/alpha/src/alpha/nodes/n.py": "import rospy\n",
    }
    found = check(tree(tmp_path, files, may_import={"rospy"}, deps="<depend>rospy</depend>"))
    assert [(v.rule, Path(v.where.split(":")[0]).name) for v in found] == [("ros-edges", "node.py")]


def test_an_import_cycle_is_reported_even_through_a_function_level_import(tmp_path: Path) -> None:
    files = {
        "ws/src/alpha/src/alpha/core/a.py": "from alpha.core.b import g\n",
        "ws/src/alpha/src/alpha/core/b.py": "def g():\n    from alpha.core.a import x\n    return x\n",
    }
    found = check(tree(tmp_path, files))
    assert rules(found) == ["cycle"]
    assert found[0].where == "alpha.core.a -> alpha.core.b"


def test_type_checking_imports_are_not_cycles(tmp_path: Path) -> None:
    files = {
        "ws/src/alpha/src/alpha/core/a.py": "from alpha.core.b import g\n",
        "ws/src/alpha/src/alpha/core/b.py": (
            "from typing import TYPE_CHECKING\nif TYPE_CHECKING:\n    from alpha.core.a import x\n"
        ),
    }
    assert check(tree(tmp_path, files)) == []


def test_a_private_name_imported_from_another_module_is_reported(tmp_path: Path) -> None:
    files = {"ws/src/alpha/src/alpha/core/user.py": "from alpha.core.algo import _helper\n"}
    found = check(tree(tmp_path, files))
    assert rules(found) == ["private-name"]
    assert "imports private _helper from alpha.core.algo" in found[0].what


def test_library_code_that_exits_is_reported_but_a_cli_may(tmp_path: Path) -> None:
    files = {
        "ws/src/alpha/src/alpha/shell/lib.py": "import sys\n\ndef f():\n    sys.exit(1)\n",
        "ws/src/alpha/src/alpha/cli.py": "import sys\n\ndef main():\n    print('x')\n    sys.exit(2)\n",
    }
    found = check(tree(tmp_path, files))
    assert [(v.rule, Path(v.where.split(":")[0]).name) for v in found] == [("no-print-exit", "lib.py")]


def test_package_xml_must_list_what_the_code_imports_and_nothing_else(tmp_path: Path) -> None:
    imports_rospy = {"ws/src/alpha/src/alpha/ros/conv.py": "import rospy\n"}
    found = check(tree(tmp_path / "a", imports_rospy, may_import={"rospy"}))
    assert [v.what for v in found] == ["rospy is imported but not a run dependency"]
    found = check(tree(tmp_path / "b", {}, deps="<depend>sensor_msgs</depend>"))
    assert [v.what for v in found] == ["sensor_msgs is declared but nothing imports, launches or runs it"]


def test_package_xml_must_list_what_the_launch_files_start(tmp_path: Path) -> None:
    launch = {
        "ws/src/alpha/launch/x.launch": (
            '<launch><node pkg="rviz" type="rviz" name="v"/><include file="$(find alpha)/launch/y.launch"/></launch>'
        ),
    }
    found = check(tree(tmp_path, launch))
    assert [v.what for v in found] == ["rviz is used by a launch file but not a run dependency"]
    assert check(tree(tmp_path / "ok", launch, deps="<exec_depend>rviz</exec_depend>")) == []

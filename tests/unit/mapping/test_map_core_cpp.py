"""The map server's C++ core (catkin_ws/src/uav_mapping), tested without ROS.

``map_core_tests`` is built by ``make build`` next to the node (devel/lib/uav_mapping). It runs against the
real liboctomap and OpenVDB: keys and ray sets identical to OctoMap's, log-odds identical to stock
``OcTree::insertPointCloud``, both backends agreeing, colour and time per voxel, the 2D layers, persistence,
``clear_bbx``, export and bad input. The binary runs once per session; every C++ test is one pytest case.
"""

from __future__ import annotations

import os
import subprocess
from pathlib import Path

import pytest
from helpers.procs import REPO

BINARY = REPO / "catkin_ws" / "devel" / "lib" / "uav_mapping" / "map_core_tests"


def _names() -> list[str]:
    if not BINARY.exists():
        return ["<map_core_tests not built: run make build>"]
    out = subprocess.run([str(BINARY), "--list"], capture_output=True, text=True, check=True, timeout=30)
    return out.stdout.split()


@pytest.fixture(scope="module")
def results(tmp_path_factory: pytest.TempPathFactory) -> dict[str, str]:
    assert BINARY.exists(), f"{BINARY} is missing: run `make build`"
    tmp = tmp_path_factory.mktemp("map_core")
    proc = subprocess.run(
        [str(BINARY), "--all"],
        capture_output=True,
        text=True,
        timeout=120,
        check=False,
        env={**os.environ, "MAP_TEST_TMP": str(tmp)},
    )
    lines: dict[str, str] = {}
    for line in proc.stdout.splitlines():
        verdict, _, rest = line.partition(" ")
        if verdict in ("PASS", "FAIL"):
            name, _, detail = rest.partition(": ")
            lines[name] = f"{verdict} {detail}".strip()
    lines["__returncode__"] = str(proc.returncode)
    lines["__stderr__"] = proc.stderr[-2000:]
    return lines


@pytest.mark.parametrize("name", _names())
def test_cpp(name: str, results: dict[str, str]) -> None:
    verdict = results.get(name)
    assert verdict is not None, f"{name} did not run (exit {results['__returncode__']}): {results['__stderr__']}"
    assert verdict == "PASS", f"{name}: {verdict}"


def test_all_tests_ran_and_the_binary_exited_cleanly(results: dict[str, str]) -> None:
    ran = {k for k in results if not k.startswith("__")}
    assert ran == set(_names())
    failed = sorted(k for k in ran if results[k] != "PASS")
    assert results["__returncode__"] == ("1" if failed else "0"), results["__stderr__"]


def test_unknown_test_name_is_an_error(tmp_path: Path) -> None:
    proc = subprocess.run([str(BINARY), "no_such_test"], capture_output=True, text=True, timeout=30, check=False)
    assert proc.returncode == 2
    assert "unknown test no_such_test" in proc.stderr

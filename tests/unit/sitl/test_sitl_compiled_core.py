"""The compiled SITL modules (mypyc, built by make setup): used only when current, bit for bit the pure ones."""

from __future__ import annotations

import json
import os
import subprocess
import sys
from pathlib import Path

import pytest

from sitl import compiled_core
from sitl.compiled_core import BUILD_DIR, COMPILED_MODULES, PURE_ENV, SHARED_LIB, STAMP_NAME, choose

FLIGHT = Path(__file__).with_name("compiled_core_flight.py")


def fake_build(root: Path, digest: str, *, modules: tuple[str, ...] = COMPILED_MODULES) -> Path:
    build = root / "compiled-core"
    for m in modules:
        so = build / "sitl" / f"{m.replace('.', '/')}.cpython-311-x86_64-linux-gnu.so"
        so.parent.mkdir(parents=True, exist_ok=True)
        so.write_bytes(b"")
    (build / f"{SHARED_LIB}.cpython-311-x86_64-linux-gnu.so").write_bytes(b"")
    (build / STAMP_NAME).write_text(digest + "\n", encoding="utf-8")
    return build


def test_a_current_build_is_used_and_anything_else_runs_the_pure_python_modules(tmp_path: Path) -> None:
    build = fake_build(tmp_path, "abc")
    assert choose(build, "abc", {}).compiled
    # the sources changed since the build: never a stale build, and the reason says how to rebuild
    stale = choose(build, "def", {})
    assert not stale.compiled
    assert "older than the sources" in stale.reason
    assert "make setup" in stale.reason
    # forced off, not built, half built
    assert not choose(build, "abc", {PURE_ENV: "1"}).compiled
    assert choose(build, "abc", {PURE_ENV: "0"}).compiled
    assert "no compiled core" in choose(tmp_path / "nowhere", "abc", {}).reason
    partial = fake_build(tmp_path / "p", "abc", modules=COMPILED_MODULES[:-1])
    incomplete = choose(partial, "abc", {})
    assert not incomplete.compiled
    assert COMPILED_MODULES[-1] in incomplete.reason


def test_the_digest_covers_the_sources_the_compiled_modules_depend_on() -> None:
    labels = [label for label, _ in compiled_core.source_files()]
    for m in COMPILED_MODULES:
        assert f"sitl/{m.replace('.', '/')}.py" in labels
    assert "sitl/vehicle.py" in labels
    assert "uav_common/autopilot_modes.py" in labels
    assert compiled_core.sources_digest() == compiled_core.sources_digest()


def fly(autopilot: str, *, pure: bool) -> dict[str, object]:
    env = {k: v for k, v in os.environ.items() if k != PURE_ENV}
    if pure:
        env[PURE_ENV] = "1"
    out = subprocess.run(
        [sys.executable, str(FLIGHT), autopilot], env=env, capture_output=True, text=True, timeout=600, check=True
    )
    result: dict[str, object] = json.loads(out.stdout.strip().splitlines()[-1])
    return result


@pytest.mark.parametrize("autopilot", ["px4", "ardupilot"])
def test_the_compiled_modules_fly_bit_for_bit_like_the_pure_python_ones(autopilot: str) -> None:
    choice = choose(BUILD_DIR, compiled_core.sources_digest(), {})
    if not choice.compiled:
        pytest.skip(f"no current compiled build to compare: {choice.reason}")
    compiled = fly(autopilot, pure=False)
    pure = fly(autopilot, pure=True)
    assert compiled["compiled"] is True, compiled["core"]
    assert pure["compiled"] is False
    # the flight went through what it scripts (both ways)
    expected = {"px4": {"OFFBOARD", "ORBIT", "AUTO_MISSION", "POSCTL", "AUTO_RTL"},
                "ardupilot": {"OFFBOARD", "AUTO_MISSION", "AUTO_RTL"}}[autopilot]  # fmt: skip
    assert expected <= set(pure["modes"])  # type: ignore[arg-type]
    for key in ("t_s", "mode", "armed", "modes", "trajectory", "gcs", "api"):
        assert compiled[key] == pure[key], key

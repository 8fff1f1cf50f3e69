"""uav-world command line (through its main(), and once through bin/uav-world)."""

from __future__ import annotations

import json
import subprocess
from pathlib import Path

import numpy as np
import pytest
from PIL import Image
from sim_worlds import REPO

from uav_sim_bridge.cli.contact_sheet import contact_sheet
from uav_sim_bridge.cli.world import main
from uav_sim_bridge.core.world_config import load_world_config
from uav_sim_bridge.shell.world_store import load_or_generate

SMALL = """name: cli
seed: 2
terrain: {size_m: 300, resolution_m: 4, hill_height_m: 20, valley_width_m: 120}
roads: {villages: 1, exits: 1}
forest: {coverage: 0.2, max_trees: 200}
people: {count: 3}
vehicles: {count: 2}
"""


@pytest.fixture
def world_yaml(tmp_path: Path) -> Path:
    p = tmp_path / "cli.yaml"
    p.write_text(SMALL)
    return p


def test_generate_info_hash_voxels_render(world_yaml: Path, tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    cache = ["--cache-dir", str(tmp_path / "cache")]
    assert main(["hash", str(world_yaml), *cache]) == 0
    h1 = capsys.readouterr().out.strip()
    assert main(["hash", str(world_yaml), "--seed", "2", *cache]) == 0
    assert capsys.readouterr().out.strip() == h1  # same seed, same world
    assert main(["hash", str(world_yaml), "--seed", "3", *cache]) == 0
    assert capsys.readouterr().out.strip() != h1
    assert main(["info", str(world_yaml), *cache]) == 0
    info = json.loads(capsys.readouterr().out)
    assert info["hash"] == h1
    assert info["objects"]["person"] == 3
    out = tmp_path / "export"
    assert main(["generate", str(world_yaml), "--out", str(out), *cache]) == 0
    assert {p.name for p in out.iterdir()} == {"world.ply", "world.glb", "objects.json", "summary.json"}
    assert json.loads((out / "objects.json").read_text())["world"]["hash"] == h1
    assert main(["voxels", str(world_yaml), "--resolution", "1.0", "--out", str(tmp_path / "v.npy"), *cache]) == 0
    keys = np.load(tmp_path / "v.npy")
    assert keys.ndim == 2
    assert keys.shape[1] == 3
    assert keys.dtype == np.int64
    assert main(["render", str(world_yaml), "--alt", "30", "--out", str(tmp_path / "r"), *cache]) == 0
    pngs = sorted((tmp_path / "r").glob("*.png"))
    assert len(pngs) == 3
    assert Image.open(pngs[0]).size == (640, 480)


def test_bad_world_is_exit_code_2(tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    assert main(["info", str(tmp_path / "missing.yaml")]) == 2
    assert "not found" in capsys.readouterr().err
    (tmp_path / "bad.yaml").write_text("terrain: {size_m: -5}\n")
    assert main(["info", str(tmp_path / "bad.yaml")]) == 2
    assert "size_m" in capsys.readouterr().err


def test_bin_wrapper_runs(world_yaml: Path, tmp_path: Path) -> None:
    proc = subprocess.run(
        [str(REPO / "bin" / "uav-world"), "hash", str(world_yaml), "--cache-dir", str(tmp_path)],
        capture_output=True,
        text=True,
        check=False,
        timeout=60,
    )
    assert proc.returncode == 0, proc.stderr
    assert len(proc.stdout.strip()) == 64


def test_render_in_an_environment_and_the_contact_sheet(
    world_yaml: Path, tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    cache = ["--cache-dir", str(tmp_path / "cache")]
    args = ["render", str(world_yaml), "--alt", "30", "--camera", "forward", *cache]
    assert main([*args, "--out", str(tmp_path / "clean")]) == 0
    assert main([*args, "--environment", "dusk_noise", "--out", str(tmp_path / "dusk")]) == 0
    clean = np.asarray(Image.open(next((tmp_path / "clean").glob("*_color.png"))), dtype=float)
    dusk = np.asarray(Image.open(next((tmp_path / "dusk").glob("*_color.png"))), dtype=float)
    assert np.abs(clean - dusk).mean() > 5.0  # twilight, gain and noise: another image of the same view
    capsys.readouterr()
    assert main([*args, "--environment", "sunny", "--out", str(tmp_path / "x")]) == 2
    assert "unknown environment preset 'sunny'" in capsys.readouterr().err
    # the contact sheet: a view per preset above, close-ups of each pose and vehicle below
    world = load_or_generate(load_world_config(world_yaml), tmp_path / "cache")
    sheet = contact_sheet(world, tmp_path / "sheet.png", presets=["clean", "low_sun"])
    img = np.asarray(Image.open(sheet))
    assert img.shape[1] >= 2 * 480
    assert img.shape[0] > 360 + 4 * 192
    assert img.std() > 20.0

"""End to end: the map server (roslaunch map_server.launch) fed with real rendered frames of the default world.

A client process renders nadir frames with the sim bridge's renderer and publishes /clock, tf and clouds; the
test checks the layers, the export and the map's accuracy against the world's ground-truth surface voxels.
Then it kills the node with SIGKILL (a crash), restarts it with resume:=true and checks that the map, the
layers and the export come back identical from the autosave.
"""

from __future__ import annotations

import json
import subprocess
import sys
import time
from pathlib import Path

import pytest
from helpers.procs import REPO, Proc, artifacts_dir, crash_launched_node, roscore

LAUNCH = REPO / "catkin_ws" / "src" / "uav_mapping" / "launch" / "map_server.launch"
CLIENT = Path(__file__).resolve().parent / "map_e2e_client.py"


def start_map_server(name: str, env: dict[str, str], autosave: Path, *, backend: str, resume: bool) -> Proc:
    return Proc(
        name,
        [
            "roslaunch", str(LAUNCH), f"backend:={backend}", f"autosave_path:={autosave}",
            f"resume:={'true' if resume else 'false'}", "output:=screen",
            "overrides:={autosave: {interval_s: 1.0}, layers: {rate_hz: 5.0}}",
        ],
        env=env,
    )  # fmt: skip


def run_client(name: str, mode: str, out: Path, env: dict[str, str], cache: Path) -> dict[str, object]:
    proc = Proc(name, [sys.executable, str(CLIENT), mode, str(out), str(cache)], env=env)
    try:
        rc = proc.wait(timeout_s=60.0)
    finally:
        proc.stop()
    text = proc.log_path.read_text(errors="replace")
    assert rc == 0, f"client {mode} failed ({rc}):\n{text[-3000:]}"
    results = [line for line in text.splitlines() if line.startswith("{")]
    assert results, f"client {mode} printed no result:\n{text[-3000:]}"
    return json.loads(results[-1])


@pytest.mark.parametrize("backend", ["octomap", "openvdb"])
def test_map_from_rendered_frames_survives_a_crash(backend: str, tmp_path: Path) -> None:
    cache = artifacts_dir() / "world_cache"
    autosave = tmp_path / ("autosave.ot" if backend == "octomap" else "autosave.vdb")
    with roscore(f"roscore_map_server_e2e_{backend}") as env:
        subprocess.run(["rosparam", "set", "/use_sim_time", "true"], env={**env}, check=True, capture_output=True)
        node = start_map_server(f"map_server_e2e_{backend}", env, autosave, backend=backend, resume=False)
        try:
            flown = run_client(f"map_e2e_fly_{backend}", "fly", tmp_path, env, cache)
            # Every frame inserted; ground-truth depth gives an accurate map.
            assert flown["frames"] == flown["inserted"] == 9
            assert flown["precision_1m"] > 0.9, flown
            assert flown["recall_1m_observed_columns"] > 0.6, flown
            assert flown["observed_area_m2"] > 20000.0, flown
            assert flown["elevation_known_fraction"] > 0.95, flown
            # Autosave runs every second when the map changed: two intervals after the last frame it holds
            # every frame (the check after the restart compares the maps exactly).
            time.sleep(2.5)
            assert autosave.exists()
            crash_launched_node(node, "map_server")  # a crash: no clean shutdown, no final save
        finally:
            node.stop()
        resumed = start_map_server(f"map_server_e2e_{backend}_resumed", env, autosave, backend=backend, resume=True)
        try:
            checked = run_client(f"map_e2e_check_{backend}", "check", tmp_path, env, cache)
            assert checked["layers_identical"]
            assert checked["resumed_occupied_05"] == flown["occupied_05"]
        finally:
            resumed.stop()
        assert "resumed from the autosave" in resumed.log_path.read_text(errors="replace")
    (artifacts_dir() / f"map_server_e2e_{backend}.json").write_text(json.dumps({**flown, **checked}, indent=2))

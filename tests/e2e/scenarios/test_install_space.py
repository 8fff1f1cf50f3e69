"""The catkin install space runs a scenario: ``roslaunch uav_scenarios loiter.launch`` from ``install/``.

A companion computer runs an install space, not the source tree: nodes, launch files, the map
server and the configuration (``share/uav_config/config``) must all come from there. ``make build``
runs ``catkin_make install``; this test sources ``catkin_ws/install/setup.bash`` in a clean
environment (no devel space, no source paths), checks where each piece resolves, flies the small
loiter scenario of the ros tier to its time limit and reads its final metrics.
"""

from __future__ import annotations

import json
import os
import subprocess
import time
from pathlib import Path

from helpers.paths import REPO, WORKSPACE
from helpers.procs import Proc, artifacts_dir, free_port, free_udp_port

INSTALL = WORKSPACE / "install"
SCENARIO = REPO / "tests" / "ros" / "scenarios" / "ros_loiter.yaml"
#: Kept from the caller's environment; everything ROS- or catkin-related comes from the install space.
KEEP = ("HOME", "LANG", "LC_ALL", "TERM", "UAV_ARTIFACTS", "MESA_SHADER_CACHE_DIR", "OPENBLAS_CORETYPE")


def install_env(tmp_path: Path) -> dict[str, str]:
    """The environment of a shell that sourced only ``install/setup.bash``."""
    setup = INSTALL / "setup.bash"
    assert setup.is_file(), f"{setup} is missing: `make build` runs catkin_make install"
    base = {k: os.environ[k] for k in KEEP if k in os.environ}
    base |= {"PATH": "/usr/local/bin:/usr/bin:/bin", "ROS_LOG_DIR": str(tmp_path / "ros_log")}
    out = subprocess.run(
        ["bash", "-c", f"source {setup} && env -0"], env=base, capture_output=True, check=True, timeout=60
    ).stdout
    env = dict(item.split("=", 1) for item in out.decode().split("\0") if "=" in item)
    assert str(WORKSPACE / "devel") not in env.get("CMAKE_PREFIX_PATH", "") + env.get("PYTHONPATH", "")
    return env


def resolved(env: dict[str, str], *argv: str) -> str:
    return subprocess.run(argv, env=env, capture_output=True, text=True, check=True, timeout=60).stdout.strip()


def test_every_piece_resolves_to_the_install_space(tmp_path: Path) -> None:
    env = install_env(tmp_path)
    for pkg in ("uav_scenarios", "uav_autonomy", "uav_perception", "uav_mapping", "uav_sim_bridge", "uav_config"):
        assert resolved(env, "rospack", "find", pkg) == str(INSTALL / "share" / pkg)
    code = (
        "import json, uav_scenarios, uav_autonomy, uav_sim_bridge, uav_perception\n"
        "from uav_common.paths import config_dir\n"
        "print(json.dumps({m.__name__: m.__file__ for m in (uav_scenarios, uav_autonomy, uav_sim_bridge, "
        "uav_perception)} | {'config': str(config_dir())}))"
    )
    where = json.loads(resolved(env, "python3", "-c", code))
    assert where.pop("config") == str(INSTALL / "share" / "uav_config" / "config")
    for module, path in where.items():
        assert path.startswith(str(INSTALL / "lib" / "python3" / "dist-packages")), (module, path)
    assert (INSTALL / "lib" / "uav_mapping" / "map_server").is_file()


def test_loiter_launch_runs_from_the_install_space(tmp_path: Path) -> None:
    env = install_env(tmp_path)
    master = free_port()
    env |= {"ROS_MASTER_URI": f"http://127.0.0.1:{master}", "ROS_IP": "127.0.0.1"}
    run_dir = tmp_path / "run"
    ports = {
        "sitl_tcp_port": free_port(), "sim_port": free_udp_port(), "router_tcp_port": free_port(),
        "gcs_port": free_udp_port(), "controller_port": free_udp_port(), "mavsdk_port": free_udp_port(),
        "adhoc_port": free_udp_port(),
    }  # fmt: skip
    argv = [
        "roslaunch", "-p", str(master), "uav_scenarios", "loiter.launch", f"scenario:={SCENARIO}",
        f"run_dir:={run_dir}", "record:=false", f"world_cache_dir:={artifacts_dir() / 'world_cache'}",
        *[f"{k}:={v}" for k, v in ports.items()],
    ]  # fmt: skip
    launch = Proc("install_space_loiter", argv, env=env, cwd=tmp_path)
    try:
        # The nodes roslaunch started are the installed executables.
        seen: dict[str, str] = {}
        deadline = time.monotonic() + 120.0
        while time.monotonic() < deadline and len(seen) < 3 and launch.alive():
            for node in ("scorer", "waypoint_controller", "map_server"):
                found = subprocess.run(
                    ["pgrep", "-f", f"__name:={node}( |$)"], capture_output=True, text=True, check=False, timeout=10
                )
                for pid in found.stdout.split():
                    try:
                        cmd = Path(f"/proc/{pid}/cmdline").read_bytes().decode(errors="replace").split("\0")
                    except OSError:
                        continue  # it exited in between
                    if not any(str(tmp_path) in c for c in cmd):
                        continue  # another run's node on the same machine (its __log is not under our ROS_LOG_DIR)
                    seen[node] = next((c for c in cmd if "/lib/uav_" in c), cmd[0])
            time.sleep(0.5)
        assert set(seen) == {"scorer", "waypoint_controller", "map_server"}, f"{seen}\n{launch.tail()}"
        for node, exe in seen.items():
            assert exe.startswith(str(INSTALL / "lib")), f"{node} ran {exe}, not the installed one"
        assert launch.wait(240.0) == 0, launch.tail(60)
    finally:
        launch.stop(5.0, int_timeout_s=30.0)
    summary = json.loads((run_dir / "metrics.json").read_text())
    assert summary["final"]
    assert summary["stop_reason"] == "time_limit"
    assert summary["time"]["duration_s"] >= 29.0
    assert summary["flight"]["distance_m"] > 20.0
    assert summary["coverage"]["mapped_pct"] > 0.5

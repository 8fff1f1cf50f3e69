"""The ``uav-sitl`` command line: clear failures for bad config and busy ports, ``python -m sitl``."""

from __future__ import annotations

import socket
import subprocess
import sys
from pathlib import Path

import yaml
from e2e.sitl.harness import SitlPorts


def run(*args: str, timeout_s: float = 60.0) -> subprocess.CompletedProcess[str]:
    return subprocess.run(["uav-sitl", *args], capture_output=True, text=True, timeout=timeout_s, check=False)


def test_invalid_value_fails_at_start_naming_file_and_key() -> None:
    out = run("--set", "physics.rate_hz=10", "--duration", "1")
    assert out.returncode == 2
    assert "config/sitl.yaml" in out.stderr
    assert "rate_hz" in out.stderr
    assert "[50, 2000]" in out.stderr
    out = run("--set", "links.gcs.remote_prot=1")
    assert out.returncode == 2
    assert "remote_prot" in out.stderr
    assert "known keys" in out.stderr


def test_busy_port_fails_naming_the_port(tmp_path: Path) -> None:
    ports = SitlPorts.allocate()
    with socket.socket(socket.AF_INET, socket.SOCK_DGRAM) as blocker:
        blocker.bind(("0.0.0.0", ports.api_local))
        out = run(*ports.argv(), "--no-params-file", "--duration", "1")
    assert out.returncode == 3
    assert f":{ports.api_local}" in out.stderr
    assert "api link" in out.stderr
    assert "port busy" in out.stderr


def test_python_dash_m_prints_the_effective_config() -> None:
    out = subprocess.run(
        [sys.executable, "-m", "sitl", "--print-config", "--speed-factor", "max", "--gcs-port", "14999", "--lockstep"],
        capture_output=True,
        text=True,
        timeout=60,
        check=False,
    )
    assert out.returncode == 0, out.stderr
    cfg = yaml.safe_load(out.stdout)
    assert cfg["time"] == {**cfg["time"], "speed_factor": "max", "mode": "lockstep"}
    assert cfg["links"]["gcs"]["remote_port"] == 14999
    assert cfg["physics"]["rate_hz"] == 250.0


def test_runs_for_a_duration_and_reports(tmp_path: Path) -> None:
    ports = SitlPorts.allocate()
    out = run(*ports.argv(), "--params-file", str(tmp_path / "p.json"), "--speed-factor", "max", "--duration", "5")
    assert out.returncode == 0, out.stderr
    assert "stopped after 5.0 s simulated" in out.stderr

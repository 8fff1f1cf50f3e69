"""Acceptance: the real MAVProxy (PyPI) connects on the GCS port, fetches every parameter, shows the
mode, sets a parameter, arms and changes modes from its command line.

MAVProxy is driven through its stdin like a person typing. Its ``mode <NAME>``
command is broken for every PX4 autopilot in MAVProxy 1.8.75 (pymavlink passes
the ``px4_map`` tuple to ``command_long_send``), so modes are changed with
MAVProxy's ``long MAV_CMD_DO_SET_MODE <base> <main> <sub>`` command, exactly the
COMMAND_LONG its ``set_mode_px4`` would have sent.
"""

from __future__ import annotations

import json
import time
from pathlib import Path

import pytest
from e2e.sitl.harness import MavProxy, run_sitl
from helpers.procs import artifacts_dir
from pymavlink import mavutil

from sitl.core.params import ParamTable

pytestmark = pytest.mark.slow


def test_mavproxy_params_mode_arm(tmp_path: Path) -> None:
    workdir = artifacts_dir() / "mavproxy"
    workdir.mkdir(parents=True, exist_ok=True)
    with run_sitl("mavproxy_sitl", tmp_path, speed="3") as sitl:
        observer = mavutil.mavlink_connection(f"tcp:127.0.0.1:{sitl.ports.tcp}", dialect="common", source_system=250)
        mp = MavProxy(f"udpin:127.0.0.1:{sitl.ports.gcs}", workdir)
        try:
            mp.expect(r"online system 1")
            mp.expect(r"Mode LOITER")
            # all parameters (MAVProxy tries MAVLink FTP first; we NAK it and it falls back at once)
            count = int(mp.expect(r"Received (\d+) parameters", 30).group(1))
            assert count == len(ParamTable())
            mark = mp.send("param show MIS_TAKEOFF_ALT")
            mp.expect(r"MIS_TAKEOFF_ALT\s+2\.5", since=mark)
            mp.send("param set MIS_TAKEOFF_ALT 6")
            mp.send("param set NAV_DLL_ACT 1")  # an INT32, encoded bytewise by MAVProxy for PX4
            deadline = time.monotonic() + 10
            while time.monotonic() < deadline and not sitl.params_file.exists():
                time.sleep(0.1)
            time.sleep(0.5)
            persisted = json.loads(sitl.params_file.read_text())["params"]
            assert persisted == {"MIS_TAKEOFF_ALT": 6.0, "NAV_DLL_ACT": 1.0}
            mark = mp.send("mode")
            mp.expect(r"Available modes:.*LOITER.*MISSION.*RTL.*LAND.*OFFBOARD.*TAKEOFF", since=mark)
            # arm, then AUTO.TAKEOFF: climbs to MIS_TAKEOFF_ALT, the parameter just set
            mark = mp.send("arm throttle")
            mp.expect(r"COMPONENT_ARM_DISARM: ACCEPTED", since=mark)
            mp.expect(r"ARMED", since=mark)
            mark = mp.send("long MAV_CMD_DO_SET_MODE 1 4 2")
            mp.expect(r"DO_SET_MODE: ACCEPTED", since=mark)
            mp.expect(r"Mode TAKEOFF", since=mark)
            msg = observer.recv_match(
                type="GLOBAL_POSITION_INT", condition="GLOBAL_POSITION_INT.relative_alt > 5500", blocking=True,
                timeout=30,
            )  # fmt: skip
            assert msg is not None, "the takeoff did not reach MIS_TAKEOFF_ALT"
            mp.expect(r"Mode LOITER", since=mark, timeout_s=30)
            mark = mp.send("long MAV_CMD_DO_SET_MODE 1 4 6")
            mp.expect(r"Mode LAND", since=mark)
            mp.expect(r"DISARMED", since=mark, timeout_s=60)
            mark = mp.send("status")
            mp.expect(r"HEARTBEAT \{type : 2, autopilot : 12", since=mark)
        finally:
            (workdir / "mavproxy_output.txt").write_text("\n".join(mp.lines) + "\n")
            mp.stop()
            observer.close()

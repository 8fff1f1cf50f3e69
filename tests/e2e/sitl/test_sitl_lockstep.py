"""Lockstep: simulation time advances only on SIM_STEP grants, and the same grants give the same flight."""

from __future__ import annotations

import math
import time
from pathlib import Path
from typing import Any

import pytest
from e2e.sitl.harness import Gcs, run_sitl
from pymavlink import mavutil
from pymavlink.dialects.v20 import common as mavlink2

pytestmark = pytest.mark.slow

M = mavlink2
SIM_STEP = 31010


class StepMaster:
    """The lockstep master on the simulation link (what the sensor bridge does)."""

    def __init__(self, port: int) -> None:
        self.conn = mavutil.mavlink_connection(
            f"udpout:127.0.0.1:{port}", dialect="common", source_system=1, source_component=200
        )
        self.conn.mav.heartbeat_send(M.MAV_TYPE_GENERIC, M.MAV_AUTOPILOT_INVALID, 0, 0, 0)

    def grant(self, steps: int, timeout_s: float = 10.0) -> list[Any]:
        """Grant ``steps``; returns the messages that came before the ACK (the state at the new time)."""
        self.conn.mav.command_long_send(1, 1, SIM_STEP, 0, steps, 0, 0, 0, 0, 0, 0)
        before: list[Any] = []
        deadline = time.monotonic() + timeout_s
        while time.monotonic() < deadline:
            msg = self.conn.recv_match(blocking=True, timeout=0.2)
            if msg is None:
                continue
            if msg.get_type() == "COMMAND_ACK" and msg.command == SIM_STEP:
                assert msg.result == M.MAV_RESULT_ACCEPTED
                return before
            before.append(msg)
        pytest.fail(f"no SIM_STEP ACK within {timeout_s} s")

    def close(self) -> None:
        self.conn.close()


def test_time_advances_only_on_grants(tmp_path: Path) -> None:
    with run_sitl("lockstep_basic", tmp_path, extra=["--lockstep"]) as sitl:
        gcs = Gcs.listen(sitl.ports.gcs)  # heartbeats keep coming on wall time while paused
        master = StepMaster(sitl.ports.sim)
        t0 = time.monotonic()
        gcs.latest.clear()
        gcs.pump(1.5)
        assert "HEARTBEAT" in gcs.latest, "clients stay connected while time is paused"
        assert "ATTITUDE" not in gcs.latest, "no simulation time passed, so no streams"
        assert time.monotonic() - t0 >= 1.5
        msgs = master.grant(250)
        kinds = [m.get_type() for m in msgs]
        for kind in ("ODOMETRY", "HIL_STATE_QUATERNION", "HIL_ACTUATOR_CONTROLS"):
            assert kind in kinds, kinds
        odo = next(m for m in reversed(msgs) if m.get_type() == "ODOMETRY")
        assert odo.time_usec == 1_000_000, "exactly 250 steps of 4 ms"
        assert (odo.frame_id, odo.child_frame_id) == (M.MAV_FRAME_LOCAL_NED, M.MAV_FRAME_BODY_FRD)
        act = next(m for m in msgs if m.get_type() == "HIL_ACTUATOR_CONTROLS")
        assert act.flags & 1, "lockstep flag"
        att = gcs.wait("ATTITUDE")
        assert att.time_boot_ms <= 1000  # type: ignore[attr-defined]
        time.sleep(0.5)
        msgs = master.grant(1)
        odo = next(m for m in msgs if m.get_type() == "ODOMETRY")
        assert odo.time_usec == 1_004_000, "wall time in between did not count"
        # the bridge reports the ground 2 m below home under the vehicle: it drops onto it
        home_alt_m = 488.0  # config/sitl.yaml
        master.conn.mav.terrain_report_send(0, 0, 0, home_alt_m - 2.0, 0, 0, 0)
        dropped = next(m for m in master.grant(500) if m.get_type() == "ODOMETRY")
        assert dropped.z - odo.z == pytest.approx(2.0, abs=0.03), "standing 2 m lower (NED z is down)"
        master.conn.mav.command_long_send(1, 1, SIM_STEP, 0, 0.5, 0, 0, 0, 0, 0, 0)
        ack = master.conn.recv_match(type="COMMAND_ACK", blocking=True, timeout=5)
        assert ack is not None
        assert ack.result == M.MAV_RESULT_DENIED, "a fractional grant is invalid"
        master.close()
        gcs.close()


def scripted_flight(tmp_path: Path, name: str) -> list[tuple[float, ...]]:
    """Arm and take off between grants, then 20 s of 1 s grants; the ground-truth trajectory."""
    extra = ["--lockstep", "--estimator", "noisy", "--seed", "3"]
    with run_sitl(name, tmp_path, extra=extra) as sitl:
        gcs = Gcs.listen(sitl.ports.gcs)
        master = StepMaster(sitl.ports.sim)
        master.grant(250)
        assert gcs.cmd(M.MAV_CMD_COMPONENT_ARM_DISARM, 1) == M.MAV_RESULT_ACCEPTED
        assert gcs.cmd(M.MAV_CMD_NAV_TAKEOFF, 0, 0, 0, math.nan, math.nan, math.nan, math.nan) == 0
        track = []
        for _ in range(20):
            odo = next(m for m in master.grant(250) if m.get_type() == "ODOMETRY")
            track.append((odo.time_usec, odo.x, odo.y, odo.z, *odo.q, odo.vx, odo.vy, odo.vz))
        master.close()
        gcs.close()
    return track


def test_same_grants_same_flight(tmp_path: Path) -> None:
    first = scripted_flight(tmp_path, "lockstep_run1")
    second = scripted_flight(tmp_path, "lockstep_run2")
    assert first[-1][3] < -2.0, "it took off"
    assert first == second, "bit-identical ground truth in both runs"

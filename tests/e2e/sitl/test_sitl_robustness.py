"""Bad input over real sockets never crashes or wedges the SITL; MAVLink 2 signing per link.

A fuzzer sprays random datagrams, mutated frames and hostile-but-valid messages
at every port (GCS, API, TCP, simulation link); afterwards a clean client must
still get heartbeats and correct command ACKs, and the process must report
what it dropped.
"""

from __future__ import annotations

import math
import random
import re
import socket
import time
from pathlib import Path

import pytest
from e2e.sitl.harness import Gcs, run_sitl
from pymavlink import mavutil
from pymavlink.dialects.v20 import common as mavlink2

pytestmark = pytest.mark.slow

M = mavlink2
KEY_HEX = "00112233445566778899aabbccddeeff00112233445566778899aabbccddeeff"


def valid_frames(mav: M.MAVLink) -> list[bytes]:
    msgs = [
        mav.heartbeat_encode(6, 8, 0, 0, 4),
        mav.command_long_encode(1, 1, 400, 0, math.nan, 0, 0, 0, 0, 0, 0),
        mav.command_long_encode(1, 1, 22, 0, 0, 0, 0, 0, math.inf, math.nan, -math.inf),
        mav.command_long_encode(7, 1, 400, 0, 1, 0, 0, 0, 0, 0, 0),
        mav.command_long_encode(1, 1, 31010, 0, 1e12, 0, 0, 0, 0, 0, 0),
        mav.param_set_encode(1, 1, b"MIS_TAKEOFF_ALT", math.nan, 9),
        mav.param_set_encode(1, 1, b"\xff\xfe\x00junk", 1.0, 9),
        mav.param_request_read_encode(1, 1, b"", 30000),
        mav.mission_count_encode(1, 1, 65535, 0),
        mav.mission_item_int_encode(1, 1, 0, 99, 16, 0, 1, math.nan, 0, 0, 0, 2**31 - 1, -(2**31), math.inf, 0),
        mav.set_position_target_local_ned_encode(0, 1, 1, 1, 0, math.inf, 0, 0, 0, 0, 0, 0, 0, 0, 0, 0),
        mav.set_position_target_global_int_encode(
            0, 1, 1, 6, 0, 2**31 - 1, 2**31 - 1, math.nan, 0, 0, 0, 0, 0, 0, 0, 0
        ),
        mav.manual_control_encode(1, 32767, -32768, 32767, 0, 0),
        mav.terrain_report_encode(0, 0, 0, math.nan, 0, 0, 0),
        mav.terrain_report_encode(0, 0, 0, 1e9, 0, 0, 0),
        mav.collision_encode(0, 1, 0, 0, 0, 0, 0),  # sent to every port except the sim link
        mav.file_transfer_protocol_encode(0, 1, 1, [255] * 251),
        mav.timesync_encode(0, -1),
    ]
    out = []
    for msg in msgs:
        out.append(msg.pack(mav))
        mav.seq = (mav.seq + 1) % 256
    return out


def fuzz_datagrams(rng: random.Random, frames: list[bytes], n: int) -> list[bytes]:
    out = []
    for _ in range(n):
        kind = rng.randrange(4)
        if kind == 0:
            out.append(bytes(rng.randrange(256) for _ in range(rng.randrange(1, 300))))
        elif kind == 1:
            frame = bytearray(rng.choice(frames))
            for _ in range(rng.randrange(1, 6)):
                frame[rng.randrange(len(frame))] ^= 1 << rng.randrange(8)
            out.append(bytes(frame))
        elif kind == 2:
            frame = rng.choice(frames)
            out.append(frame[: rng.randrange(1, len(frame))] + rng.choice(frames))
        else:
            out.append(rng.choice(frames))
    return out


def test_fuzzed_ports_and_signed_link(tmp_path: Path) -> None:
    key_file = tmp_path / "api.key"
    key_file.write_text(KEY_HEX + "\n")
    extra = ["--set", f"links.api.signing_key_file={key_file}"]
    with run_sitl("robustness", tmp_path, speed="3", extra=extra) as sitl:
        ports = sitl.ports
        rng = random.Random(1234)
        frames = valid_frames(M.MAVLink(None, srcSystem=66, srcComponent=1))
        sim_frames = [f for f in frames if f[7:10] != (247).to_bytes(3, "little")]  # no COLLISION on the sim link
        with socket.socket(socket.AF_INET, socket.SOCK_DGRAM) as udp:
            for port, pool in ((ports.gcs_local, frames), (ports.api_local, frames), (ports.sim, sim_frames)):
                for data in fuzz_datagrams(rng, pool, 1500):
                    udp.sendto(data, ("127.0.0.1", port))
                time.sleep(0.05)
        stream = b"".join(fuzz_datagrams(rng, frames, 1500))
        for _ in range(12):  # more connections than max_clients, some closed at once
            with socket.create_connection(("127.0.0.1", ports.tcp), timeout=5) as tcp:
                tcp.sendall(stream[: rng.randrange(1, len(stream))])
        time.sleep(0.5)
        assert sitl.proc.alive(), sitl.proc.tail()

        # a clean client on the GCS link: heartbeats, correct ACKs, state untouched by the garbage
        gcs = Gcs.listen(ports.gcs)
        hb = gcs.wait("HEARTBEAT", lambda m: m.get_srcComponent() == 1)
        assert not hb.base_mode & M.MAV_MODE_FLAG_SAFETY_ARMED  # type: ignore[attr-defined]
        assert gcs.cmd(M.MAV_CMD_REQUEST_MESSAGE, M.MAVLINK_MSG_ID_HOME_POSITION) == M.MAV_RESULT_ACCEPTED
        assert gcs.cmd(M.MAV_CMD_COMPONENT_ARM_DISARM, math.nan) == M.MAV_RESULT_DENIED
        assert gcs.cmd(M.MAV_CMD_NAV_TAKEOFF, 0, 0, 0, 0, 0, 0, math.inf) == M.MAV_RESULT_DENIED
        assert gcs.cmd(M.MAV_CMD_DO_FLIGHTTERMINATION, 1) == M.MAV_RESULT_UNSUPPORTED
        gcs.conn.mav.param_request_read_send(1, 1, b"MIS_TAKEOFF_ALT", -1)
        assert gcs.wait("PARAM_VALUE").param_value == 2.5  # type: ignore[attr-defined]

        # the signed API link: unsigned commands are rejected, signed ones work, telemetry is signed
        api = mavutil.mavlink_connection(
            f"udpin:127.0.0.1:{ports.api}", dialect="common", source_system=245, source_component=190
        )
        assert api.wait_heartbeat(timeout=10) is not None
        api.mav.command_long_send(1, 1, M.MAV_CMD_COMPONENT_ARM_DISARM, 0, 1, 0, 0, 0, 0, 0, 0)
        assert api.recv_match(type="COMMAND_ACK", blocking=True, timeout=2) is None, "unsigned arm must be ignored"
        api.setup_signing(bytes.fromhex(KEY_HEX), sign_outgoing=True)
        api.mav.command_long_send(1, 1, M.MAV_CMD_COMPONENT_ARM_DISARM, 0, 1, 0, 0, 0, 0, 0, 0)
        ack = api.recv_match(type="COMMAND_ACK", blocking=True, timeout=5)
        assert ack is not None
        assert ack.result == M.MAV_RESULT_ACCEPTED
        assert ack._signed
        api.mav.command_long_send(1, 1, M.MAV_CMD_COMPONENT_ARM_DISARM, 0, 0, 0, 0, 0, 0, 0, 0)
        api.close()
        gcs.close()
    log = sitl.proc.log_path.read_text(errors="replace")
    stats = {m.group(1): m.group(0) for m in re.finditer(r"link (\w+): rx \d+ msgs/\d+ B, bad (\d+).*", log)}
    for name in ("gcs", "api", "tcp", "sim"):
        assert name in stats, log[-2000:]
        bad = int(re.search(r"bad (\d+)", stats[name]).group(1))  # type: ignore[union-attr]
        assert bad > 0, f"{name}: fuzz input was not counted: {stats[name]}"
    assert re.search(r"link api: .*unsigned-rejected [1-9]", log), "unsigned messages counted on the signed link"
    assert "Traceback" not in log

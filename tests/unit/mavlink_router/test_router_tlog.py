"""Telemetry log files: format readable by pymavlink, naming, rotation limits."""

from __future__ import annotations

import struct
from pathlib import Path

from mr_build import command_long, heartbeat, pack
from pymavlink import mavutil

from mavlink_router.shell.tlog import TelemetryLog, next_log_path

T0 = 1_800_000_000.25


def test_tlog_is_timestamp_plus_raw_frame_and_pymavlink_reads_it(tmp_path: Path) -> None:
    frames = [pack(heartbeat(), 1, 1, seq=i) if i % 2 else pack(command_long(1, 1), 255, 190, seq=i) for i in range(6)]
    log = TelemetryLog(tmp_path)
    path = log.start(T0)
    for i, raw in enumerate(frames):
        log.write(raw, T0 + i * 0.5)
    log.stop()
    data = path.read_bytes()
    assert data[:8] == struct.pack(">Q", int(T0 * 1e6))
    assert data[8 : 8 + len(frames[0])] == frames[0]
    assert len(data) == sum(8 + len(f) for f in frames)

    reader = mavutil.mavlink_connection(str(path))
    read = []
    while (msg := reader.recv_match()) is not None:
        read.append((msg.get_type(), round(msg._timestamp, 3)))
    assert read == [("COMMAND_LONG" if i % 2 == 0 else "HEARTBEAT", round(T0 + i * 0.5, 3)) for i in range(6)]


def test_names_count_up(tmp_path: Path) -> None:
    first = next_log_path(tmp_path, T0)
    assert first.name.startswith("00001-")
    assert first.suffix == ".tlog"
    first.touch()
    assert next_log_path(tmp_path, T0).name.startswith("00002-")


def test_max_log_files_deletes_the_oldest(tmp_path: Path) -> None:
    log = TelemetryLog(tmp_path, max_files=2)
    paths = []
    for i in range(4):
        paths.append(log.start(T0 + i))
        log.write(pack(heartbeat()), T0 + i)
    log.stop()
    remaining = sorted(p.name for p in tmp_path.glob("*.tlog"))
    assert remaining == sorted(p.name for p in paths[-2:])


def test_write_without_file_is_a_no_op(tmp_path: Path) -> None:
    log = TelemetryLog(tmp_path / "sub")
    log.write(b"x", T0)
    assert not log.active
    assert log.frames == 0

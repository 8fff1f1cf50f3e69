"""The fast MAVLink 2 framing is byte-identical to pymavlink's, and parsers survive what we send."""

from __future__ import annotations

import hashlib
import math
from typing import Any

import pytest
from hypothesis import given
from hypothesis import strategies as st
from unit.sitl.sitl_builders import make_vehicle, take_off

from sitl.core.protocol import MsgId
from sitl.core.telemetry import PRODUCIBLE
from sitl.errors import LinkError
from sitl.shell.encode import Encoder, sim_time_us
from sitl.shell.links import frame_v2, load_signing_key, mavlink


def reference(msg: Any, seq: int, sysid: int, compid: int) -> bytes:
    mav = mavlink.MAVLink(None, srcSystem=sysid, srcComponent=compid)
    mav.seq = seq
    frame: bytes = msg.pack(mav)
    return frame


def test_every_telemetry_message_frames_like_pymavlink() -> None:
    v = make_vehicle()
    take_off(v, 3.0, settle_s=0.5)
    enc = Encoder(v, unix_epoch_s=1.7e9, system_id=1)
    msgs = [enc.build(i) for i in sorted(PRODUCIBLE)]
    msgs += [enc.odometry(truth=True), enc.param_value(v.params, "MIS_TAKEOFF_ALT"), *enc.statustexts(4, "x" * 70)]
    assert all(m is not None for m in msgs)
    for seq, msg in enumerate(msgs):
        assert frame_v2(msg, seq, 1, 1) == reference(msg, seq, 1, 1), msg.get_type()
    assert {m.get_type() for m in msgs} >= {x.name for x in MsgId if x in PRODUCIBLE}


def test_messages_are_stamped_on_the_exact_step() -> None:
    # steps * dt lands a hair below some instants (2050 * 0.004 s * 1e6 = 8199999.999...): truncated, the state
    # of 8.2 s was stamped 8199999 us, and a 10 Hz camera on the bridge skipped that frame.
    v = make_vehicle()
    enc = Encoder(v, unix_epoch_s=1.7e9, system_id=1)
    for _ in range(2050):
        v.step(v.t_s)
    assert v.t_s * 1e6 < 8_200_000  # the floating-point instant is below the step...
    assert enc.odometry(truth=True).time_usec == 8_200_000  # ... its stamp is not
    assert enc.time_boot_ms == 8200
    assert sim_time_us(v.t_s) == v.steps * 4000


@given(
    st.floats(allow_nan=True, allow_infinity=True, width=32),
    st.integers(0, 255),
    st.integers(0, 2**32 - 1),
    st.integers(0, 255),
)
def test_random_content_frames_like_pymavlink(value: float, seq: int, boot_ms: int, sysid: int) -> None:
    for msg in (
        mavlink.MAVLink_attitude_message(boot_ms, value, 0.0, value, 0.0, 0.0, 0.0),
        mavlink.MAVLink_command_ack_message(400, 0, 0, 0, sysid, 0),  # trailing zeros are truncated
        mavlink.MAVLink_heartbeat_message(0, 0, 0, 0, 0, 3),
    ):
        assert frame_v2(msg, seq, max(sysid, 1), 1) == reference(msg, seq, max(sysid, 1), 1)


def test_frames_parse_back() -> None:
    parser = mavlink.MAVLink(None)
    msg = mavlink.MAVLink_attitude_message(1234, 0.1, -0.2, math.pi, 0.0, 0.0, 1.0)
    (back,) = parser.parse_buffer(frame_v2(msg, 7, 1, 1))
    assert back.get_type() == "ATTITUDE"
    assert back.time_boot_ms == 1234
    assert back.yaw == pytest.approx(math.pi, abs=1e-6)
    assert back.get_seq() == 7


def test_signing_key_files(tmp_path: Any) -> None:
    hexkey = tmp_path / "hex.key"
    hexkey.write_text("ab" * 32 + "\n")
    assert load_signing_key(hexkey) == bytes([0xAB]) * 32
    phrase = tmp_path / "phrase.key"
    phrase.write_text("correct horse battery staple\n")
    assert load_signing_key(phrase) == hashlib.sha256(b"correct horse battery staple").digest()
    empty = tmp_path / "empty.key"
    empty.write_text("\n")
    with pytest.raises(LinkError, match="empty"):
        load_signing_key(empty)
    with pytest.raises(LinkError, match="cannot read"):
        load_signing_key(tmp_path / "missing.key")

"""MAVLink microservices through the real gateway and parsers, in process (links are fakes)."""

from __future__ import annotations

import math
import struct
from typing import Any

import pytest
from unit.sitl.sitl_builders import Client, Rig

from sitl.core.modes import FlightMode
from sitl.shell.encode import AUTOPILOT_CAPABILITIES, statustext_chunks
from sitl.shell.links import mavlink

NAN = math.nan


@pytest.fixture(scope="module")
def rig() -> Rig:
    return Rig()


def test_default_streams_per_link_profile() -> None:
    r = Rig()
    r.gcs.clear()
    r.api.clear()
    for _ in range(500):  # 2 s
        r.step()
    assert len(r.gcs.of_type("HEARTBEAT")) == 2
    assert len(r.api.of_type("HEARTBEAT")) == 2
    assert len(r.gcs.of_type("ATTITUDE")) == pytest.approx(30, abs=1)
    assert len(r.api.of_type("ATTITUDE")) == pytest.approx(200, abs=1)
    assert len(r.api.of_type("HIGHRES_IMU")) == pytest.approx(100, abs=1)
    assert not r.gcs.of_type("HIGHRES_IMU")
    hb = r.gcs.of_type("HEARTBEAT")[0]
    assert (hb.type, hb.autopilot) == (mavlink.MAV_TYPE_QUADROTOR, mavlink.MAV_AUTOPILOT_PX4)
    assert hb.custom_mode == FlightMode.AUTO_LOITER.custom_mode
    assert hb.system_status == mavlink.MAV_STATE_STANDBY
    status = r.gcs.of_type("SYS_STATUS")[-1]
    assert status.onboard_control_sensors_health & mavlink.MAV_SYS_STATUS_PREARM_CHECK
    assert status.onboard_control_sensors_health & mavlink.MAV_SYS_STATUS_SENSOR_GPS
    assert 16000 < status.voltage_battery < 17000
    assert status.battery_remaining == 100
    gpi = r.api.of_type("GLOBAL_POSITION_INT")[-1]
    assert gpi.time_boot_ms == pytest.approx(r.v.t_s * 1000, abs=25), "stamped with simulation time"
    battery = r.gcs.of_type("BATTERY_STATUS")[-1]
    assert battery.voltages[:5] == [battery.voltages[0]] * 4 + [65535]


def test_command_ack_semantics(rig: Rig) -> None:
    ack = rig.cmd(mavlink.MAV_CMD_REQUEST_MESSAGE, mavlink.MAVLINK_MSG_ID_AUTOPILOT_VERSION)
    assert ack.result == mavlink.MAV_RESULT_ACCEPTED
    assert (ack.target_system, ack.target_component) == (255, 190)
    wire = mavlink.MAVLink(None).parse_buffer(rig.gcs.frames[0])[0]
    assert (wire.get_type(), wire.get_srcSystem(), wire.get_srcComponent()) == ("COMMAND_ACK", 1, 1)
    version = rig.gcs.of_type("AUTOPILOT_VERSION")[0]
    assert version.capabilities == AUTOPILOT_CAPABILITIES
    assert version.capabilities & mavlink.MAV_PROTOCOL_CAPABILITY_MISSION_INT
    assert version.capabilities & mavlink.MAV_PROTOCOL_CAPABILITY_PARAM_ENCODE_BYTEWISE
    assert rig.cmd(mavlink.MAV_CMD_REQUEST_MESSAGE, 9999).result == mavlink.MAV_RESULT_UNSUPPORTED
    assert rig.cmd(mavlink.MAV_CMD_REQUEST_MESSAGE, NAN).result == mavlink.MAV_RESULT_DENIED
    assert rig.cmd(mavlink.MAV_CMD_REQUEST_AUTOPILOT_CAPABILITIES, 1).result == 0
    assert rig.gcs.of_type("AUTOPILOT_VERSION")
    assert rig.cmd(mavlink.MAV_CMD_GET_HOME_POSITION).result == 0
    home = rig.gcs.of_type("HOME_POSITION")[0]
    assert (home.latitude, home.longitude, home.altitude) == (473977420, 85455940, 488000)
    assert rig.cmd(mavlink.MAV_CMD_DO_SET_SERVO, 1, 1500).result == mavlink.MAV_RESULT_UNSUPPORTED
    assert rig.cmd(mavlink.MAV_CMD_COMPONENT_ARM_DISARM, NAN).result == mavlink.MAV_RESULT_DENIED
    assert rig.cmd(mavlink.MAV_CMD_COMPONENT_ARM_DISARM, math.inf).result == mavlink.MAV_RESULT_DENIED
    before = rig.gcs.stats.rx_other_target
    assert rig.cmd(mavlink.MAV_CMD_COMPONENT_ARM_DISARM, 1, target=(7, 1)) is None, "another system's command"
    assert rig.cmd(mavlink.MAV_CMD_COMPONENT_ARM_DISARM, 1, target=(1, 100)) is None, "another component's"
    assert rig.gcs.stats.rx_other_target == before + 2
    assert not rig.v.autopilot.armed


def test_message_interval_is_per_link(rig: Rig) -> None:
    ack = rig.cmd(mavlink.MAV_CMD_SET_MESSAGE_INTERVAL, mavlink.MAVLINK_MSG_ID_HIGHRES_IMU, 100_000)
    assert ack.result == mavlink.MAV_RESULT_ACCEPTED
    rig.gcs.clear()
    rig.api.clear()
    for _ in range(250):
        rig.step()
    assert len(rig.gcs.of_type("HIGHRES_IMU")) == pytest.approx(10, abs=1)
    assert len(rig.api.of_type("HIGHRES_IMU")) == pytest.approx(50, abs=1)
    assert rig.cmd(mavlink.MAV_CMD_GET_MESSAGE_INTERVAL, mavlink.MAVLINK_MSG_ID_HIGHRES_IMU).result == 0
    assert rig.gcs.of_type("MESSAGE_INTERVAL")[0].interval_us == 100_000
    assert rig.cmd(mavlink.MAV_CMD_SET_MESSAGE_INTERVAL, 4321, 1000).result == mavlink.MAV_RESULT_UNSUPPORTED


def test_modes_by_command_and_legacy_set_mode() -> None:
    r = Rig()
    assert r.cmd(mavlink.MAV_CMD_DO_SET_MODE, 1, 4, 6).result == 0  # MAVSDK/MAVProxy: main 4 sub 6 = LAND
    assert r.v.autopilot.mode is FlightMode.AUTO_LAND
    assert r.gcs.of_type("HEARTBEAT")[-1].custom_mode == FlightMode.AUTO_LAND.custom_mode, "announced at once"
    custom = FlightMode.AUTO_LOITER.custom_mode
    assert r.cmd(mavlink.MAV_CMD_DO_SET_MODE, 1, custom, 0).result == 0  # QGC: full custom_mode
    assert r.v.autopilot.mode is FlightMode.AUTO_LOITER
    r.gcs.clear()
    r.feed(r.client.mav.set_mode_encode(1, 1, FlightMode.AUTO_RTL.custom_mode))  # MAVROS
    assert r.v.autopilot.mode is FlightMode.AUTO_RTL
    assert not r.gcs.of_type("COMMAND_ACK"), "SET_MODE has no ACK"
    assert r.cmd(mavlink.MAV_CMD_DO_SET_MODE, 1, 6, 0).result == mavlink.MAV_RESULT_DENIED, "no offboard stream"
    assert r.cmd(mavlink.MAV_CMD_DO_SET_MODE, 1, 5, 0).result == mavlink.MAV_RESULT_DENIED, "ACRO not flown"
    assert any(m.severity <= mavlink.MAV_SEVERITY_CRITICAL for m in r.gcs.of_type("STATUSTEXT"))


def test_arm_and_nan_takeoff_switch_modes() -> None:
    r = Rig()
    assert r.cmd(mavlink.MAV_CMD_COMPONENT_ARM_DISARM, 1).result == 0
    assert r.v.autopilot.armed
    assert r.gcs.of_type("HEARTBEAT")[-1].base_mode & mavlink.MAV_MODE_FLAG_SAFETY_ARMED
    assert r.cmd(mavlink.MAV_CMD_NAV_TAKEOFF, NAN, NAN, NAN, NAN, NAN, NAN, NAN).result == 0
    assert r.v.autopilot.mode is FlightMode.AUTO_TAKEOFF
    assert r.cmd(mavlink.MAV_CMD_COMPONENT_ARM_DISARM, 0, 21196).result == 0, "kill"
    assert not r.v.autopilot.armed


def test_parameter_protocol() -> None:
    r = Rig()
    n = len(r.v.params)
    r.gcs.clear()
    r.feed(r.client.mav.param_request_list_encode(1, 1))
    values = r.gcs.of_type("PARAM_VALUE")
    assert len(values) == n
    assert sorted(v.param_index for v in values) == list(range(n))
    assert {v.param_count for v in values} == {n}
    r.gcs.clear()
    r.feed(r.client.mav.param_request_read_encode(1, 1, b"MIS_TAKEOFF_ALT", -1))
    (value,) = r.gcs.of_type("PARAM_VALUE")
    assert (value.param_id, value.param_value, value.param_type) == ("MIS_TAKEOFF_ALT", 2.5, 9)
    r.gcs.clear()
    r.feed(r.client.mav.param_request_read_encode(1, 1, b"", value.param_index))
    assert r.gcs.of_type("PARAM_VALUE")[0].param_id == "MIS_TAKEOFF_ALT"
    # an integer, bytewise (as MAVSDK and QGC send it for PX4)
    r.gcs.clear()
    r.api.clear()
    wire = struct.unpack("<f", struct.pack("<i", 2))[0]
    r.feed(r.client.mav.param_set_encode(1, 1, b"NAV_DLL_ACT", wire, mavlink.MAV_PARAM_TYPE_INT32))
    assert r.v.params["NAV_DLL_ACT"] == 2
    echo = r.gcs.of_type("PARAM_VALUE")[0]
    assert echo.param_value == wire
    assert echo.param_type == mavlink.MAV_PARAM_TYPE_INT32
    assert r.api.of_type("PARAM_VALUE"), "changes are broadcast on every link"
    assert r.persisted[-1] == {"NAV_DLL_ACT": 2.0}
    # out of range: rejected, the old value comes back, the reason is announced
    r.gcs.clear()
    r.feed(r.client.mav.param_set_encode(1, 1, b"MIS_TAKEOFF_ALT", 1e6, mavlink.MAV_PARAM_TYPE_REAL32))
    assert r.v.params["MIS_TAKEOFF_ALT"] == 2.5
    assert r.gcs.of_type("PARAM_VALUE")[0].param_value == 2.5
    assert any("out of range" in m.text for m in r.gcs.of_type("STATUSTEXT"))
    r.feed(r.client.mav.param_set_encode(1, 1, b"MIS_TAKEOFF_ALT", NAN, mavlink.MAV_PARAM_TYPE_REAL32))
    assert r.v.params["MIS_TAKEOFF_ALT"] == 2.5
    r.feed(r.client.mav.param_set_encode(1, 1, b"NO_SUCH", 1.0, mavlink.MAV_PARAM_TYPE_REAL32))
    assert r.gcs.stats.rx_invalid_values >= 3
    assert len(r.persisted) == 1


def mission_item(client: Client, seq: int, north_e7: int, east_e7: int, alt: float) -> Any:
    return client.mav.mission_item_int_encode(1, 1, seq, 6, 16, 0, 1, 0, 0, 0, NAN, north_e7, east_e7, alt, 0)


def test_mission_protocol_over_mavlink() -> None:
    r = Rig()
    c = r.client
    r.gcs.clear()
    r.feed(c.mav.mission_count_encode(1, 1, 2, 0))
    assert r.gcs.of_type("MISSION_REQUEST_INT")[-1].seq == 0
    assert not r.gcs.of_type("MISSION_REQUEST"), "never the legacy float request"
    r.feed(mission_item(c, 0, 473980000, 85460000, 10.0))
    r.feed(mission_item(c, 1, 473981000, 85460000, 12.0))
    ack = r.gcs.of_type("MISSION_ACK")[-1]
    assert (ack.type, ack.target_system, ack.target_component) == (0, 255, 190)
    assert len(r.v.autopilot.mission_store) == 2
    assert r.gcs.of_type("MISSION_CURRENT")[-1].total == 2
    r.gcs.clear()
    r.feed(c.mav.mission_request_list_encode(1, 1, 0))
    assert r.gcs.of_type("MISSION_COUNT")[0].count == 2
    r.feed(c.mav.mission_request_int_encode(1, 1, 1, 0))
    item = r.gcs.of_type("MISSION_ITEM_INT")[0]
    assert (item.seq, item.x, item.y, item.z) == (1, 473981000, 85460000, 12.0)
    r.feed(c.mav.mission_request_encode(1, 1, 0, 0))
    legacy = r.gcs.of_type("MISSION_ITEM")[0]
    assert legacy.x == pytest.approx(47.398, abs=1e-6)
    r.feed(c.mav.mission_set_current_encode(1, 1, 1))
    assert r.v.autopilot.mission_current_seq == 1
    r.gcs.clear()
    r.feed(c.mav.mission_clear_all_encode(1, 1, 0))
    assert r.gcs.of_type("MISSION_ACK")[0].type == 0
    assert len(r.v.autopilot.mission_store) == 0
    assert r.gcs.of_type("MISSION_CURRENT")[-1].mission_state == 1  # NO_MISSION


def test_small_services(rig: Rig) -> None:
    c = rig.client
    rig.gcs.clear()
    c_seq = 4242
    rig.feed(c.mav.ping_encode(123456, c_seq, 0, 0))
    pong = rig.gcs.of_type("PING")[0]
    assert (pong.time_usec, pong.seq, pong.target_system, pong.target_component) == (123456, c_seq, 255, 190)
    rig.feed(c.mav.timesync_encode(0, 777))
    ts = rig.gcs.of_type("TIMESYNC")[0]
    assert ts.ts1 == 777
    assert ts.tc1 == pytest.approx(rig.v.t_s * 1e9, abs=1e6)
    payload = [7, 0, 0, 4] + [0] * 247  # OpenFileRO, seq 7
    rig.feed(c.mav.file_transfer_protocol_encode(0, 1, 1, payload))
    nak = rig.gcs.of_type("FILE_TRANSFER_PROTOCOL")[0].payload
    assert (nak[0], nak[3], nak[5], nak[12]) == (8, 129, 4, 10), "NAK FileNotFound: clients fall back to the list"


def test_offboard_setpoint_validation(rig: Rig) -> None:
    c = rig.client
    before = rig.gcs.stats.rx_invalid_values
    rig.feed(c.mav.set_position_target_local_ned_encode(0, 1, 1, 1, 2552, NAN, 0, -5, 0, 0, 0, 0, 0, 0, 0, 0))
    assert rig.gcs.stats.rx_invalid_values == before + 1
    assert not rig.v.autopilot.failsafe.offboard.ever
    rig.feed(
        c.mav.set_position_target_local_ned_encode(0, 1, 1, 1, 2552, 1, 0, -5, NAN, NAN, NAN, NAN, NAN, NAN, 0, NAN)
    )
    assert rig.v.autopilot.failsafe.offboard.ever


def test_statustext_chunks() -> None:
    assert statustext_chunks("short", 3) == [(b"short", 0, 0)]
    text = "x" * 120
    chunks = statustext_chunks(text, 9)
    assert [len(c[0]) for c in chunks] == [50, 50, 20]
    assert {c[1] for c in chunks} == {9}
    assert [c[2] for c in chunks] == [0, 1, 2]
    assert statustext_chunks("y" * 100, 1)[-1] == (b"", 1, 2), "a 50-byte multiple ends with an empty chunk"


def test_signing_rejects_unsigned_state_changes() -> None:
    key = bytes(range(32))
    r = Rig(key=key)
    unsigned = Client()
    wrong = Client(signing_key=bytes(32))
    signed = Client(signing_key=key)
    # pymavlink records a stream's timestamp before checking the signature, so the forged frame
    # above "uses up" its timestamp; a genuine sender's clock is later anyway
    signed.mav.signing.timestamp += 100_000
    r.gcs.clear()
    r.feed(unsigned.mav.command_long_encode(1, 1, 400, 0, 1, 0, 0, 0, 0, 0, 0), client=unsigned)
    r.feed(wrong.mav.command_long_encode(1, 1, 400, 0, 1, 0, 0, 0, 0, 0, 0), client=wrong)
    assert not r.gcs.of_type("COMMAND_ACK")
    assert not r.v.autopilot.armed
    assert r.gcs.stats.rx_rejected_unsigned == 2
    r.feed(unsigned.mav.param_request_read_encode(1, 1, b"MIS_TAKEOFF_ALT", -1), client=unsigned)
    assert r.gcs.of_type("PARAM_VALUE"), "reading is allowed unsigned"
    r.feed(signed.mav.command_long_encode(1, 1, 400, 0, 1, 0, 0, 0, 0, 0, 0), client=signed)
    assert r.gcs.of_type("COMMAND_ACK")[0].result == 0
    assert r.v.autopilot.armed
    # what we send on the signed link is signed and verifies with the key
    verifier = mavlink.MAVLink(None)
    verifier.signing.secret_key = key
    ack_frame = r.gcs.pack(r.gcs.of_type("COMMAND_ACK")[0])
    assert ack_frame[2] & mavlink.MAVLINK_IFLAG_SIGNED
    assert verifier.parse_buffer(ack_frame)[0].get_type() == "COMMAND_ACK"


def test_a_takeoff_right_after_a_parameter_set_uses_the_new_value() -> None:
    """MAVSDK's set_takeoff_altitude, arm and takeoff can all arrive before the next control step: the takeoff
    must climb to the MIS_TAKEOFF_ALT just set, not the one before (it stopped at 2.5 m once in CI)."""
    r = Rig()
    r.feed(r.client.mav.param_set_encode(1, 1, b"MIS_TAKEOFF_ALT", 10.0, mavlink.MAV_PARAM_TYPE_REAL32))
    assert r.cmd(mavlink.MAV_CMD_COMPONENT_ARM_DISARM, 1).result == 0
    assert r.cmd(mavlink.MAV_CMD_NAV_TAKEOFF, NAN, NAN, NAN, NAN, NAN, NAN, NAN).result == 0
    for _ in range(250 * 20):  # 20 s at 250 Hz
        r.step()
    rel = r.gcs.of_type("GLOBAL_POSITION_INT")[-1].relative_alt / 1000.0
    assert rel > 9.0, f"climbed to {rel:.1f} m, not MIS_TAKEOFF_ALT 10 m"

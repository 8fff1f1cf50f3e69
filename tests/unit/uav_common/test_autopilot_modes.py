"""uav_common.autopilot_modes: one mode table for the SITL and the controller, PX4 and ArduCopter encodings."""

from __future__ import annotations

import pytest
from pymavlink.dialects.v20 import common as mavlink

from uav_common.autopilot_modes import (
    Autopilot,
    FlightMode,
    decode_custom_mode,
    mode_from_custom_mode,
    mode_from_set_mode_params,
    mode_name,
    set_mode_params,
)


@pytest.mark.parametrize("mode", list(FlightMode), ids=lambda m: m.name)
def test_px4_encodings_round_trip(mode: FlightMode) -> None:
    assert mode_from_custom_mode(mode.custom_mode) is mode
    assert decode_custom_mode(Autopilot.PX4, mode.custom_mode) is mode
    base, main, sub = set_mode_params(Autopilot.PX4, mode, armed=False)
    assert mode_from_set_mode_params(base, main, sub) is mode  # what MAVSDK / MAVProxy send
    assert mode_from_set_mode_params(base, float(mode.custom_mode), 0.0) is mode  # what QGC sends
    assert mode_name(Autopilot.PX4, mode.custom_mode) == mode.px4_name


def test_px4_names_and_custom_modes_are_px4s() -> None:
    assert FlightMode.AUTO_LOITER.px4_name == "AUTO.LOITER"
    assert FlightMode.AUTO_RTL.custom_mode == (4 << 16) | (5 << 24)
    assert FlightMode.OFFBOARD.custom_mode == 6 << 16
    armed = FlightMode.OFFBOARD.base_mode(armed=True)
    assert armed & mavlink.MAV_MODE_FLAG_SAFETY_ARMED
    assert armed & mavlink.MAV_MODE_FLAG_CUSTOM_MODE_ENABLED
    assert not FlightMode.OFFBOARD.base_mode(armed=False) & mavlink.MAV_MODE_FLAG_SAFETY_ARMED


@pytest.mark.parametrize(
    ("mode", "number", "name"),
    [
        (FlightMode.STABILIZED, 0, "STABILIZE"),
        (FlightMode.ALTCTL, 2, "ALT_HOLD"),
        (FlightMode.AUTO_MISSION, 3, "AUTO"),
        (FlightMode.OFFBOARD, 4, "GUIDED"),
        (FlightMode.AUTO_LOITER, 5, "LOITER"),
        (FlightMode.AUTO_RTL, 6, "RTL"),
        (FlightMode.AUTO_LAND, 9, "LAND"),
    ],
)
def test_arducopter_numbers_are_arducopters(mode: FlightMode, number: int, name: str) -> None:
    assert (mode.ardupilot_number, mode.ardupilot_name) == (number, name)
    assert decode_custom_mode(Autopilot.ARDUPILOT, number) is mode
    assert mode_name(Autopilot.ARDUPILOT, number) == name
    assert set_mode_params(Autopilot.ARDUPILOT, mode, armed=True)[1:] == (float(number), 0.0)


def test_unknown_modes_and_impossible_requests() -> None:
    assert decode_custom_mode(Autopilot.ARDUPILOT, 99) is None
    assert mode_name(Autopilot.ARDUPILOT, 99) == "MODE_99"
    assert decode_custom_mode(Autopilot.PX4, (9 << 16)) is None
    assert mode_name(Autopilot.PX4, 9 << 16) == "PX4_9.0"
    assert decode_custom_mode(Autopilot.PX4, 4 << 16) is None  # AUTO with no sub mode is no mode
    assert mode_from_custom_mode(FlightMode.AUTO_RTL.custom_mode | 1) is None  # low bits set
    assert mode_from_set_mode_params(0, 4, 3) is None  # no CUSTOM_MODE_ENABLED flag
    assert mode_from_set_mode_params(1, 4.5, 3) is None
    with pytest.raises(ValueError, match=r"ArduPilot Copter has no mode for PX4's AUTO\.TAKEOFF"):
        set_mode_params(Autopilot.ARDUPILOT, FlightMode.AUTO_TAKEOFF, armed=True)


def test_heartbeat_autopilot_field_picks_the_table_as_mavsdk_does() -> None:
    assert Autopilot.from_heartbeat(mavlink.MAV_AUTOPILOT_ARDUPILOTMEGA) is Autopilot.ARDUPILOT
    assert Autopilot.from_heartbeat(mavlink.MAV_AUTOPILOT_PX4) is Autopilot.PX4
    assert Autopilot.from_heartbeat(mavlink.MAV_AUTOPILOT_GENERIC) is Autopilot.PX4
    assert Autopilot.ARDUPILOT.mav_autopilot == mavlink.MAV_AUTOPILOT_ARDUPILOTMEGA

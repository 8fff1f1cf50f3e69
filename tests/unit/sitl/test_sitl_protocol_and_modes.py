"""MAVLink numbers in the core, PX4 custom_mode encoding and the mode-switch rules."""

from __future__ import annotations

import pytest
from pymavlink import mavutil
from pymavlink.dialects.v20 import common as mavlink

from sitl.core.modes import (
    FlightMode,
    ModeContext,
    check_arm,
    check_mode_switch,
    mode_from_custom_mode,
    mode_from_set_mode_params,  # fmt: skip
)
from sitl.core.protocol import (
    LandedState,
    MavCmd,
    MavFrame,
    MavMissionResult,
    MavResult,
    MavSeverity,
    MavState,
    MissionState,
    MsgId,
    PositionTargetMask,
)

PREFIXES = {
    MavCmd: "MAV_CMD_",
    MavResult: "MAV_RESULT_",
    MavFrame: "MAV_FRAME_",
    MavMissionResult: "MAV_MISSION_",
    MavSeverity: "MAV_SEVERITY_",
    MavState: "MAV_STATE_",
    LandedState: "MAV_LANDED_STATE_",
    MissionState: "MISSION_STATE_",
}


@pytest.mark.parametrize("enum", list(PREFIXES))
def test_core_enums_match_pymavlink(enum: type) -> None:
    for member in enum:  # type: ignore[attr-defined]
        assert getattr(mavlink, PREFIXES[enum] + member.name) == member.value, member


def test_message_ids_and_mask_bits_match_pymavlink() -> None:
    for member in MsgId:
        assert getattr(mavlink, f"MAVLINK_MSG_ID_{member.name}") == member.value
    for member in PositionTargetMask:
        assert getattr(mavlink, f"POSITION_TARGET_TYPEMASK_{member.name}") == member.value


# custom_mode values from docs research (PX4 px4_custom_mode.hpp), as MAVSDK decodes them
@pytest.mark.parametrize(
    ("mode", "custom_mode", "name"),
    [
        (FlightMode.MANUAL, 65536, "MANUAL"),
        (FlightMode.POSCTL, 196608, "POSCTL"),
        (FlightMode.AUTO_TAKEOFF, 33816576, "AUTO.TAKEOFF"),
        (FlightMode.AUTO_LOITER, 50593792, "AUTO.LOITER"),
        (FlightMode.AUTO_MISSION, 67371008, "AUTO.MISSION"),
        (FlightMode.AUTO_RTL, 84148224, "AUTO.RTL"),
        (FlightMode.AUTO_LAND, 100925440, "AUTO.LAND"),
        (FlightMode.OFFBOARD, 393216, "OFFBOARD"),
    ],
)
def test_px4_custom_mode_encoding(mode: FlightMode, custom_mode: int, name: str) -> None:
    assert mode.custom_mode == custom_mode
    assert mode_from_custom_mode(custom_mode) is mode
    assert mode.px4_name == name
    assert mavlink.MAV_MODE_FLAG_CUSTOM_MODE_ENABLED & mode.base_mode(armed=False)
    assert mode.base_mode(armed=True) & mavlink.MAV_MODE_FLAG_SAFETY_ARMED
    assert not mode.base_mode(armed=False) & mavlink.MAV_MODE_FLAG_SAFETY_ARMED


def test_pymavlink_decodes_our_heartbeat_modes_like_mavproxy() -> None:
    assert mavutil.interpret_px4_mode(29, FlightMode.AUTO_LOITER.custom_mode) == "LOITER"
    assert mavutil.interpret_px4_mode(29, FlightMode.AUTO_RTL.custom_mode) == "RTL"
    assert mavutil.interpret_px4_mode(29, FlightMode.OFFBOARD.custom_mode) == "OFFBOARD"


def test_set_mode_params_from_every_client() -> None:
    # MAVSDK / MAVProxy: param2 main, param3 sub
    assert mode_from_set_mode_params(1, 4, 5) is FlightMode.AUTO_RTL
    assert mode_from_set_mode_params(129, 6, 0) is FlightMode.OFFBOARD
    # QGC: full custom_mode in param2
    assert mode_from_set_mode_params(1, FlightMode.AUTO_MISSION.custom_mode, 0) is FlightMode.AUTO_MISSION
    # no custom-mode flag, unknown or fractional modes
    assert mode_from_set_mode_params(0, 4, 5) is None
    assert mode_from_set_mode_params(1, 5, 0) is None  # ACRO: not flown here
    assert mode_from_set_mode_params(1, 4.5, 3) is None
    assert mode_from_custom_mode(-1) is None
    assert mode_from_custom_mode(FlightMode.AUTO_RTL.custom_mode | 1) is None


def ctx(**changes: bool) -> ModeContext:
    base = {
        "armed": True,
        "landed": False,
        "crashed": False,
        "position_valid": True,
        "home_valid": True,
        "mission_valid": True,
        "offboard_stream_ok": True,
        "manual_control_ok": True,
    }
    base.update(changes)
    return ModeContext(**base)


def test_mode_switch_rules() -> None:
    assert all(check_mode_switch(m, ctx()) is None for m in FlightMode)
    assert check_mode_switch(FlightMode.AUTO_LOITER, ctx(crashed=True)) is not None
    assert check_mode_switch(FlightMode.OFFBOARD, ctx(offboard_stream_ok=False)) is not None
    assert check_mode_switch(FlightMode.AUTO_MISSION, ctx(mission_valid=False)) is not None
    assert check_mode_switch(FlightMode.AUTO_RTL, ctx(home_valid=False)) is not None
    assert check_mode_switch(FlightMode.POSCTL, ctx(position_valid=False)) is not None
    assert check_mode_switch(FlightMode.MANUAL, ctx(position_valid=False)) is None
    assert check_mode_switch(FlightMode.MANUAL, ctx(manual_control_ok=False)) is not None
    assert check_mode_switch(FlightMode.MANUAL, ctx(manual_control_ok=False, armed=False)) is None
    assert check_arm(FlightMode.AUTO_LAND, ctx(armed=False)) is not None
    assert check_arm(FlightMode.AUTO_RTL, ctx(armed=False)) is not None
    assert check_arm(FlightMode.AUTO_LOITER, ctx(armed=False)) is None

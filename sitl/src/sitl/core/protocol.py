"""The MAVLink numbers the autopilot core reasons about, as enums.

The core stays free of pymavlink (it never sees a message object); these values
are the MAVLink common dialect's, and ``tests/unit/sitl/test_sitl_protocol_and_modes.py``
checks every one of them against pymavlink's generated constants.
"""

from __future__ import annotations

import enum

__all__ = [
    "AttitudeTargetMask",
    "LandedState",
    "MavCmd",
    "MavFrame",
    "MavMissionResult",
    "MavProtocolCapability",
    "MavResult",
    "MavSeverity",
    "MavState",
    "MissionState",
    "MsgId",
    "PositionTargetMask",
]


class MavCmd(enum.IntEnum):
    NAV_WAYPOINT = 16
    NAV_LOITER_UNLIM = 17
    NAV_LOITER_TURNS = 18
    NAV_LOITER_TIME = 19
    NAV_RETURN_TO_LAUNCH = 20
    NAV_LAND = 21
    NAV_TAKEOFF = 22
    NAV_LOITER_TO_ALT = 31
    DO_ORBIT = 34
    NAV_DELAY = 93
    CONDITION_DELAY = 112
    CONDITION_YAW = 115
    DO_SET_MODE = 176
    DO_JUMP = 177
    DO_CHANGE_SPEED = 178
    DO_SET_HOME = 179
    DO_LAND_START = 189
    DO_REPOSITION = 192
    DO_SET_ROI_LOCATION = 195
    DO_SET_ROI_NONE = 197
    DO_DIGICAM_CONTROL = 203
    DO_MOUNT_CONFIGURE = 204
    DO_MOUNT_CONTROL = 205
    DO_SET_CAM_TRIGG_DIST = 206
    DO_SET_CAM_TRIGG_INTERVAL = 214
    DO_SET_MISSION_CURRENT = 224
    MISSION_START = 300
    COMPONENT_ARM_DISARM = 400
    GET_HOME_POSITION = 410
    INJECT_FAILURE = 420
    GET_MESSAGE_INTERVAL = 510
    SET_MESSAGE_INTERVAL = 511
    REQUEST_MESSAGE = 512
    REQUEST_AUTOPILOT_CAPABILITIES = 520
    SET_CAMERA_MODE = 530
    SET_CAMERA_ZOOM = 531
    SET_CAMERA_FOCUS = 532
    DO_GIMBAL_MANAGER_PITCHYAW = 1000
    DO_GIMBAL_MANAGER_CONFIGURE = 1001
    IMAGE_START_CAPTURE = 2000
    IMAGE_STOP_CAPTURE = 2001
    VIDEO_START_CAPTURE = 2500
    VIDEO_STOP_CAPTURE = 2501
    NAV_FENCE_POLYGON_VERTEX_INCLUSION = 5001
    NAV_FENCE_POLYGON_VERTEX_EXCLUSION = 5002
    NAV_FENCE_CIRCLE_INCLUSION = 5003
    NAV_FENCE_CIRCLE_EXCLUSION = 5004
    NAV_RALLY_POINT = 5100
    USER_1 = 31010


SIM_STEP = MavCmd.USER_1
"""The simulation link's lockstep grant (docs/architecture.md)."""

FORCE_ARM_MAGIC = 21196.0


class MavProtocolCapability(enum.IntFlag):
    """``MAV_PROTOCOL_CAPABILITY`` bits (AUTOPILOT_VERSION.capabilities)."""

    MISSION_FLOAT = 1
    PARAM_FLOAT = 2
    MISSION_INT = 4
    COMMAND_INT = 8
    PARAM_ENCODE_BYTEWISE = 16
    FTP = 32
    SET_ATTITUDE_TARGET = 64
    SET_POSITION_TARGET_LOCAL_NED = 128
    SET_POSITION_TARGET_GLOBAL_INT = 256
    TERRAIN = 512
    FLIGHT_TERMINATION = 2048
    COMPASS_CALIBRATION = 4096
    MAVLINK2 = 8192
    MISSION_FENCE = 16384
    MISSION_RALLY = 32768
    PARAM_ENCODE_C_CAST = 131072


class MavResult(enum.IntEnum):
    ACCEPTED = 0
    TEMPORARILY_REJECTED = 1
    DENIED = 2
    UNSUPPORTED = 3
    FAILED = 4
    IN_PROGRESS = 5


class MavFrame(enum.IntEnum):
    GLOBAL = 0
    LOCAL_NED = 1
    MISSION = 2
    GLOBAL_RELATIVE_ALT = 3
    GLOBAL_INT = 5
    GLOBAL_RELATIVE_ALT_INT = 6
    LOCAL_OFFSET_NED = 7
    BODY_NED = 8
    BODY_OFFSET_NED = 9
    GLOBAL_TERRAIN_ALT = 10
    GLOBAL_TERRAIN_ALT_INT = 11


class MavMissionResult(enum.IntEnum):
    ACCEPTED = 0
    ERROR = 1
    UNSUPPORTED_FRAME = 2
    UNSUPPORTED = 3
    NO_SPACE = 4
    INVALID = 5
    INVALID_PARAM1 = 6
    INVALID_PARAM2 = 7
    INVALID_PARAM3 = 8
    INVALID_PARAM4 = 9
    INVALID_PARAM5_X = 10
    INVALID_PARAM6_Y = 11
    INVALID_PARAM7 = 12
    INVALID_SEQUENCE = 13
    DENIED = 14
    OPERATION_CANCELLED = 15


class MavSeverity(enum.IntEnum):
    EMERGENCY = 0
    ALERT = 1
    CRITICAL = 2
    ERROR = 3
    WARNING = 4
    NOTICE = 5
    INFO = 6
    DEBUG = 7


class MavState(enum.IntEnum):
    UNINIT = 0
    BOOT = 1
    CALIBRATING = 2
    STANDBY = 3
    ACTIVE = 4
    CRITICAL = 5
    EMERGENCY = 6
    POWEROFF = 7
    FLIGHT_TERMINATION = 8


class LandedState(enum.IntEnum):
    UNDEFINED = 0
    ON_GROUND = 1
    IN_AIR = 2
    TAKEOFF = 3
    LANDING = 4


class MissionState(enum.IntEnum):
    UNKNOWN = 0
    NO_MISSION = 1
    NOT_STARTED = 2
    ACTIVE = 3
    PAUSED = 4
    COMPLETE = 5


class PositionTargetMask(enum.IntFlag):
    """``type_mask`` bits of SET_POSITION_TARGET_*: a set bit means *ignore*."""

    X_IGNORE = 1
    Y_IGNORE = 2
    Z_IGNORE = 4
    VX_IGNORE = 8
    VY_IGNORE = 16
    VZ_IGNORE = 32
    AX_IGNORE = 64
    AY_IGNORE = 128
    AZ_IGNORE = 256
    FORCE_SET = 512
    YAW_IGNORE = 1024
    YAW_RATE_IGNORE = 2048


class AttitudeTargetMask(enum.IntFlag):
    """``type_mask`` bits of SET_ATTITUDE_TARGET: a set bit means *ignore*."""

    BODY_ROLL_RATE_IGNORE = 1
    BODY_PITCH_RATE_IGNORE = 2
    BODY_YAW_RATE_IGNORE = 4
    THRUST_BODY_SET = 32
    THROTTLE_IGNORE = 64
    ATTITUDE_IGNORE = 128


class MsgId(enum.IntEnum):
    """Message ids the autopilot produces or that commands refer to."""

    HEARTBEAT = 0
    SYS_STATUS = 1
    SYSTEM_TIME = 2
    PING = 4
    PARAM_VALUE = 22
    GPS_RAW_INT = 24
    ATTITUDE = 30
    ATTITUDE_QUATERNION = 31
    LOCAL_POSITION_NED = 32
    GLOBAL_POSITION_INT = 33
    MISSION_CURRENT = 42
    GPS_GLOBAL_ORIGIN = 49
    VFR_HUD = 74
    ATTITUDE_TARGET = 83
    POSITION_TARGET_LOCAL_NED = 85
    HIGHRES_IMU = 105
    TIMESYNC = 111
    ALTITUDE = 141
    FOLLOW_TARGET = 144
    BATTERY_STATUS = 147
    AUTOPILOT_VERSION = 148
    HOME_POSITION = 242
    MESSAGE_INTERVAL = 244
    EXTENDED_SYS_STATE = 245
    STATUSTEXT = 253
    ODOMETRY = 331

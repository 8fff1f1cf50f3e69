"""Failures injected in flight, as PX4's ``MAV_CMD_INJECT_FAILURE`` (420) does them.

PX4 accepts the command only with ``SYS_FAILURE_EN`` = 1 (else DENIED); param1 is the MAVLink
``FAILURE_UNIT``, param2 the ``FAILURE_TYPE``, param3 the instance (0 = all). What this SITL models, and
how the vehicle reacts (as PX4 would):

* ``SENSOR_GPS`` ``OFF``: no fix (GPS_RAW_INT, SYS_STATUS); the estimate dead-reckons for
  :data:`NO_AID_TIMEOUT_S` (PX4's ``EKF2_NOAID_TOUT``), then the local position is invalid: the
  position-estimate failsafe descends without position control (PX4's Descend, reported as AUTO.LAND),
  position modes are refused, LOCAL_POSITION_NED, GLOBAL_POSITION_INT and ODOMETRY stop.
* ``SYSTEM_BATTERY`` ``OFF``: the battery reads empty (PX4's battery simulator ``force empty``): the
  battery failsafes act (critical: land).
* ``SYSTEM_MOTOR`` ``OFF``: that motor (1..4, PX4 quad-X order; 0 = all) stops; ``WRONG``: it delivers
  :data:`MOTOR_WRONG_FACTOR` of the commanded ESC duty (a damaged propeller or a failing ESC).
* ``OK`` on any of these units clears it.

Every other unit/type pair (gyro, accel, mag, baro, airspeed, optical flow, RC and MAVLink signal, stuck,
garbage, slow, delayed, intermittent...) is answered ``UNSUPPORTED``: not modelled.
"""

from __future__ import annotations

import enum
from dataclasses import dataclass

__all__ = [
    "MOTOR_COUNT",
    "MOTOR_WRONG_FACTOR",
    "NO_AID_TIMEOUT_S",
    "FailureType",
    "FailureUnit",
    "FaultState",
    "InjectOutcome",
]

#: PX4's EKF2_NOAID_TOUT: without GPS the horizontal position is dead-reckoned this long, then invalid.
NO_AID_TIMEOUT_S = 5.0
#: A motor with a WRONG failure delivers this fraction of its commanded ESC duty.
MOTOR_WRONG_FACTOR = 0.7
MOTOR_COUNT = 4


class FailureUnit(enum.IntEnum):
    """MAVLink FAILURE_UNIT."""

    SENSOR_GYRO = 0
    SENSOR_ACCEL = 1
    SENSOR_MAG = 2
    SENSOR_BARO = 3
    SENSOR_GPS = 4
    SENSOR_OPTICAL_FLOW = 5
    SENSOR_VIO = 6
    SENSOR_DISTANCE_SENSOR = 7
    SENSOR_AIRSPEED = 8
    SYSTEM_BATTERY = 100
    SYSTEM_MOTOR = 101
    SYSTEM_SERVO = 102
    SYSTEM_AVOIDANCE = 103
    SYSTEM_RC_SIGNAL = 104
    SYSTEM_MAVLINK_SIGNAL = 105


class FailureType(enum.IntEnum):
    """MAVLink FAILURE_TYPE."""

    OK = 0
    OFF = 1
    STUCK = 2
    GARBAGE = 3
    WRONG = 4
    SLOW = 5
    DELAYED = 6
    INTERMITTENT = 7


#: The unit/type pairs this SITL models (OK clears any of them).
MODELLED: dict[FailureUnit, frozenset[FailureType]] = {
    FailureUnit.SENSOR_GPS: frozenset({FailureType.OK, FailureType.OFF}),
    FailureUnit.SYSTEM_BATTERY: frozenset({FailureType.OK, FailureType.OFF}),
    FailureUnit.SYSTEM_MOTOR: frozenset({FailureType.OK, FailureType.OFF, FailureType.WRONG}),
}


class InjectOutcome(enum.Enum):
    ACCEPTED = "accepted"
    UNSUPPORTED = "unsupported"
    INVALID = "invalid"


@dataclass(frozen=True)
class _Result:
    outcome: InjectOutcome
    text: str


class FaultState:
    """The failures in force; the physics, the estimator and the autopilot read it."""

    def __init__(self) -> None:
        self.gps_off = False
        self.battery_off = False
        self.motor_factors: tuple[float, float, float, float] = (1.0, 1.0, 1.0, 1.0)
        self.injected = 0

    @property
    def motors_degraded(self) -> bool:
        return self.motor_factors != (1.0, 1.0, 1.0, 1.0)

    @property
    def any(self) -> bool:
        return self.gps_off or self.battery_off or self.motors_degraded

    def describe(self) -> list[str]:
        """The failures in force, e.g. ``["gps off", "motor 1 wrong (0.7)"]``."""
        out = []
        if self.gps_off:
            out.append("gps off")
        if self.battery_off:
            out.append("battery off")
        for i, f in enumerate(self.motor_factors):
            if f == 0.0:
                out.append(f"motor {i + 1} off")
            elif f != 1.0:
                out.append(f"motor {i + 1} wrong ({f:g})")
        return out

    def inject(self, unit: int, failure_type: int, instance: int) -> _Result:
        """Apply one MAV_CMD_INJECT_FAILURE (already allowed by SYS_FAILURE_EN)."""
        try:
            u = FailureUnit(unit)
        except ValueError:
            return _Result(InjectOutcome.UNSUPPORTED, f"Failure injection: unknown unit {unit}")
        try:
            t = FailureType(failure_type)
        except ValueError:
            return _Result(InjectOutcome.UNSUPPORTED, f"Failure injection: unknown type {failure_type}")
        what = f"{u.name.lower()} {t.name.lower()}"
        if t not in MODELLED.get(u, frozenset()):
            return _Result(InjectOutcome.UNSUPPORTED, f"Failure injection: {what} is not simulated")
        if u is FailureUnit.SYSTEM_MOTOR:
            if not 0 <= instance <= MOTOR_COUNT:
                return _Result(
                    InjectOutcome.INVALID, f"Failure injection: no motor {instance} (1..{MOTOR_COUNT}, 0 all)"
                )
            factor = {FailureType.OK: 1.0, FailureType.OFF: 0.0, FailureType.WRONG: MOTOR_WRONG_FACTOR}[t]
            factors = list(self.motor_factors)
            for i in range(MOTOR_COUNT):
                if instance in (0, i + 1):
                    factors[i] = factor
            self.motor_factors = (factors[0], factors[1], factors[2], factors[3])
            what = f"motor {instance or 'all'} {t.name.lower()}"
        elif u is FailureUnit.SENSOR_GPS:
            self.gps_off = t is FailureType.OFF
        else:
            self.battery_off = t is FailureType.OFF
        self.injected += 1
        return _Result(InjectOutcome.ACCEPTED, f"Failure injected: {what}")

"""Failures injected in flight, as PX4's ``MAV_CMD_INJECT_FAILURE`` (420) does them.

PX4 accepts the command only with ``SYS_FAILURE_EN`` = 1 (else DENIED); param1 is the MAVLink
``FAILURE_UNIT``, param2 the ``FAILURE_TYPE``, param3 the instance (0 = all). What this SITL models, and
how the vehicle reacts (as PX4 would):

* ``SENSOR_GPS`` ``OFF``: no fix (GPS_RAW_INT, SYS_STATUS); the estimate dead-reckons for
  :data:`NO_AID_TIMEOUT_S` (PX4's ``EKF2_NOAID_TOUT``), then the local position is invalid: the
  position-estimate failsafe descends without position control (PX4's Descend, reported as AUTO.LAND),
  position modes are refused, LOCAL_POSITION_NED, GLOBAL_POSITION_INT and ODOMETRY stop.
* ``SENSOR_GPS`` ``STUCK``: the receiver repeats its last fix (position and velocity; PX4's GPS failure
  injector re-publishes its last sample). EKF2 fuses it while its innovation passes the gate
  (:data:`GPS_POS_GATE_SD` standard deviations of the reported accuracy, at least
  :data:`GPS_POS_NOISE_MIN_M`: ``EKF2_GPS_P_GATE``, ``EKF2_GPS_P_NOISE``), so the estimate is held near
  the frozen position (over :data:`GPS_FUSION_TIME_CONSTANT_S`) and a hovering vehicle notices nothing; a
  vehicle told to move accelerates with its estimate lagging until the innovation leaves the gate, then
  the fix is rejected, the estimate dead-reckons and, :data:`NO_AID_TIMEOUT_S` after the last accepted
  sample, the position is invalid and the failsafe descends as for OFF. GPS_RAW_INT repeats the frozen
  fix (3D); SYS_STATUS reports the GPS unhealthy while its samples are rejected.
* ``SENSOR_GPS`` ``GARBAGE``: the receiver reports random positions anywhere on Earth (GPS_RAW_INT shows
  them, with a 3D fix); every sample fails the innovation gate at once, so the estimate behaves as for OFF
  (dead reckoning, invalid after :data:`NO_AID_TIMEOUT_S`, the failsafe descends); SYS_STATUS: GPS unhealthy.
* ``SENSOR_GPS`` ``INTERMITTENT``: the fix drops out and comes back, seeded (``estimator.seed``): fixes
  last :data:`INTERMITTENT_FIX_MEAN_S`, gaps :data:`INTERMITTENT_GAP_MEAN_S` on average (exponential).
  Each gap dead-reckons as OFF does; a gap shorter than :data:`NO_AID_TIMEOUT_S` keeps the position
  valid and the vehicle flies on, a longer one makes it invalid and the failsafe descends.
* ``SYSTEM_BATTERY`` ``OFF``: the battery reads empty (PX4's battery simulator ``force empty``): the
  battery failsafes act (critical: land).
* ``SYSTEM_MOTOR`` ``OFF``: that motor (1..4, PX4 quad-X order; 0 = all) stops; ``WRONG``: it delivers
  :data:`MOTOR_WRONG_FACTOR` of the commanded ESC duty (a damaged propeller or a failing ESC).
* ``SENSOR_BARO`` and ``SENSOR_MAG`` ``OFF``, ``STUCK``, ``GARBAGE``, ``INTERMITTENT``: what the sensor reports
  (HIGHRES_IMU) and how EKF2 on a multicopter with one baro and one compass reacts, modelled in
  :mod:`sitl.core.estimator`: a baro that stops or is rejected by its innovation gate (:data:`BARO_GATE_SD`
  times :data:`BARO_NOISE_M`) leaves the height to the GNSS (EKF2_HGT_REF's fallback), a compass that stops
  or is rejected (:data:`MAG_GATE_SD` times :data:`MAG_NOISE_GAUSS`) leaves the heading to the gyro, aligned
  by the GNSS velocity once the vehicle moves (EKF-GSF). Neither triggers a failsafe while the GPS is good.
* ``OK`` on any of these units clears it; a new type replaces the one in force on its unit.

PX4 itself (its GPS failure injector, 2025) knows GPS OFF, STUCK and WRONG; GARBAGE and INTERMITTENT are
this SITL's, with the reaction PX4's EKF2 has to such data. Not modelled of EKF2: after 7 s of rejected
samples it resets its position to the GPS (to the frozen fix for STUCK) and fuses again; here the estimate
stays invalid until the fault is cleared.

Every other unit/type pair (gyro, accel, airspeed, optical flow, RC and MAVLink signal, GPS
wrong, slow or delayed...) is answered ``UNSUPPORTED``: not modelled.
"""

from __future__ import annotations

import enum
import math
from dataclasses import dataclass

__all__ = [
    "BARO_GATE_SD",
    "BARO_NOISE_M",
    "EARTH_FIELD_NED_GAUSS",
    "GARBAGE_ALT_RANGE_M",
    "GPS_FUSION_TIME_CONSTANT_S",
    "GPS_POS_GATE_SD",
    "GPS_POS_NOISE_MIN_M",
    "GYRO_YAW_DRIFT_SD_RADPS",
    "HGT_FUSION_TIMEOUT_S",
    "INTERMITTENT_FIX_MEAN_S",
    "INTERMITTENT_GAP_MEAN_S",
    "MAG_FUSION_TIME_CONSTANT_S",
    "MAG_GATE_SD",
    "MAG_HEADING_GATE_RAD",
    "MAG_NOISE_GAUSS",
    "MOTOR_COUNT",
    "MOTOR_WRONG_FACTOR",
    "NO_AID_TIMEOUT_S",
    "YAW_GNSS_ALIGN_MIN_SPEED_MPS",
    "YAW_GNSS_ALIGN_TIME_CONSTANT_S",
    "FailureType",
    "FailureUnit",
    "FaultState",
    "InjectOutcome",
]

#: PX4's EKF2_NOAID_TOUT: without GPS the horizontal position is dead-reckoned this long, then invalid.
NO_AID_TIMEOUT_S = 5.0
#: PX4's EKF2_GPS_P_GATE: a GPS position sample whose innovation exceeds this many standard deviations is rejected.
GPS_POS_GATE_SD = 5.0
#: PX4's EKF2_GPS_P_NOISE: the floor of the GPS position noise the gate is scaled by (m).
GPS_POS_NOISE_MIN_M = 0.5
#: How fast an accepted (stuck) fix pulls the estimate to itself: about EKF2's settling on a 5 Hz GPS.
GPS_FUSION_TIME_CONSTANT_S = 1.0
#: INTERMITTENT: mean length of a fix and of a gap (exponentially distributed, seeded).
INTERMITTENT_FIX_MEAN_S = 3.0
INTERMITTENT_GAP_MEAN_S = 1.0
#: GARBAGE: the range of the random altitudes reported (m AMSL).
GARBAGE_ALT_RANGE_M = (-1000.0, 10000.0)
#: PX4's EKF2_BARO_GATE: a baro height sample whose innovation exceeds this many standard deviations is rejected.
BARO_GATE_SD = 5.0
#: PX4's EKF2_BARO_NOISE (m): the baro height's measurement noise (so the gate is 17.5 m).
BARO_NOISE_M = 3.5
#: EKF2's hgt_fusion_timeout_max: baro height fusion failing this long stops it for good (baro_fault).
HGT_FUSION_TIMEOUT_S = 5.0
#: PX4's EKF2_MAG_GATE and EKF2_MAG_NOISE (gauss): the 3-axis magnetometer fusion's innovation gate.
MAG_GATE_SD = 3.0
MAG_NOISE_GAUSS = 0.05
#: The Earth's field (gauss, NED) the simulated magnetometer measures (central Europe: 0.48 gauss, 63 deg down).
EARTH_FIELD_NED_GAUSS = (0.216, 0.0, 0.423)
#: The heading error whose horizontal-field innovation leaves that gate: 2 asin(gate / 2H), about 40.6 deg.
MAG_HEADING_GATE_RAD = 2.0 * math.asin(min(1.0, MAG_GATE_SD * MAG_NOISE_GAUSS / (2.0 * EARTH_FIELD_NED_GAUSS[0])))
#: How fast fused compass samples pull the heading: sqrt(R / q) for the horizontal-field noise (0.05 / 0.216 rad)
#: at 50 Hz against EKF2_GYR_NOISE (0.015 rad/s/sqrt(Hz)) process noise, about 2 s.
MAG_FUSION_TIME_CONSTANT_S = 2.0
#: Without the compass the heading integrates the gyro: the residual z-gyro bias EKF2 had not learned
#: (drawn once per failure, this standard deviation: 0.02 deg/s, 72 deg/h; an assumption for a MEMS IMU).
GYRO_YAW_DRIFT_SD_RADPS = math.radians(0.02)
#: Moving at least this fast, GNSS velocity with the vehicle's accelerations makes the heading observable
#: (EKF2's fusion and its EKF-GSF yaw estimator): the heading error then decays over this time constant.
YAW_GNSS_ALIGN_MIN_SPEED_MPS = 1.0
YAW_GNSS_ALIGN_TIME_CONSTANT_S = 10.0
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
    FailureUnit.SENSOR_GPS: frozenset(
        {FailureType.OK, FailureType.OFF, FailureType.STUCK, FailureType.GARBAGE, FailureType.INTERMITTENT}
    ),
    FailureUnit.SENSOR_MAG: frozenset(
        {FailureType.OK, FailureType.OFF, FailureType.STUCK, FailureType.GARBAGE, FailureType.INTERMITTENT}
    ),
    FailureUnit.SENSOR_BARO: frozenset(
        {FailureType.OK, FailureType.OFF, FailureType.STUCK, FailureType.GARBAGE, FailureType.INTERMITTENT}
    ),
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
        #: The GPS failure in force (OK: none).
        self.gps = FailureType.OK
        #: The compass and barometer failures in force (OK: none).
        self.mag = FailureType.OK
        self.baro = FailureType.OK
        self.battery_off = False
        self.motor_factors: tuple[float, float, float, float] = (1.0, 1.0, 1.0, 1.0)
        self.injected = 0

    @property
    def gps_off(self) -> bool:
        return self.gps is FailureType.OFF

    @property
    def motors_degraded(self) -> bool:
        return self.motor_factors != (1.0, 1.0, 1.0, 1.0)

    @property
    def any(self) -> bool:
        return (
            self.gps is not FailureType.OK
            or self.mag is not FailureType.OK
            or self.baro is not FailureType.OK
            or self.battery_off
            or self.motors_degraded
        )

    def describe(self) -> list[str]:
        """The failures in force, e.g. ``["gps stuck", "motor 1 wrong (0.7)"]``."""
        out = []
        if self.gps is not FailureType.OK:
            out.append(f"gps {self.gps.name.lower()}")
        if self.mag is not FailureType.OK:
            out.append(f"mag {self.mag.name.lower()}")
        if self.baro is not FailureType.OK:
            out.append(f"baro {self.baro.name.lower()}")
        if self.battery_off:
            out.append("battery off")
        for i, f in enumerate(self.motor_factors):
            if f == 0.0:
                out.append(f"motor {i + 1} off")
            elif f != 1.0:
                out.append(f"motor {i + 1} wrong ({f:g})")
        return out

    def _sensor(self, unit: FailureUnit, failure_type: FailureType, instance: int) -> _Result | None:
        """A compass or baro failure; a refusal if ``instance`` is not this vehicle's one sensor."""
        if instance not in (0, 1):  # one compass and one barometer (PX4 numbers instances from 1; 0 = all)
            return _Result(InjectOutcome.INVALID, f"Failure injection: no {unit.name.lower()} {instance} (1, 0 all)")
        if unit is FailureUnit.SENSOR_MAG:
            self.mag = failure_type
        else:
            self.baro = failure_type
        return None

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
            self.gps = t
        elif u in (FailureUnit.SENSOR_MAG, FailureUnit.SENSOR_BARO):
            refused = self._sensor(u, t, instance)
            if refused is not None:
                return refused
        else:
            self.battery_off = t is FailureType.OFF
        self.injected += 1
        return _Result(InjectOutcome.ACCEPTED, f"Failure injected: {what}")

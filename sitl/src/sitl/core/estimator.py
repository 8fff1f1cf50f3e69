"""State estimate: the truth, or the truth plus seeded noise, bias, heading error and GPS dropouts.

Noise is first-order Gauss-Markov (exponentially correlated over
``noise_correlation_s``), which looks like an EKF's wander rather than white
jitter; the bias is drawn once per run. The heading (yaw) has its own error, as
a magnetometer-derived heading is much worse than roll and pitch: a bias drawn
once per run (compass calibration, declination, nearby metal) plus a slow
Gauss-Markov wander (``heading_correlation_s``). During a GPS dropout the
horizontal error drifts at ``dropout_drift_mps`` in a random direction and
``gps_ok`` is false (GPS_RAW_INT reports no fix); afterwards the error converges
back. The presets that fill these numbers in (rtk, gps, poor_gps) are in
:mod:`sitl.config`.

An injected GPS failure (:mod:`sitl.core.faults`) is set by the vehicle in
:attr:`Estimator.gps_fault` before each update: OFF and GARBAGE dead-reckon,
STUCK is fused through PX4 EKF2's innovation gate until rejected, INTERMITTENT
drops the fix in and out. All randomness comes from ``numpy.random.Generator``\\ s
seeded from the config: the noise of the original model from ``seed`` itself
(its draws are unchanged by the newer terms), the heading error and the faults
from independent streams spawned from the same seed.

Injected compass and barometer failures (:attr:`Estimator.mag_fault`, :attr:`Estimator.baro_fault`) change
what those sensors report (:attr:`Estimator.mag_report_body`, :attr:`Estimator.baro_report_alt_m`, and
whether they report at all) and the estimate as EKF2 would on a multicopter with one of each and a good GPS:

* Baro: while EKF2 fuses it (the height reference, ``EKF2_HGT_REF`` = baro) the height is the noise model's.
  Without it (OFF, a gap of INTERMITTENT, GARBAGE or a STUCK reading outside the innovation gate of
  ``EKF2_BARO_GATE`` x ``EKF2_BARO_NOISE`` = 17.5 m) the height comes from the GNSS alone: a Gauss-Markov
  error of the GNSS height's standard deviation (:attr:`Estimator.gnss_height_sd_m`, 1.5 times the
  horizontal) grows from zero over the noise model's correlation time. A STUCK reading inside the gate is
  blended in with its weight against the GNSS height's (1 / 3.5^2 against 1 / sd^2), so a climb or descent
  drags the estimate a little towards the frozen height until the innovation leaves the gate; rejected for
  ``hgt_fusion_timeout_max`` (5 s) EKF2 stops baro fusion for good (baro_fault) until the fault is cleared.
* Compass: while EKF2 fuses it the heading error is the compass's (the noise model's heading bias and
  wander). Without it (OFF, a gap, GARBAGE, or a STUCK field whose heading innovation leaves the
  ``EKF2_MAG_GATE`` x ``EKF2_MAG_NOISE`` gate, about 40 degrees) the heading integrates the gyro: its error
  drifts at a residual gyro bias drawn once per failure; moving at 1 m/s or more, GNSS velocity makes
  the heading observable (EKF2's fusion and its EKF-GSF yaw estimator) and the error decays over 10 s. A
  STUCK field inside the gate pulls the heading towards the frozen one over about 2 s: a slow yaw is
  followed by the estimate only partly, a fast one is rejected. A compass that comes back pulls the
  heading back to its own error over the same 2 s.

Both draw from their own spawned streams, so they do not change the other draws.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

from sitl.core.faults import (
    BARO_GATE_SD,
    BARO_NOISE_M,
    EARTH_FIELD_NED_GAUSS,
    GARBAGE_ALT_RANGE_M,
    GPS_FUSION_TIME_CONSTANT_S,
    GPS_POS_GATE_SD,
    GPS_POS_NOISE_MIN_M,
    GYRO_YAW_DRIFT_SD_RADPS,
    HGT_FUSION_TIMEOUT_S,
    INTERMITTENT_FIX_MEAN_S,
    INTERMITTENT_GAP_MEAN_S,
    MAG_FUSION_TIME_CONSTANT_S,
    MAG_HEADING_GATE_RAD,
    NO_AID_TIMEOUT_S,
    YAW_GNSS_ALIGN_MIN_SPEED_MPS,
    YAW_GNSS_ALIGN_TIME_CONSTANT_S,
    FailureType,
)
from sitl.core.state import LocalState, VehicleState
from uav_common.geo import GeoPoint, LocalProjection

__all__ = ["RTK_FIXED_MAX_ERROR_M", "Estimator", "GpsReport", "NoiseModel", "field_in_body"]

#: GPS_RAW_INT reports an RTK fixed solution when the configured horizontal error (noise and bias) is this small.
RTK_FIXED_MAX_ERROR_M = 0.05
#: What the receiver reports without a configured error model (the truth): u-blox-like accuracies.
_TRUTH_H_ACC_M = 0.5
_TRUTH_V_ACC_M = 0.8
#: Without a configured error model, the GNSS height's error wanders over this time.
_TRUTH_CORRELATION_S = 30.0

_OFF = int(FailureType.OFF)
_STUCK = int(FailureType.STUCK)
_GARBAGE = int(FailureType.GARBAGE)
_INTERMITTENT = int(FailureType.INTERMITTENT)


@dataclass(frozen=True)
class NoiseModel:
    horizontal_noise_m: float
    vertical_noise_m: float
    velocity_noise_mps: float
    attitude_noise_rad: float
    noise_correlation_s: float
    horizontal_bias_m: float
    vertical_bias_m: float
    gps_dropouts_per_hour: float
    gps_dropout_duration_s: float
    dropout_drift_mps: float
    heading_bias_rad: float = 0.0
    heading_noise_rad: float = 0.0
    heading_correlation_s: float = 60.0

    @property
    def horizontal_error_m(self) -> float:
        """The per-axis standard deviation of the horizontal error (wander and bias, outside dropouts)."""
        return math.hypot(self.horizontal_noise_m, self.horizontal_bias_m)

    @property
    def vertical_error_m(self) -> float:
        return math.hypot(self.vertical_noise_m, self.vertical_bias_m)


@dataclass(frozen=True, slots=True)
class GpsReport:
    """What the receiver reports when it differs from the estimate (an injected STUCK or GARBAGE failure)."""

    lat_deg: float
    lon_deg: float
    alt_amsl_m: float
    vel_n_mps: float
    vel_e_mps: float


class _Intermittent:
    """A sensor that drops out and comes back (FAILURE_TYPE INTERMITTENT): fixes and gaps of exponential length,
    :data:`INTERMITTENT_FIX_MEAN_S` and :data:`INTERMITTENT_GAP_MEAN_S` on average, drawn from ``rng``."""

    __slots__ = ("gaps", "in_gap", "rng", "until_s")

    def __init__(self, rng: np.random.Generator) -> None:
        self.rng = rng
        self.in_gap = False
        self.until_s = 0.0
        #: Gaps so far.
        self.gaps = 0

    def restart(self, t_s: float) -> None:
        """A new fault (or OK): a fix now, the next phase drawn at once."""
        self.in_gap = False
        self.until_s = t_s

    def step(self, t_s: float) -> bool:
        """Whether the sensor is in a gap at ``t_s`` (called every update while the fault is in force)."""
        if t_s >= self.until_s:
            self.in_gap = not self.in_gap
            mean = INTERMITTENT_GAP_MEAN_S if self.in_gap else INTERMITTENT_FIX_MEAN_S
            self.until_s = t_s + float(self.rng.exponential(mean))
            if self.in_gap:
                self.gaps += 1
        return self.in_gap


class Estimator:
    """Produces the :class:`LocalState` the autopilot flies on and reports."""

    RECOVERY_TIME_S = 2.0

    def __init__(self, projection: LocalProjection, noise: NoiseModel | None, seed: int = 0) -> None:
        self.projection = projection
        self.noise = noise
        self._rng = np.random.default_rng(seed)
        heading_seq, fault_seq, mag_seq, baro_seq = np.random.SeedSequence(seed).spawn(4)
        self._heading_rng = np.random.default_rng(heading_seq)
        self._fault_rng = np.random.default_rng(fault_seq)
        self._mag_rng = np.random.default_rng(mag_seq)
        self._baro_rng = np.random.default_rng(baro_seq)
        self._gm = np.zeros(9)  # correlated noise state: pos(3), vel(3), att(3)
        self._heading_bias = 0.0
        self._heading_gm = 0.0
        self._heading_on = False
        if noise is not None:
            bh = self._rng.normal(0.0, noise.horizontal_bias_m, 2)
            bv = self._rng.normal(0.0, noise.vertical_bias_m)
            self._bias = (float(bh[0]), float(bh[1]), float(bv))
            self._heading_on = noise.heading_bias_rad > 0.0 or noise.heading_noise_rad > 0.0
            if self._heading_on:
                self._heading_bias = float(self._heading_rng.normal(0.0, noise.heading_bias_rad))
                self._heading_gm = float(self._heading_rng.normal(0.0, noise.heading_noise_rad))
            self.h_acc_m = max(0.01, noise.horizontal_error_m)
            self.v_acc_m = max(0.01, noise.vertical_error_m)
        else:
            self._bias = (0.0, 0.0, 0.0)
            self.h_acc_m = _TRUTH_H_ACC_M
            self.v_acc_m = _TRUTH_V_ACC_M
        #: GPS_RAW_INT's fix type while the receiver has a fix: 6 (RTK fixed) for an RTK-grade model, else 3 (3D).
        self.fix_type = 6 if noise is not None and noise.horizontal_error_m <= RTK_FIXED_MAX_ERROR_M else 3
        #: EKF2's GPS position innovation gate (EKF2_GPS_P_GATE standard deviations of the reported accuracy).
        self.gate_m = GPS_POS_GATE_SD * max(GPS_POS_NOISE_MIN_M, self.h_acc_m)
        self._dropout_until = -1.0
        self._drift = (0.0, 0.0)
        self._drift_error = [0.0, 0.0]
        self._last_t: float | None = None
        self.dropouts = 0
        #: An injected GPS failure (a MAVLink FAILURE_TYPE value, 0 = none): set by the vehicle before each update.
        self.gps_fault = 0
        #: What the receiver reports when it is not the estimate (STUCK, GARBAGE); None otherwise.
        self.gps_report: GpsReport | None = None
        #: STUCK: samples of the frozen fix the innovation gate rejected so far.
        self.rejected_samples = 0
        self._fault_seen = 0
        self._gps_failed_since: float | None = None
        self._dead_reckoned: tuple[float, float] | None = None
        self._stuck_fix: tuple[float, float] | None = None
        self._stuck_pos = (0.0, 0.0)
        self._stuck_fused_t = 0.0
        self._gps_gaps = _Intermittent(self._fault_rng)
        self._init_sensor_faults(noise)

    def _init_sensor_faults(self, noise: NoiseModel | None) -> None:
        #: The GNSS height's error (per-axis sd, m) that the height shows once the baro is lost.
        self.gnss_height_sd_m = max(self.v_acc_m, 1.5 * self.h_acc_m)
        self._gnss_height_corr_s = noise.noise_correlation_s if noise is not None else _TRUTH_CORRELATION_S
        w_baro = 1.0 / (BARO_NOISE_M * BARO_NOISE_M)
        #: How much a (stuck) baro sample weighs in the height against the GNSS height.
        self.baro_weight = w_baro / (w_baro + 1.0 / (self.gnss_height_sd_m * self.gnss_height_sd_m))
        self.baro_gate_m = BARO_GATE_SD * BARO_NOISE_M
        #: Injected compass and baro failures (MAVLink FAILURE_TYPE values): set by the vehicle before each update.
        self.mag_fault = 0
        self.baro_fault = 0
        #: What the estimator wants announced (STATUSTEXT): the vehicle takes them.
        self.messages: list[str] = []
        #: The magnetometer's reading in the body frame (gauss) when it is not the estimate's (STUCK, GARBAGE).
        self.mag_report_body: tuple[float, float, float] | None = None
        #: False while the compass publishes nothing (OFF, a gap of INTERMITTENT).
        self.mag_reporting = True
        self.mag_rejected_samples = 0
        self._mag_on = False
        self._mag_seen = 0
        self._mag_fused = True
        self._mag_err = 0.0
        self._mag_drift = 0.0
        self._mag_stuck_yaw = 0.0
        self._mag_said = False
        self._mag_gaps = _Intermittent(self._mag_rng)
        #: The altitude (m AMSL) whose pressure the barometer reports when it is not the estimate's.
        self.baro_report_alt_m: float | None = None
        self.baro_reporting = True
        self.baro_rejected_samples = 0
        self._baro_on = False
        self._baro_seen = 0
        self._baro_fused = True
        self._baro_latched = False
        self._baro_rejected_since: float | None = None
        self._baro_pull = 0.0
        self._hgt_err = 0.0
        self._baro_stuck_d = 0.0
        self._baro_said = False
        self._baro_gaps = _Intermittent(self._baro_rng)

    @property
    def gaps(self) -> int:
        """GPS INTERMITTENT: fix gaps so far."""
        return self._gps_gaps.gaps

    @property
    def mag_gaps(self) -> int:
        return self._mag_gaps.gaps

    @property
    def baro_gaps(self) -> int:
        return self._baro_gaps.gaps

    @property
    def mag_healthy(self) -> bool:
        """Whether EKF2 fuses the compass (SYS_STATUS's 3D_MAG health)."""
        return self._mag_fused

    @property
    def baro_healthy(self) -> bool:
        """Whether EKF2 fuses the barometer (SYS_STATUS's ABSOLUTE_PRESSURE health)."""
        return self._baro_fused

    @property
    def gps_ok(self) -> bool:
        fault = self.gps_fault
        if fault in (_OFF, _GARBAGE) or (fault == _INTERMITTENT and self._gps_gaps.in_gap):
            return False
        return self._last_t is None or self._last_t >= self._dropout_until

    @property
    def heading_error_rad(self) -> float:
        """The present heading error beyond the attitude noise: the per-run bias plus the wander."""
        return self._heading_bias + self._heading_gm if self._heading_on else 0.0

    def _moved(self, est: LocalState, pos: tuple[float, float, float], gps_ok: bool, valid: bool) -> LocalState:
        """``est`` at another LOCAL_NED position (its geodetic position follows)."""
        s = est.full
        geo = self.projection.to_geo(*pos)
        full = VehicleState(
            s.t_s,
            geo.lat_deg,
            geo.lon_deg,
            geo.alt_amsl_m,
            s.vel_ned_mps,
            s.q_wxyz,
            s.euler_rad,
            s.rates_frd_radps,
            s.specific_force_frd_mps2,
            s.height_above_ground_m,
            s.gravity_mps2,
        )
        return LocalState(full, pos, gps_ok, valid)

    def _without_gps(self, t_s: float, est: LocalState, dt: float) -> LocalState:
        """No usable fix: the horizontal position is dead-reckoned on the velocity estimate from where the last
        fix left it, and invalid after :data:`NO_AID_TIMEOUT_S` (PX4's EKF2_NOAID_TOUT)."""
        if self._gps_failed_since is None or self._dead_reckoned is None:
            self._gps_failed_since = t_s
            self._dead_reckoned = (est.pos_ned_m[0], est.pos_ned_m[1])
        else:
            vn, ve, _ = est.vel_ned_mps
            self._dead_reckoned = (self._dead_reckoned[0] + vn * dt, self._dead_reckoned[1] + ve * dt)
        pos = (self._dead_reckoned[0], self._dead_reckoned[1], est.pos_ned_m[2])
        valid = t_s - self._gps_failed_since < NO_AID_TIMEOUT_S
        if pos == est.pos_ned_m:
            return LocalState(est.full, pos, False, valid)
        return self._moved(est, pos, False, valid)

    def _stuck(self, t_s: float, est: LocalState, dt: float) -> LocalState:
        """The receiver repeats its last fix: EKF2 fuses it while the innovation passes the gate, so the estimate
        is pulled to the frozen position; once the vehicle has moved away far enough the fix is rejected, the
        estimate dead-reckons, and it is invalid :data:`NO_AID_TIMEOUT_S` after the last accepted sample."""
        vn, ve, _ = est.vel_ned_mps
        if self._stuck_fix is None:
            s = est.full
            self._stuck_fix = (est.pos_ned_m[0], est.pos_ned_m[1])
            self._stuck_pos = self._stuck_fix
            self._stuck_fused_t = t_s
            self.gps_report = GpsReport(s.lat_deg, s.lon_deg, s.alt_amsl_m, vn, ve)
            accepted = True
        else:
            pn = self._stuck_pos[0] + vn * dt
            pe = self._stuck_pos[1] + ve * dt
            inn_n = self._stuck_fix[0] - pn
            inn_e = self._stuck_fix[1] - pe
            accepted = math.hypot(inn_n, inn_e) <= self.gate_m
            if accepted:
                k = min(1.0, dt / GPS_FUSION_TIME_CONSTANT_S)
                pn += k * inn_n
                pe += k * inn_e
                self._stuck_fused_t = t_s
            else:
                self.rejected_samples += 1
            self._stuck_pos = (pn, pe)
        valid = t_s - self._stuck_fused_t < NO_AID_TIMEOUT_S
        return self._moved(est, (self._stuck_pos[0], self._stuck_pos[1], est.pos_ned_m[2]), accepted, valid)

    def _with_fault(self, t_s: float, est: LocalState, dt: float) -> LocalState:
        fault = self.gps_fault
        if fault != self._fault_seen:  # a new fault: start it from the present estimate
            self._fault_seen = fault
            self._gps_failed_since = None
            self._stuck_fix = None
            self.gps_report = None
            self._gps_gaps.restart(t_s)
        if fault == _STUCK:
            return self._stuck(t_s, est, dt)
        if fault == _GARBAGE:
            r = self._fault_rng
            self.gps_report = GpsReport(
                float(r.uniform(-89.0, 89.0)),
                float(r.uniform(-180.0, 180.0)),
                float(r.uniform(GARBAGE_ALT_RANGE_M[0], GARBAGE_ALT_RANGE_M[1])),
                float(r.uniform(-50.0, 50.0)),
                float(r.uniform(-50.0, 50.0)),
            )
            return self._without_gps(t_s, est, dt)
        if fault == _INTERMITTENT:
            if self._gps_gaps.step(t_s):
                return self._without_gps(t_s, est, dt)
            self._gps_failed_since = None
            return est
        return self._without_gps(t_s, est, dt)  # OFF

    def _no_fault(self) -> None:
        self._gps_failed_since = None
        if self._fault_seen:
            self._fault_seen = 0
            self.gps_report = None
            self._gps_gaps.in_gap = False

    def update(self, truth: VehicleState, truth_ned_m: tuple[float, float, float] | None = None) -> LocalState:
        """The estimate for ``truth``; ``truth_ned_m`` is its LOCAL_NED position if already known."""
        if truth_ned_m is None:
            truth_ned_m = self.projection.to_ned(GeoPoint(truth.lat_deg, truth.lon_deg, truth.alt_amsl_m))
        n, e, d = truth_ned_m
        dt = 0.0 if self._last_t is None else max(0.0, truth.t_s - self._last_t)
        if self.noise is None:
            self._last_t = truth.t_s
            if self.gps_fault:
                out = self._with_fault(truth.t_s, LocalState(truth, (n, e, d), True), dt)
            else:
                self._no_fault()
                out = LocalState(truth, (n, e, d), True)
            if self.mag_fault or self.baro_fault or self._mag_on or self._baro_on:
                return self._sensor_faults(truth, out, dt)
            return out
        self._last_t = truth.t_s
        nm = self.noise
        self._step_noise(dt, nm)
        self._step_dropout(truth.t_s, dt, nm)
        gm = self._gm
        pos = (
            n + self._bias[0] + gm[0] + self._drift_error[0],
            e + self._bias[1] + gm[1] + self._drift_error[1],
            d + self._bias[2] + gm[2],
        )
        v = truth.vel_ned_mps
        vel = (v[0] + gm[3], v[1] + gm[4], v[2] + gm[5])
        roll, pitch, yaw = truth.euler_rad
        roll, pitch, yaw = roll + gm[6], pitch + gm[7], yaw + gm[8]
        if self._heading_on:
            self._step_heading(dt, nm)
            yaw += self._heading_bias + self._heading_gm
        q = _quat_from_euler(roll, pitch, yaw)
        geo = self.projection.to_geo(*pos)
        est = VehicleState(
            t_s=truth.t_s,
            lat_deg=geo.lat_deg,
            lon_deg=geo.lon_deg,
            alt_amsl_m=geo.alt_amsl_m,
            vel_ned_mps=vel,
            q_wxyz=q,
            euler_rad=(roll, pitch, (yaw + math.pi) % (2 * math.pi) - math.pi),
            rates_frd_radps=truth.rates_frd_radps,
            specific_force_frd_mps2=truth.specific_force_frd_mps2,
            height_above_ground_m=truth.height_above_ground_m,
            gravity_mps2=truth.gravity_mps2,
        )
        if self.gps_fault:
            # a fault replaces the receiver: a dropout of the noise model does not add to it
            out = self._with_fault(truth.t_s, LocalState(est, pos, True), dt)
        else:
            self._no_fault()
            out = LocalState(est, pos, self.gps_ok)
        if self.mag_fault or self.baro_fault or self._mag_on or self._baro_on:
            return self._sensor_faults(truth, out, dt)
        return out

    # ---- compass and barometer failures -------------------------------------------------------------------------

    def _sensor_faults(self, truth: VehicleState, est: LocalState, dt: float) -> LocalState:
        yaw_shift = self._mag_update(truth, est, dt) if self.mag_fault or self._mag_on else 0.0
        d_shift = self._baro_update(truth.t_s, est, dt) if self.baro_fault or self._baro_on else 0.0
        if yaw_shift == 0.0 and d_shift == 0.0:
            return est
        s = est.full
        n, e, d = est.pos_ned_m
        pos = (n, e, d + d_shift)
        geo = self.projection.to_geo(*pos) if d_shift != 0.0 else GeoPoint(s.lat_deg, s.lon_deg, s.alt_amsl_m)
        roll, pitch, yaw = s.euler_rad
        if yaw_shift != 0.0:
            yaw = _wrap(yaw + yaw_shift)
            q = _quat_from_euler(roll, pitch, yaw)
        else:
            q = s.q_wxyz
        full = VehicleState(
            s.t_s,
            geo.lat_deg,
            geo.lon_deg,
            geo.alt_amsl_m,
            s.vel_ned_mps,
            q,
            (roll, pitch, yaw),
            s.rates_frd_radps,
            s.specific_force_frd_mps2,
            s.height_above_ground_m,
            s.gravity_mps2,
        )
        return LocalState(full, pos, est.gps_ok, est.pos_valid)

    def _mag_update(self, truth: VehicleState, est: LocalState, dt: float) -> float:
        """The compass model: returns the change to the estimate's heading (rad)."""
        fault = self.mag_fault
        compass = self.heading_error_rad  # the working compass's own heading error (0 with the truth)
        if fault != self._mag_seen:
            self._mag_start(fault, truth, est, compass)
        reporting, fused = self._mag_sample(fault, truth, dt)
        if not fused:  # the gyro alone; GNSS velocity aligns the heading while the vehicle moves
            self._mag_err += self._mag_drift * dt
            vn, ve, _ = truth.vel_ned_mps
            if vn * vn + ve * ve >= YAW_GNSS_ALIGN_MIN_SPEED_MPS * YAW_GNSS_ALIGN_MIN_SPEED_MPS:
                self._mag_err -= min(1.0, dt / YAW_GNSS_ALIGN_TIME_CONSTANT_S) * self._mag_err
            if not self._mag_said:
                self._mag_said = True
                why = {_OFF: "stopped", _INTERMITTENT: "intermittent"}.get(fault, "rejected")
                self.messages.append(f"EKF2: compass {why}, heading from gyro and GNSS velocity")
        elif fault != _STUCK:  # a working compass pulls the heading back to its own error
            self._mag_err += min(1.0, dt / MAG_FUSION_TIME_CONSTANT_S) * (compass - self._mag_err)
        self.mag_reporting = reporting
        self._mag_fused = fused
        if not fault and abs(self._mag_err - compass) < 1e-4:  # cleared and recovered: the compass's again
            self._mag_on = False
            return 0.0
        return self._mag_err - compass

    def _mag_start(self, fault: int, truth: VehicleState, est: LocalState, compass: float) -> None:
        """A new compass failure (or OK) takes over from the present state."""
        self._mag_seen = fault
        self._mag_said = False
        self.mag_report_body = None
        self._mag_gaps.restart(truth.t_s)
        if not fault:
            return
        if not self._mag_on:  # take over from the compass's present error
            self._mag_err = compass
            self._mag_on = True
        self._mag_drift = float(self._mag_rng.normal(0.0, GYRO_YAW_DRIFT_SD_RADPS))
        if fault == _STUCK:  # the field it froze at says this heading
            self._mag_stuck_yaw = truth.euler_rad[2] + self._mag_err
            self.mag_report_body = field_in_body(est.full.q_wxyz)

    def _mag_sample(self, fault: int, truth: VehicleState, dt: float) -> tuple[bool, bool]:
        """What the compass reports this step and whether EKF2 fuses it: ``(reporting, fused)``."""
        if fault == _OFF:
            return False, False
        if fault == _GARBAGE:
            r = self._mag_rng
            x = float(r.uniform(0.65, 2.0))  # at least 0.65 gauss on one axis: beyond any field + the gate
            sign = 1.0 if r.random() < 0.5 else -1.0
            self.mag_report_body = (sign * x, float(r.uniform(-2.0, 2.0)), float(r.uniform(-2.0, 2.0)))
            return True, False
        if fault == _STUCK:
            innovation = _wrap(self._mag_stuck_yaw - (truth.euler_rad[2] + self._mag_err))
            if abs(innovation) > MAG_HEADING_GATE_RAD:
                self.mag_rejected_samples += 1
                return True, False
            self._mag_err += min(1.0, dt / MAG_FUSION_TIME_CONSTANT_S) * innovation
            return True, True
        if fault == _INTERMITTENT and self._mag_gaps.step(truth.t_s):
            return False, False
        return True, True

    def _baro_update(self, t_s: float, est: LocalState, dt: float) -> float:
        """The barometer model: returns the change to the estimate's NED down position (m)."""
        fault = self.baro_fault
        d0 = est.pos_ned_m[2]  # the height with the baro fused as the reference
        if fault != self._baro_seen:
            self._baro_start(fault, t_s, est)
            if not fault:
                return 0.0
        reporting, fused, pull_to = self._baro_sample(fault, t_s, est, d0)
        k = min(1.0, dt / GPS_FUSION_TIME_CONSTANT_S)
        self._baro_pull += k * (pull_to - self._baro_pull)
        if fused:  # the baro holds the height again
            self._hgt_err -= k * self._hgt_err
        else:  # the GNSS height alone: its error wanders in from zero
            if dt > 0.0:
                a = math.exp(-dt / self._gnss_height_corr_s)
                b = math.sqrt(max(0.0, 1.0 - a * a))
                self._hgt_err = a * self._hgt_err + b * self.gnss_height_sd_m * float(self._baro_rng.standard_normal())
            if not self._baro_said and fault != _STUCK:
                self._baro_said = True
                why = {_OFF: "stopped", _INTERMITTENT: "intermittent"}.get(fault, "rejected")
                self.messages.append(f"EKF2: baro {why}, height from GNSS")
        self.baro_reporting = reporting
        self._baro_fused = fused
        return self._baro_pull + self._hgt_err

    def _baro_start(self, fault: int, t_s: float, est: LocalState) -> None:
        """A new baro failure (or OK) takes over from the present state."""
        self._baro_seen = fault
        self._baro_said = False
        self._baro_latched = False
        self._baro_rejected_since = None
        self.baro_report_alt_m = None
        self._baro_gaps.restart(t_s)
        if not fault:  # baro fusion restarts as the height reference: EKF2 resets the height to it
            self._baro_on = False
            self._baro_fused = True
            self.baro_reporting = True
            self._baro_pull = self._hgt_err = 0.0
            return
        self._baro_on = True
        if fault == _STUCK:
            self._baro_stuck_d = est.pos_ned_m[2]  # the baro's own reading: the height it fused until now
            self.baro_report_alt_m = est.full.alt_amsl_m

    def _baro_sample(self, fault: int, t_s: float, est: LocalState, d0: float) -> tuple[bool, bool, float]:
        """What the baro reports this step, whether EKF2 fuses it, and how far it pulls the height (down, m)."""
        if fault == _OFF:
            return False, False, 0.0
        if fault == _GARBAGE:
            r = self._baro_rng
            off = float(r.uniform(2.0 * self.baro_gate_m, 5000.0))  # always beyond the gate
            self.baro_report_alt_m = est.full.alt_amsl_m + (off if r.random() < 0.5 else -off)
            return True, False, 0.0
        if fault == _STUCK:
            innovation = self._baro_stuck_d - (d0 + self._baro_pull + self._hgt_err)
            if not self._baro_latched and abs(innovation) <= self.baro_gate_m:
                self._baro_rejected_since = None
                return True, True, self.baro_weight * (self._baro_stuck_d - d0)
            self.baro_rejected_samples += 1
            if self._baro_rejected_since is None:
                self._baro_rejected_since = t_s
            elif not self._baro_latched and t_s - self._baro_rejected_since >= HGT_FUSION_TIMEOUT_S:
                self._baro_latched = True  # EKF2: "stopping baro height fusion, fusion failing"; baro_fault
                self.messages.append("EKF2: baro fusion failing, height from GNSS")
            return True, False, 0.0
        if fault == _INTERMITTENT and self._baro_gaps.step(t_s):
            return False, False, 0.0
        return True, True, 0.0

    def _step_noise(self, dt: float, nm: NoiseModel) -> None:
        if dt <= 0.0:
            return
        a = math.exp(-dt / nm.noise_correlation_s)
        b = math.sqrt(max(0.0, 1.0 - a * a))
        sigma = np.array(
            [nm.horizontal_noise_m] * 2
            + [nm.vertical_noise_m]
            + [nm.velocity_noise_mps] * 3
            + [nm.attitude_noise_rad] * 3
        )
        self._gm = a * self._gm + b * sigma * self._rng.standard_normal(9)

    def _step_heading(self, dt: float, nm: NoiseModel) -> None:
        if dt <= 0.0:
            return
        a = math.exp(-dt / nm.heading_correlation_s)
        b = math.sqrt(max(0.0, 1.0 - a * a))
        self._heading_gm = a * self._heading_gm + b * nm.heading_noise_rad * float(self._heading_rng.standard_normal())

    def _step_dropout(self, t_s: float, dt: float, nm: NoiseModel) -> None:
        if t_s < self._dropout_until:
            self._drift_error[0] += self._drift[0] * dt
            self._drift_error[1] += self._drift[1] * dt
            return
        decay = math.exp(-dt / self.RECOVERY_TIME_S) if dt > 0 else 1.0
        self._drift_error[0] *= decay
        self._drift_error[1] *= decay
        rate_per_s = nm.gps_dropouts_per_hour / 3600.0
        if rate_per_s > 0.0 and dt > 0.0 and self._rng.random() < 1.0 - math.exp(-rate_per_s * dt):
            self._dropout_until = t_s + nm.gps_dropout_duration_s
            heading = float(self._rng.uniform(0.0, 2.0 * math.pi))
            self._drift = (nm.dropout_drift_mps * math.cos(heading), nm.dropout_drift_mps * math.sin(heading))
            self.dropouts += 1


def _wrap(angle_rad: float) -> float:
    return (angle_rad + math.pi) % (2.0 * math.pi) - math.pi


def field_in_body(q_wxyz: tuple[float, float, float, float]) -> tuple[float, float, float]:
    """The Earth's field (:data:`EARTH_FIELD_NED_GAUSS`) in the body frame of attitude ``q_wxyz``: R^T B."""
    w, x, y, z = q_wxyz
    mn, me, md = EARTH_FIELD_NED_GAUSS
    return (
        (1 - 2 * (y * y + z * z)) * mn + 2 * (x * y + w * z) * me + 2 * (x * z - w * y) * md,
        2 * (x * y - w * z) * mn + (1 - 2 * (x * x + z * z)) * me + 2 * (y * z + w * x) * md,
        2 * (x * z + w * y) * mn + 2 * (y * z - w * x) * me + (1 - 2 * (x * x + y * y)) * md,
    )


def _quat_from_euler(roll: float, pitch: float, yaw: float) -> tuple[float, float, float, float]:
    cr, sr = math.cos(0.5 * roll), math.sin(0.5 * roll)
    cp, sp = math.cos(0.5 * pitch), math.sin(0.5 * pitch)
    cy, sy = math.cos(0.5 * yaw), math.sin(0.5 * yaw)
    q = (
        cr * cp * cy + sr * sp * sy,
        sr * cp * cy - cr * sp * sy,
        cr * sp * cy + sr * cp * sy,
        cr * cp * sy - sr * sp * cy,
    )
    return q if q[0] >= 0.0 else (-q[0], -q[1], -q[2], -q[3])

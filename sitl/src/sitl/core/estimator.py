"""State estimate: the truth, or the truth plus seeded noise, bias and GPS dropouts.

Noise is first-order Gauss-Markov (exponentially correlated over
``noise_correlation_s``), which looks like an EKF's wander rather than white
jitter; the bias is drawn once per run. During a GPS dropout the horizontal
error drifts at ``dropout_drift_mps`` in a random direction and ``gps_ok`` is
false (GPS_RAW_INT reports no fix); afterwards the error converges back.
All randomness comes from one ``numpy.random.Generator`` seeded from the config.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

from sitl.core.faults import NO_AID_TIMEOUT_S
from sitl.core.state import LocalState, VehicleState
from uav_common.geo import GeoPoint, LocalProjection

__all__ = ["Estimator", "NoiseModel"]


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


class Estimator:
    """Produces the :class:`LocalState` the autopilot flies on and reports."""

    RECOVERY_TIME_S = 2.0

    def __init__(self, projection: LocalProjection, noise: NoiseModel | None, seed: int = 0) -> None:
        self.projection = projection
        self.noise = noise
        self._rng = np.random.default_rng(seed)
        self._gm = np.zeros(9)  # correlated noise state: pos(3), vel(3), att(3)
        if noise is not None:
            bh = self._rng.normal(0.0, noise.horizontal_bias_m, 2)
            bv = self._rng.normal(0.0, noise.vertical_bias_m)
            self._bias = (float(bh[0]), float(bh[1]), float(bv))
        else:
            self._bias = (0.0, 0.0, 0.0)
        self._dropout_until = -1.0
        self._drift = (0.0, 0.0)
        self._drift_error = [0.0, 0.0]
        self._last_t: float | None = None
        self.dropouts = 0
        #: An injected GPS failure (MAV_CMD_INJECT_FAILURE): set by the vehicle before each update.
        self.gps_failed = False
        self._gps_failed_since: float | None = None
        self._dead_reckoned: tuple[float, float] | None = None

    @property
    def gps_ok(self) -> bool:
        if self.gps_failed:
            return False
        return self._last_t is None or self._last_t >= self._dropout_until

    def _without_gps(self, t_s: float, est: LocalState, dt: float) -> LocalState:
        """An injected GPS failure: no fix; the horizontal position is dead-reckoned on the velocity
        estimate from where the last fix left it, and invalid after :data:`NO_AID_TIMEOUT_S` (PX4's EKF2)."""
        if self._gps_failed_since is None or self._dead_reckoned is None:
            self._gps_failed_since = t_s
            self._dead_reckoned = (est.pos_ned_m[0], est.pos_ned_m[1])
        else:
            vn, ve, _ = est.vel_ned_mps
            self._dead_reckoned = (self._dead_reckoned[0] + vn * dt, self._dead_reckoned[1] + ve * dt)
        pos = (self._dead_reckoned[0], self._dead_reckoned[1], est.pos_ned_m[2])
        valid = t_s - self._gps_failed_since < NO_AID_TIMEOUT_S
        return LocalState(est.full, pos, False, valid)

    def update(self, truth: VehicleState, truth_ned_m: tuple[float, float, float] | None = None) -> LocalState:
        """The estimate for ``truth``; ``truth_ned_m`` is its LOCAL_NED position if already known."""
        if truth_ned_m is None:
            truth_ned_m = self.projection.to_ned(GeoPoint(truth.lat_deg, truth.lon_deg, truth.alt_amsl_m))
        n, e, d = truth_ned_m
        dt = 0.0 if self._last_t is None else max(0.0, truth.t_s - self._last_t)
        if self.noise is None:
            self._last_t = truth.t_s
            if self.gps_failed:
                return self._without_gps(truth.t_s, LocalState(truth, (n, e, d), False), dt)
            self._gps_failed_since = None
            return LocalState(truth, (n, e, d), True)
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
        if self.gps_failed:
            return self._without_gps(truth.t_s, LocalState(est, pos, False), dt)
        self._gps_failed_since = None
        return LocalState(est, pos, self.gps_ok)

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

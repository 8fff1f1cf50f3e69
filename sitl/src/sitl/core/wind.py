"""Mean wind with a height profile, and Dryden turbulence (MIL-F-8785C, low altitude), seeded.

Pure: the caller passes the height above ground, the vehicle's velocity, the time step and a seeded
``numpy.random.Generator``; the result is the wind in LOCAL_NED (the air's velocity over the ground),
which the physics shell hands to JSBSim's atmosphere (``atmosphere/wind-{north,east,down}-fps``).

* **Mean wind**: ``speed_mps`` at ``reference_height_m``, blowing *from* ``from_deg`` (meteorological,
  clockwise from north), growing with height above ground by the power law
  ``speed(h) = speed_mps * (h / reference_height_m) ** shear_exponent`` (h at least 1 m).
* **Turbulence**: the Dryden spectra of MIL-F-8785C below 1000 ft, in axes aligned with the mean wind
  (u along it, v across it, w vertical), carried past the vehicle at its airspeed (Taylor's frozen
  turbulence: ``T = L / V`` with ``V`` at least 1 m/s). Intensities: ``sigma_w = 0.1 * W20`` and
  ``sigma_u = sigma_v = sigma_w / (0.177 + 0.000823 h_ft) ** 0.4``; scale lengths ``L_w = h_ft`` and
  ``L_u = L_v = h_ft / (0.177 + 0.000823 h_ft) ** 1.2`` (h clamped to 10..1000 ft). ``W20``, the wind at
  20 ft that defines the level, is MIL-F-8785C's: light 15 kt, moderate 30 kt, severe 45 kt.
  u is a first-order Gauss-Markov process (its spectrum is Dryden's exactly); v and w pass white noise
  through ``(1 + sqrt(3) T s) / (1 + T s)^2``, built from two exact first-order lags.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

__all__ = ["TURBULENCE_W20_MPS", "WindModel", "WindSpec", "mean_wind_speed_mps"]

_KNOT_MPS = 0.514444
_FT_M = 0.3048
#: MIL-F-8785C's wind speed at 20 ft per turbulence level (low altitude).
TURBULENCE_W20_MPS: dict[str, float] = {
    "none": 0.0,
    "light": 15.0 * _KNOT_MPS,
    "moderate": 30.0 * _KNOT_MPS,
    "severe": 45.0 * _KNOT_MPS,
}
_SQRT3 = math.sqrt(3.0)
_MIN_HEIGHT_M = 1.0
_MIN_AIRSPEED_MPS = 1.0


@dataclass(frozen=True)
class WindSpec:
    """The air: mean wind by height and a turbulence level (a :data:`TURBULENCE_W20_MPS` name)."""

    speed_mps: float = 0.0
    from_deg: float = 0.0
    reference_height_m: float = 10.0
    shear_exponent: float = 0.0
    turbulence: str = "none"

    @property
    def enabled(self) -> bool:
        return self.speed_mps > 0.0 or self.turbulence != "none"


def mean_wind_speed_mps(spec: WindSpec, height_agl_m: float) -> float:
    """Mean wind speed at ``height_agl_m`` above ground (the power-law profile)."""
    h = height_agl_m if height_agl_m > _MIN_HEIGHT_M else _MIN_HEIGHT_M
    if spec.shear_exponent == 0.0:
        return spec.speed_mps
    return float(spec.speed_mps * (h / spec.reference_height_m) ** spec.shear_exponent)


class WindModel:
    """The wind one vehicle flies in; :meth:`update` once per time step (the outer loop's, 50 Hz)."""

    def __init__(self, spec: WindSpec, rng: np.random.Generator) -> None:
        if spec.turbulence not in TURBULENCE_W20_MPS:
            msg = f"turbulence must be one of {', '.join(TURBULENCE_W20_MPS)}, got {spec.turbulence!r}"
            raise ValueError(msg)
        self.spec = spec
        self._rng = rng
        to_rad = math.radians(spec.from_deg)
        # the air moves towards from_deg + 180
        self._along_ne = (-math.cos(to_rad), -math.sin(to_rad))
        self._w20_mps = TURBULENCE_W20_MPS[spec.turbulence]
        self._u = 0.0
        self._v1 = self._v2 = 0.0
        self._w1 = self._w2 = 0.0
        self.gust_uvw_mps = (0.0, 0.0, 0.0)
        self.wind_ned_mps = (0.0, 0.0, 0.0)

    def update(
        self, height_agl_m: float, vel_ned_mps: tuple[float, float, float], dt_s: float
    ) -> tuple[float, float, float]:
        """Advance the turbulence by ``dt_s`` and return the wind (NED, m/s) at this height."""
        mean = mean_wind_speed_mps(self.spec, height_agl_m)
        an, ae = self._along_ne
        if self._w20_mps > 0.0:
            u, v, w = self._turbulence(height_agl_m, mean, vel_ned_mps, dt_s)
        else:
            u = v = w = 0.0
        self.gust_uvw_mps = (u, v, w)
        along = mean + u
        # v across the wind: 90 degrees clockwise from its direction (seen from above)
        wind = (an * along - ae * v, ae * along + an * v, w)
        self.wind_ned_mps = wind
        return wind

    def _turbulence(
        self, height_agl_m: float, mean_mps: float, vel_ned_mps: tuple[float, float, float], dt_s: float
    ) -> tuple[float, float, float]:
        h_ft = min(max(height_agl_m / _FT_M, 10.0), 1000.0)
        k = 0.177 + 0.000823 * h_ft
        sigma_w = 0.1 * self._w20_mps
        sigma_uv = sigma_w / k**0.4
        l_w_m = h_ft * _FT_M
        l_uv_m = h_ft / k**1.2 * _FT_M
        an, ae = self._along_ne
        air_n = an * mean_mps - vel_ned_mps[0]
        air_e = ae * mean_mps - vel_ned_mps[1]
        airspeed = math.sqrt(air_n * air_n + air_e * air_e + vel_ned_mps[2] * vel_ned_mps[2])
        airspeed = max(airspeed, _MIN_AIRSPEED_MPS)
        n_u, n_v, n_w = self._rng.standard_normal(3)
        # u: first-order Gauss-Markov, variance sigma_uv^2, correlation time L_u / V
        a_u = math.exp(-dt_s * airspeed / l_uv_m)
        self._u = a_u * self._u + sigma_uv * math.sqrt(1.0 - a_u * a_u) * float(n_u)
        v = self._transverse(l_uv_m / airspeed, sigma_uv, float(n_v), dt_s, lateral=True)
        w = self._transverse(l_w_m / airspeed, sigma_w, float(n_w), dt_s, lateral=False)
        return self._u, v, w

    def _transverse(self, tau_s: float, sigma: float, noise: float, dt_s: float, *, lateral: bool) -> float:
        """One step of ``sigma * sqrt(tau) * (1 + sqrt(3) tau s) / (1 + tau s)^2`` on unit white noise."""
        alpha = math.exp(-dt_s / tau_s)
        xi = sigma * math.sqrt(tau_s / dt_s) * noise
        if lateral:
            self._v1 = alpha * self._v1 + (1.0 - alpha) * xi
            self._v2 = alpha * self._v2 + (1.0 - alpha) * self._v1
            return _SQRT3 * self._v1 + (1.0 - _SQRT3) * self._v2
        self._w1 = alpha * self._w1 + (1.0 - alpha) * xi
        self._w2 = alpha * self._w2 + (1.0 - alpha) * self._w1
        return _SQRT3 * self._w1 + (1.0 - _SQRT3) * self._w2

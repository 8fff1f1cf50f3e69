"""Smoothing of the camera trajectory, against white pose jitter.

The stereo baseline *length* cannot be seen in the images: a 5 cm jitter on each
of two positions 7 m apart is a 1 % depth scale error, about 0.5 m at 50 m.
A multicopter's path is smooth over a second or two, while jitter is white, so
a low-degree polynomial fitted (least squares, per axis) to the positions of the
recent frames gives a much better *relative* translation between two of them.

The fit is used only when the poses do jitter: :func:`estimate_jitter_m`
measures the jitter from a cubic over the last second, where the flight itself
leaves millimetres. Exact poses (the bridge's default) are never smoothed, so a
manoeuvre cannot bias them. When the fit residual is larger than
``max_residual_m`` (a sharp manoeuvre, a pose jump) the raw positions are used.
"""

from __future__ import annotations

import math
from collections.abc import Sequence
from dataclasses import dataclass

import numpy as np

from uav_perception.core.depth.types import FloatArray

__all__ = ["TrajectoryFit", "estimate_jitter_m", "fit_trajectory"]


@dataclass(frozen=True, eq=False)
class TrajectoryFit:
    """A per-axis polynomial ``p(t)`` fitted to positions.

    Attributes:
        coeffs: ``(degree + 1, 3)`` coefficients in powers of ``(t - t0_s) / scale_s``, highest first.
        t0_s, scale_s: time normalisation.
        residual_rms_m: RMS distance of the samples from the fit.
        samples: number of samples used.
    """

    coeffs: FloatArray
    t0_s: float
    scale_s: float
    residual_rms_m: float
    samples: int

    def at(self, t_s: float) -> FloatArray:
        """Fitted position at ``t_s``, ``(3,)`` metres."""
        x = (t_s - self.t0_s) / self.scale_s
        powers = x ** np.arange(len(self.coeffs) - 1, -1, -1, dtype=np.float64)
        return np.asarray(powers @ self.coeffs, dtype=np.float64)


def fit_trajectory(times_s: Sequence[float] | FloatArray, positions_m: FloatArray, degree: int) -> TrajectoryFit | None:
    """Least-squares polynomial of ``degree`` through ``(times_s, positions_m (N, 3))``.

    Returns None with fewer than ``degree + 3`` finite samples (too few to beat the raw poses)
    or when the times do not span a positive interval.
    """
    t = np.asarray(times_s, dtype=np.float64)
    p = np.asarray(positions_m, dtype=np.float64)
    ok = np.isfinite(t) & np.all(np.isfinite(p), axis=1)
    t, p = t[ok], p[ok]
    if len(t) < degree + 3:
        return None
    t0 = float(t.mean())
    scale = float(np.ptp(t)) / 2.0
    if not math.isfinite(scale) or scale <= 0:
        return None
    x = (t - t0) / scale
    vander = np.vander(x, degree + 1)
    coeffs, *_ = np.linalg.lstsq(vander, p, rcond=None)
    resid = p - vander @ coeffs
    rms = float(np.sqrt(np.mean(np.sum(resid * resid, axis=1))))
    return TrajectoryFit(np.asarray(coeffs, dtype=np.float64), t0, scale, rms, len(t))


def estimate_jitter_m(times_s: Sequence[float] | FloatArray, positions_m: FloatArray, window_s: float) -> float | None:
    """White position jitter (per-axis standard deviation, metres) of the samples of the last ``window_s``.

    A cubic over a short window follows any real flight (its residual from the
    motion itself is millimetres), so what remains is the jitter:
    ``sigma = rms_3d / sqrt(3) * sqrt(N / (N - 4))``. None with fewer than 7 samples.
    """
    t = np.asarray(times_s, dtype=np.float64)
    p = np.asarray(positions_m, dtype=np.float64)
    if len(t) == 0:
        return None
    recent = t >= t.max() - window_s
    if int(recent.sum()) < 7:
        return None
    fit = fit_trajectory(t[recent], p[recent], 3)
    if fit is None:
        return None
    n = fit.samples
    return fit.residual_rms_m / math.sqrt(3.0) * math.sqrt(n / (n - 4))

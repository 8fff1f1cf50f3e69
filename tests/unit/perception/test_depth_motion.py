"""Trajectory smoothing: less baseline jitter, no bias in manoeuvres."""

from __future__ import annotations

from collections.abc import Callable

import numpy as np
import pytest

from uav_perception.core.depth.config import PoseSmoothingConfig
from uav_perception.core.depth.motion import estimate_jitter_m, fit_trajectory

CFG = PoseSmoothingConfig()
T = np.arange(-CFG.window_s, 1e-9, 0.1)  # 10 Hz frames of the last window, reference at t = 0
PARTNER_T = -0.9  # a partner 0.9 s back (7.2 m at 8 m/s)


def relative_error(
    traj: Callable[[np.ndarray], np.ndarray], noise_m: float = 0.0, seed: int = 0
) -> tuple[float, float]:
    """|fitted - true| and |raw - true| of the partner-minus-reference translation."""
    rng = np.random.default_rng(seed)
    pos = traj(T) + rng.normal(0.0, noise_m, (len(T), 3))
    fit = fit_trajectory(T, pos, CFG.degree)
    assert fit is not None
    true_rel = traj(np.array([PARTNER_T]))[0] - traj(np.array([0.0]))[0]
    raw_rel = pos[np.argmin(np.abs(T - PARTNER_T))] - pos[-1]
    return float(np.linalg.norm(fit.at(PARTNER_T) - fit.at(0.0) - true_rel)), float(np.linalg.norm(raw_rel - true_rel))


def straight(t: np.ndarray) -> np.ndarray:
    return np.stack([8.0 * t, 2.0 * t, 50.0 + 0.0 * t], axis=1)


def turn(radius_m: float) -> Callable[[np.ndarray], np.ndarray]:
    def traj(t: np.ndarray) -> np.ndarray:
        a = 8.0 / radius_m * t
        return np.stack([radius_m * np.cos(a), radius_m * np.sin(a), 50.0 + 0.0 * t], axis=1)

    return traj


def braking(t: np.ndarray) -> np.ndarray:
    """Braking at 3 m/s^2 until 1.5 s ago, constant speed since: a jump in acceleration."""
    return np.stack([8.0 * t + 1.5 * np.minimum(t + 1.5, 0.0) ** 2, 0.0 * t, 50.0 + 0.0 * t], axis=1)


def test_jitter_is_reduced() -> None:
    fitted, raw = zip(*(relative_error(straight, 0.05, seed) for seed in range(200)), strict=True)
    rms_fit = float(np.sqrt(np.mean(np.square(fitted))))
    rms_raw = float(np.sqrt(np.mean(np.square(raw))))
    assert rms_raw == pytest.approx(0.05 * np.sqrt(6), rel=0.15)
    assert rms_fit < rms_raw / 1.7


@pytest.mark.parametrize(("traj", "max_err_m"), [(turn(50.0), 0.005), (turn(20.0), 0.03), (braking, 0.04)])
def test_manoeuvres_are_followed_without_noise(traj: Callable[[np.ndarray], np.ndarray], max_err_m: float) -> None:
    err, raw = relative_error(traj)
    assert raw == pytest.approx(0.0, abs=1e-12)
    assert err < max_err_m


def test_too_few_or_bad_samples() -> None:
    assert fit_trajectory([0.0, 0.1, 0.2, 0.3, 0.4], np.zeros((5, 3)), 3) is None  # needs degree + 3
    assert fit_trajectory([1.0] * 8, np.zeros((8, 3)), 1) is None  # no time span
    pos = straight(T)
    pos[3] = np.nan
    fit = fit_trajectory(T, pos, 3)
    assert fit is not None
    assert fit.samples == len(T) - 1
    assert fit.at(-1.0) == pytest.approx([-8.0, -2.0, 50.0])


@pytest.mark.parametrize("traj", [straight, turn(20.0), braking])
def test_exact_poses_show_no_jitter_even_in_manoeuvres(traj: Callable[[np.ndarray], np.ndarray]) -> None:
    jitter = estimate_jitter_m(T, traj(T), CFG.jitter_window_s)
    assert jitter is not None
    assert jitter < CFG.min_jitter_m / 2  # so exact poses are never smoothed


def test_jitter_is_measured() -> None:
    rng = np.random.default_rng(4)
    estimates = [
        estimate_jitter_m(T, braking(T) + rng.normal(0.0, 0.05, (len(T), 3)), CFG.jitter_window_s) for _ in range(100)
    ]
    assert float(np.median([e for e in estimates if e is not None])) == pytest.approx(0.05, rel=0.15)
    assert estimate_jitter_m(T[-5:], straight(T[-5:]), 1.0) is None  # too few samples

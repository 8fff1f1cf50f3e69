"""Wind and turbulence: the pure model, and the real JSBSim F450 holding its position in moving air."""

from __future__ import annotations

import math

import numpy as np
import pytest
from unit.sitl.sitl_builders import make_config, make_vehicle, pos, take_off

from sitl.core.wind import WindModel, WindSpec, mean_wind_speed_mps
from sitl.errors import SitlConfigError
from sitl.vehicle import Vehicle

NAV_ACC_RAD_M = 2.0  # PX4's horizontal acceptance radius: the position tolerance of a hold


def _hold(v: Vehicle, seconds: float) -> tuple[float, float, float]:
    """Fly ``seconds`` in the present hold; (worst horizontal offset m, mean roll rad, mean pitch rad)."""
    worst = 0.0
    roll = pitch = 0.0
    steps = round(seconds / v.dt_s)
    for _ in range(steps):
        v.step(v.t_s)
        n, e, _ = pos(v)
        worst = max(worst, math.hypot(n, e))
        euler = v.truth().euler_rad
        roll += euler[0]
        pitch += euler[1]
    return worst, roll / steps, pitch / steps


@pytest.mark.parametrize(("from_deg", "axis", "sign"), [(270.0, "roll", -1.0), (0.0, "pitch", -1.0)])
def test_hold_in_a_steady_wind_stays_put_and_leans_into_it(from_deg: float, axis: str, sign: float) -> None:
    v = make_vehicle(**{"wind.speed_mps": 10.0, "wind.from_deg": from_deg})
    take_off(v, 10.0, settle_s=10.0)
    worst, roll, pitch = _hold(v, 20.0)
    assert worst < NAV_ACC_RAD_M, f"a 10 m/s wind pushed the hold {worst:.2f} m"
    # from the west the air pushes east: the thrust must point west (roll left); from the north: nose down
    lean = roll if axis == "roll" else pitch
    other = pitch if axis == "roll" else roll
    assert sign * lean > math.radians(2.0), f"{axis} {math.degrees(lean):.2f} deg does not lean into the wind"
    assert abs(other) < math.radians(0.5)
    # the air JSBSim applied is the configured wind
    wn, we, wd = v.fdm.wind_ned_mps()
    to = math.radians(from_deg + 180.0)
    assert math.isclose(wn, 10.0 * math.cos(to), abs_tol=1e-9)
    assert math.isclose(we, 10.0 * math.sin(to), abs_tol=1e-9)
    assert wd == 0.0


def test_stronger_wind_leans_further() -> None:
    leans = []
    for speed in (4.0, 12.0):
        v = make_vehicle(**{"wind.speed_mps": speed, "wind.from_deg": 270.0})
        take_off(v, 10.0, settle_s=8.0)
        leans.append(-_hold(v, 5.0)[1])
    assert leans[1] > 3.0 * leans[0] > 0.0  # drag grows with the square of the airspeed


def test_hold_in_turbulence_stays_within_the_tolerance() -> None:
    v = make_vehicle(**{"wind.speed_mps": 12.0, "wind.from_deg": 250.0, "wind.turbulence": "light", "wind.seed": 4})
    take_off(v, 10.0, settle_s=10.0)
    worst, _, _ = _hold(v, 30.0)
    assert 0.02 < worst < NAV_ACC_RAD_M, f"light turbulence moved the hold {worst:.2f} m"


def _gusts(seed: int, n: int = 3000) -> np.ndarray:
    model = WindModel(WindSpec(speed_mps=5.0, from_deg=90.0, turbulence="moderate"), np.random.default_rng(seed))
    return np.array([model.update(30.0, (0.0, 0.0, 0.0), 0.02) for _ in range(n)])


def test_turbulence_is_reproducible_with_its_seed_and_differs_with_another() -> None:
    a, b, c = _gusts(1), _gusts(1), _gusts(2)
    assert np.array_equal(a, b)
    assert not np.allclose(a, c)
    v1 = make_vehicle(**{"wind.speed_mps": 6.0, "wind.turbulence": "moderate", "wind.seed": 9})
    v2 = make_vehicle(**{"wind.speed_mps": 6.0, "wind.turbulence": "moderate", "wind.seed": 9})
    v3 = make_vehicle(**{"wind.speed_mps": 6.0, "wind.turbulence": "moderate", "wind.seed": 10})
    for v in (v1, v2, v3):
        take_off(v, 10.0, settle_s=3.0)
    assert pos(v1) == pos(v2)
    assert math.dist(pos(v1), pos(v3)) > 1e-3


def test_turbulence_has_the_dryden_intensities() -> None:
    """MIL-F-8785C at 30 m, moderate (W20 = 30 kt): sigma_w = 1.54 m/s, sigma_u = sigma_v = 2.65 m/s."""
    model = WindModel(WindSpec(speed_mps=0.0, from_deg=0.0, turbulence="moderate"), np.random.default_rng(5))
    # along north (u), east (v), down (w): the mean wind is zero, from the north
    samples = np.array([model.update(30.0, (8.0, 0.0, 0.0), 0.02) for _ in range(200_000)])
    std = samples[2000:].std(axis=0)
    h_ft = 30.0 / 0.3048
    sigma_w = 0.1 * 30.0 * 0.514444
    sigma_u = sigma_w / (0.177 + 0.000823 * h_ft) ** 0.4
    assert std[0] == pytest.approx(sigma_u, rel=0.15)
    assert std[1] == pytest.approx(sigma_u, rel=0.15)
    assert std[2] == pytest.approx(sigma_w, rel=0.15)
    assert abs(samples[:, 0].mean()) < 0.5


def test_mean_wind_grows_with_height_by_the_power_law() -> None:
    spec = WindSpec(speed_mps=5.0, reference_height_m=10.0, shear_exponent=0.14)
    assert mean_wind_speed_mps(spec, 10.0) == pytest.approx(5.0)
    assert mean_wind_speed_mps(spec, 40.0) == pytest.approx(5.0 * 4.0**0.14)
    assert mean_wind_speed_mps(spec, 0.0) == pytest.approx(5.0 * 0.1**0.14)  # at least 1 m
    v = make_vehicle(**{"wind.speed_mps": 5.0, "wind.from_deg": 0.0, "wind.shear_exponent": 0.14})
    take_off(v, 40.0, settle_s=2.0)
    # set at the last outer-loop step (at most 4 physics steps ago)
    assert -v.fdm.wind_ned_mps()[0] == pytest.approx(
        mean_wind_speed_mps(spec, v.truth().height_above_ground_m), rel=1e-4
    )


def test_calm_air_never_touches_jsbsim_wind() -> None:
    v = make_vehicle()
    assert v.wind is None
    assert v.fdm.wind_ned_mps() == (0.0, 0.0, 0.0)


@pytest.mark.parametrize(
    ("key", "value", "words"),
    [
        ("wind.speed_mps", 41.0, "speed_mps"),
        ("wind.speed_mps", -1.0, "speed_mps"),
        ("wind.from_deg", 400.0, "from_deg"),
        ("wind.reference_height_m", 0.0, "reference_height_m"),
        ("wind.shear_exponent", 2.0, "shear_exponent"),
        ("wind.turbulence", "hurricane", "turbulence"),
        ("wind.gusts", 1.0, "gusts"),
        ("wind.speed_mps", float("nan"), "speed_mps"),
    ],
)
def test_bad_wind_values_name_the_key(key: str, value: object, words: str) -> None:
    with pytest.raises(SitlConfigError, match=words):
        make_config(**{key: value})

"""The noisy estimator's presets (rtk, gps, poor_gps) and its heading error, on the real estimator core.

Each preset's errors are measured over seeded runs and compared with the magnitudes docs/sitl.md states
("Estimator presets": CEP, vertical and heading sigma); explicit keys win over a preset; a bad preset or
value is a configuration error naming the key.
"""

from __future__ import annotations

import math
import re
from pathlib import Path

import numpy as np
import pytest
from helpers.paths import REPO

from sitl.cli import build_parser, load_from_args
from sitl.config import ESTIMATOR_PRESETS, EstimatorConfig, EstimatorMode, EstimatorPreset, load_sitl_config
from sitl.core.estimator import Estimator, NoiseModel
from sitl.core.state import VehicleState
from sitl.errors import SitlConfigError
from uav_common.geo import GeoPoint, LocalProjection

HOME = GeoPoint(47.397742, 8.545594, 488.0)
PROJ = LocalProjection(HOME)
DOC = REPO / "docs" / "sitl.md"
#: A circular Gaussian's CEP (50 % radius) over its per-axis sigma: sqrt(2 ln 2).
CEP_PER_SIGMA = math.sqrt(2.0 * math.log(2.0))


def hover(t_s: float, yaw_rad: float = 0.3) -> VehicleState:
    """A vehicle hovering 10 m above home, heading ``yaw_rad``."""
    q = (math.cos(yaw_rad / 2), 0.0, 0.0, math.sin(yaw_rad / 2))
    return VehicleState(t_s, HOME.lat_deg, HOME.lon_deg, HOME.alt_amsl_m + 10.0, (0.0, 0.0, 0.0), q,
                        (0.0, 0.0, yaw_rad), (0.0, 0.0, 0.0), (0.0, 0.0, -9.8), 10.0)  # fmt: skip


def documented(preset: str) -> dict[str, float]:
    """The row of docs/sitl.md's preset table: CEP, vertical sigma, heading sigma (numbers before their units)."""
    text = DOC.read_text(encoding="utf-8")
    row = next(line for line in text.splitlines() if line.startswith(f"| `{preset}` |"))
    cells = [c.strip() for c in row.strip("|").split("|")]
    number = re.compile(r"([0-9.]+)")

    def first(cell: str) -> float:
        m = number.search(cell)
        assert m is not None, f"no number in {cell!r} of the {preset} row"
        return float(m.group(1))

    return {"cep_m": first(cells[2]), "vertical_m": first(cells[3]), "heading_deg": first(cells[4])}


def final_errors(noise: NoiseModel, seeds: int, settle_s: float) -> np.ndarray:
    """Per seed, (north, east, down, heading, roll) errors after ``settle_s`` (the wander's stationary spread)."""
    out = []
    for seed in range(seeds):
        est = Estimator(PROJ, noise, seed=seed)
        s = None
        for k in range(9):
            s = est.update(hover(k * settle_s / 8))
        assert s is not None
        yaw_err = (s.yaw_rad - 0.3 + math.pi) % (2 * math.pi) - math.pi
        out.append((s.pos_ned_m[0], s.pos_ned_m[1], s.pos_ned_m[2] + 10.0, yaw_err, s.full.euler_rad[0]))
    return np.array(out)


@pytest.mark.parametrize("preset", [p.value for p in EstimatorPreset])
def test_each_preset_errs_by_the_documented_magnitude(preset: str) -> None:
    cfg = EstimatorConfig.from_preset(preset, gps_dropouts_per_hour=0.0)  # dropouts: their own test
    noise = cfg.noise_model()
    assert noise is not None
    doc = documented(preset)
    settle = 4.0 * max(cfg.noise_correlation_s, cfg.heading_correlation_s)
    err = final_errors(noise, seeds=400, settle_s=settle)
    radial = np.hypot(err[:, 0], err[:, 1])
    cep = float(np.median(radial))
    assert cep == pytest.approx(doc["cep_m"], rel=0.15), f"{preset}: CEP {cep:.3f} m, documented {doc['cep_m']}"
    # and the documented CEP is the configured per-axis sigma's
    assert noise.horizontal_error_m * CEP_PER_SIGMA == pytest.approx(doc["cep_m"], rel=0.05)
    vertical = float(np.std(err[:, 2]))
    assert vertical == pytest.approx(doc["vertical_m"], rel=0.15)
    heading = math.degrees(float(np.std(err[:, 3])))
    assert heading == pytest.approx(doc["heading_deg"], rel=0.15)
    # the heading error is its own term: several times the roll/pitch error (a compass, not the gyros)
    roll = math.degrees(float(np.std(err[:, 4])))
    assert roll == pytest.approx(math.degrees(cfg.attitude_noise_rad), rel=0.2)
    assert heading > 3.0 * roll


def test_presets_are_ordered_from_rtk_to_poor_gps() -> None:
    sigma = {p: EstimatorConfig.from_preset(p).noise_model() for p in EstimatorPreset}
    h = [sigma[p].horizontal_error_m for p in EstimatorPreset]  # type: ignore[union-attr]
    yaw = [sigma[p].heading_bias_rad for p in EstimatorPreset]  # type: ignore[union-attr]
    assert h == sorted(h)
    assert yaw == sorted(yaw)
    assert h[0] < 0.05, "RTK is centimetres"
    assert h[1] > 1.0, "single-band GPS metres"


def test_the_wander_is_slow_drift_not_jitter() -> None:
    """The gps preset's error changes little within a second and decorrelates over its correlation time."""
    cfg = EstimatorConfig.from_preset("gps", gps_dropouts_per_hour=0.0)
    est = Estimator(PROJ, cfg.noise_model(), seed=3)
    north = np.array([est.update(hover(k * 0.5)).pos_ned_m[0] for k in range(8000)])  # 4000 s
    steps = np.diff(north)
    # a 0.5 s step moves the error by about sigma * sqrt(2 dt / tau): 1.2 * sqrt(1 / 30) = 0.22 m
    assert float(np.std(steps)) == pytest.approx(1.2 * math.sqrt(1.0 / 30.0), rel=0.15)
    wander = north - north.mean()
    lag = round(cfg.noise_correlation_s / 0.5)
    r = float(np.corrcoef(wander[:-lag], wander[lag:])[0, 1])
    assert r == pytest.approx(math.exp(-1.0), abs=0.15), "correlated over noise_correlation_s"


def test_dropouts_of_poor_gps_come_at_the_configured_rate() -> None:
    cfg = EstimatorConfig.from_preset("poor_gps")
    est = Estimator(PROJ, cfg.noise_model(), seed=5)
    hours = 5.0
    ok = [est.update(hover(k * 0.5)).gps_ok for k in range(round(hours * 7200))]
    expected = cfg.gps_dropouts_per_hour * hours  # 60
    assert abs(est.dropouts - expected) < 4.0 * math.sqrt(expected)
    no_fix = 1.0 - sum(ok) / len(ok)
    assert no_fix == pytest.approx(est.dropouts * cfg.gps_dropout_duration_s / (hours * 3600.0), rel=0.1)


def test_heading_terms_leave_the_position_noise_as_it_was() -> None:
    """The heading error draws from its own stream: the same seed gives the same positions with or without it."""
    plain = EstimatorConfig(mode=EstimatorMode.NOISY).noise_model()
    with_heading = EstimatorConfig(mode=EstimatorMode.NOISY, heading_bias_deg=5.0, heading_noise_deg=2.0).noise_model()
    a, b = Estimator(PROJ, plain, seed=9), Estimator(PROJ, with_heading, seed=9)
    for k in range(300):
        sa, sb = a.update(hover(k * 0.02)), b.update(hover(k * 0.02))
        assert sa.pos_ned_m == sb.pos_ned_m
        assert sa.full.euler_rad[:2] == sb.full.euler_rad[:2]
    assert abs(b.heading_error_rad) > 0.0
    assert a.heading_error_rad == 0.0
    # and the truth is the truth
    exact = Estimator(PROJ, None).update(hover(0.0))
    assert exact.pos_ned_m == pytest.approx((0.0, 0.0, -10.0), abs=1e-9)
    assert exact.yaw_rad == 0.3


# ---- configuration ------------------------------------------------------------------------------------------------


def test_explicit_keys_win_over_the_preset(tmp_path: Path) -> None:
    f = tmp_path / "sitl.yaml"
    f.write_text("estimator:\n  mode: noisy\n  preset: gps\n  horizontal_noise_m: 0.3\n  seed: 4\n")
    cfg = load_sitl_config(f, {"estimator.heading_bias_deg": 10.0}).estimator
    assert cfg.preset is EstimatorPreset.GPS
    assert cfg.horizontal_noise_m == 0.3  # the file's own key
    assert cfg.heading_bias_deg == 10.0  # the command line's
    assert cfg.vertical_bias_m == ESTIMATOR_PRESETS[EstimatorPreset.GPS]["vertical_bias_m"]  # the preset's
    assert cfg.seed == 4
    assert EstimatorConfig.from_preset("rtk", dropout_drift_mps=1.0).dropout_drift_mps == 1.0
    # every preset key is a configuration key with a validated range
    for values in ESTIMATOR_PRESETS.values():
        assert EstimatorConfig(mode=EstimatorMode.NOISY, **values)


def test_the_cli_flag_and_the_shipped_config_take_a_preset() -> None:
    cfg = load_from_args(build_parser().parse_args(["--estimator-preset", "poor_gps", "--seed", "2"]))
    assert cfg.estimator.mode is EstimatorMode.NOISY
    assert cfg.estimator.preset is EstimatorPreset.POOR_GPS
    assert cfg.estimator.horizontal_bias_m == 2.5
    # the shipped config/sitl.yaml stays the truth, with the built-in noise numbers unchanged
    shipped = load_sitl_config(REPO / "config" / "sitl.yaml").estimator
    assert shipped.mode is EstimatorMode.TRUTH
    assert shipped.preset is None
    assert shipped.noise_model() is None
    assert (EstimatorConfig().horizontal_noise_m, EstimatorConfig().horizontal_bias_m) == (0.05, 0.2)
    assert EstimatorConfig().heading_bias_deg == 0.0


@pytest.mark.parametrize(
    ("overrides", "expected"),
    [
        ({"estimator.mode": "noisy", "estimator.preset": "ublox"},
         "'estimator.preset': unknown preset 'ublox'; choose one of rtk, gps, poor_gps"),
        ({"estimator.preset": "gps"}, "'preset' 'gps' needs 'mode: noisy'"),
        ({"estimator.mode": "noisy", "estimator.heading_bias_deg": 120}, "'heading_bias_deg' must be in [0, 90]"),
        ({"estimator.mode": "noisy", "estimator.heading_noise_deg": -1}, "'heading_noise_deg' must be in [0, 90]"),
        ({"estimator.heading_correlation_s": 0}, "'heading_correlation_s' must be in [0.01, 3600]"),
        ({"estimator.mode": "noisy", "estimator.preset": "rtk", "estimator.horizontal_noise_m": -0.1},
         "'horizontal_noise_m' must be in [0, 1000]"),
    ],
)  # fmt: skip
def test_bad_estimator_settings_are_errors_naming_the_key(overrides: dict[str, object], expected: str) -> None:
    with pytest.raises(SitlConfigError) as err:
        load_sitl_config(None, overrides)
    assert expected in str(err.value)


def test_an_unknown_preset_on_the_command_line_lists_the_choices(capsys: pytest.CaptureFixture[str]) -> None:
    with pytest.raises(SystemExit) as done:
        build_parser().parse_args(["--estimator-preset", "ublox"])
    assert done.value.code == 2
    assert "choose from 'rtk', 'gps', 'poor_gps'" in capsys.readouterr().err

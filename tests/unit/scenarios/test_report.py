"""Offline report: read a bag with rosbags (no ROS), draw every figure, write one HTML."""

from __future__ import annotations

import base64
import re
from pathlib import Path

import numpy as np
import pytest
from bagkit import write_synthetic_run

from uav_scenarios.errors import BagReadError
from uav_scenarios.report.data import read_run_bag
from uav_scenarios.report.figures import FIGURES, snapshot_columns
from uav_scenarios.report.html import build_report, flatten_metrics


@pytest.fixture(scope="module")
def bag(tmp_path_factory: pytest.TempPathFactory) -> Path:
    path = tmp_path_factory.mktemp("bag") / "run.bag"
    write_synthetic_run(path)
    return path


def test_bag_reads_into_run_data(bag: Path) -> None:
    run = read_run_bag(bag)
    assert run.name == "synthetic"
    assert run.start_stamp_s == pytest.approx(100.0)
    assert run.trajectory.shape == (601, 4)
    assert run.trajectory[0, 0] == pytest.approx(0.0)
    assert run.trajectory[-1, 3] == pytest.approx(30.0)
    assert run.timeseries["t_s"][-1] == pytest.approx(60.0)
    assert run.timeseries["mapped_pct"][-1] == pytest.approx(30.0)
    assert run.summary["time"]["duration_s"] == pytest.approx(60.0)
    assert [s for _, s in run.controller] == ["TAKEOFF", "AUTONOMOUS", "HOLD"]
    assert len(run.layers) == 2
    assert run.layers[0].layers["elevation_m"].shape == (50, 50)
    assert {(i.camera, i.kind) for i in run.images} == {
        (c, k) for c in ("nadir", "forward") for k in ("color", "depth", "instance")
    }
    depth = next(i.image for i in run.images if i.kind == "depth")
    assert depth.dtype == np.float32
    assert depth[0, 0] == pytest.approx(5.0)
    assert run.target_position_m == (30.0, -80.0)
    assert run.stop_reason == "target_found"
    assert "search_and_rescue" in run.scenario_yaml
    assert run.notes == []


def test_report_builds_with_every_figure(bag: Path, artifacts: Path) -> None:
    run = read_run_bag(bag)
    report = build_report(run, artifacts / "report", versions={"uav_autonomy": "test"})
    assert report.missing == ()
    assert set(report.figures) == set(FIGURES)
    text = report.html_path.read_text()
    images = re.findall(r'src="data:image/png;base64,([^"]+)"', text)
    assert len(images) == len(FIGURES)
    for data in images:
        assert base64.b64decode(data)[:8] == b"\x89PNG\r\n\x1a\n"
    assert 'src="http' not in text  # self-contained
    for section in ("metrics", "events", "versions", "config"):
        assert f'id="{section}"' in text
    assert "coverage.mapped_pct" in text


def test_report_without_snapshots_says_what_is_missing(tmp_path: Path) -> None:
    path = tmp_path / "thin.bag"
    write_synthetic_run(path, duration_s=20.0, with_snapshots=False)
    report = build_report(read_run_bag(path), tmp_path / "out")
    # 20 s: the synthetic detector has not started (no detector frame scored: no PR curve, no gallery)
    assert set(report.missing) == {"cameras", "maps", "pr_curves", "gallery"}
    assert "no data for this figure" in report.html_path.read_text()


def test_missing_and_unfinished_bags_fail_clearly(tmp_path: Path) -> None:
    with pytest.raises(BagReadError, match="no such bag"):
        read_run_bag(tmp_path / "none.bag")
    active = tmp_path / "run.bag.active"
    active.write_bytes(b"#ROSBAG V2.0\n")
    with pytest.raises(BagReadError, match="reindex"):
        read_run_bag(active)


def test_truncated_bag_fails_clearly(bag: Path, tmp_path: Path) -> None:
    cut = tmp_path / "cut.bag"
    cut.write_bytes(bag.read_bytes()[: bag.stat().st_size // 2])
    with pytest.raises(BagReadError, match=r"cut\.bag"):
        read_run_bag(cut)


def test_flatten_metrics() -> None:
    flat = dict(flatten_metrics({"a": {"b": 1, "c": {"d": 2.5}}, "e": [1, 2], "f": "x"}))
    assert flat == {"a.b": 1, "a.c.d": 2.5, "f": "x"}


def test_map_snapshot_columns_pair_layers_and_features_taken_moments_apart() -> None:
    # the scorer takes the layer and the feature snapshot as each arrives after a snapshot time
    cols = snapshot_columns([10.0, 25.0, 26.0], [10.2, 25.1, 60.0])
    assert cols == [(10.0, 0, 0), (25.0, 1, 1), (26.0, 2, None), (60.0, None, 2)]
    assert snapshot_columns([], []) == []

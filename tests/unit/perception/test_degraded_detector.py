"""The stand-in detector (a test instrument): seeded per frame, misses small objects more, jitters, adds false
boxes, and gives nothing but boxes, class ids and scores."""

from __future__ import annotations

import dataclasses

import numpy as np
import pytest

from uav_common.config import ConfigError, from_mapping
from uav_perception.core.detection.boxes import Box, RawDetection
from uav_perception.core.detection.degrade import DegradeConfig, degrade, frame_rng

IDS = {"person": 0, "vehicle": 2}
W, H = 640, 480


def truth(n: int, size: float, cls: str = "person") -> list[Box]:
    return [Box(cls, IDS[cls], 1.0, 20.0 + 30 * k, 200.0, 20.0 + 30 * k + size, 200.0 + size) for k in range(n)]


def run(
    cfg: DegradeConfig, boxes: list[Box], stamp_ns: int, camera: str = "camera_forward_optical"
) -> list[RawDetection]:
    return degrade(boxes, width_px=W, height_px=H, class_ids=IDS, cfg=cfg, rng=frame_rng(cfg.seed, stamp_ns, camera))


def test_a_frame_degrades_the_same_way_whatever_came_before() -> None:
    cfg = DegradeConfig(seed=4)
    boxes = truth(8, 12.0)
    first = run(cfg, boxes, 1_000_000_000)
    run(cfg, boxes, 2_000_000_000)  # another frame in between changes nothing
    assert run(cfg, boxes, 1_000_000_000) == first
    assert run(cfg, boxes, 1_100_000_000) != first
    assert run(DegradeConfig(seed=5), boxes, 1_000_000_000) != first
    assert run(cfg, boxes, 1_000_000_000, camera="camera_nadir_optical") != first


def test_small_objects_are_missed_more_often_at_the_configured_rates() -> None:
    cfg = DegradeConfig(seed=1, false_positives_per_frame=0.0, jitter_px=0.0, jitter_rel=0.0, confusion_rate=0.0)
    frames = 400
    small = sum(len(run(cfg, truth(10, 4.0), k)) for k in range(frames)) / (10 * frames)
    large = sum(len(run(cfg, truth(10, 40.0), k)) for k in range(frames)) / (10 * frames)
    tol = 3 * np.sqrt(0.25 / (10 * frames))  # 3 binomial standard errors
    assert 1 - small == pytest.approx(cfg.miss_rate_small, abs=tol)
    assert 1 - large == pytest.approx(cfg.miss_rate_large, abs=tol)
    assert cfg.miss_probability(15.0) == pytest.approx((cfg.miss_rate_small + cfg.miss_rate_large) / 2)


def test_jitter_false_positives_and_scores() -> None:
    cfg = DegradeConfig(seed=2, miss_rate_small=0.0, miss_rate_large=0.0, confusion_rate=0.0, jitter_rel=0.1)
    edges_err = []
    false = 0
    frames = 300
    for k in range(frames):
        boxes = truth(4, 30.0)
        out = run(cfg, boxes, k)
        kept = out[: len(boxes)]
        false += len(out) - len(boxes)
        for b, d in zip(boxes, kept, strict=True):
            edges_err.append(d.center_u - d.size_u / 2 - b.u0)
            assert d.hypotheses[0][0] == IDS["person"]
            assert 0.0 < d.hypotheses[0][1] <= 1.0
        for d in out:  # every box stays in the image
            assert d.center_u - d.size_u / 2 >= -0.5
            assert d.center_u + d.size_u / 2 <= W - 0.5
            assert d.center_v - d.size_v / 2 >= -0.5
            assert d.center_v + d.size_v / 2 <= H - 0.5
    assert np.std(edges_err) == pytest.approx(cfg.jitter_px + cfg.jitter_rel * 30.0, rel=0.1)
    assert false / frames == pytest.approx(cfg.false_positives_per_frame, abs=0.1)


def test_it_outputs_boxes_only() -> None:
    # A RawDetection is the contract's Detection2D: centre, size and (class id, score) hypotheses; nothing else.
    assert [f.name for f in dataclasses.fields(RawDetection)] == [
        "center_u",
        "center_v",
        "size_u",
        "size_v",
        "hypotheses",
    ]


def test_bad_settings_are_config_errors() -> None:
    with pytest.raises(ConfigError, match="miss_rate_small must be within"):
        from_mapping(DegradeConfig, {"miss_rate_small": 1.5}, source="~degrade")
    with pytest.raises(ConfigError, match="small_size_px < large_size_px"):
        from_mapping(DegradeConfig, {"small_size_px": 30.0}, source="~degrade")
    with pytest.raises(ConfigError, match="unknown key"):
        from_mapping(DegradeConfig, {"recall": 0.5}, source="~degrade")

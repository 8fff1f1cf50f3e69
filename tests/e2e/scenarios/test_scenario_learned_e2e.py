"""Search and rescue with the learned detector in the loop, end to end (issue 22).

``small_sar_learned.yaml``: the small scenario world (never trained on), uav_perception's detector node running the
shipped ONNX model on the forward camera's images, and nothing else from the ground truth: the geolocator places its
boxes, the tracker and the confirmation work from those placements, the candidate check accepts only the person
the scenario placed. The search must end on that person; the scorer's numbers must be those of a real detector
(false boxes and misses, an AP well below 1) measured against the ground truth.
"""

from __future__ import annotations

import math

import pytest
from e2e.scenarios.test_scenario_e2e import HERE, assert_box_only_search
from helpers.runs import metrics, uav_run

pytestmark = pytest.mark.slow


def test_sar_with_the_learned_detector_finds_the_person() -> None:
    run_dir, out = uav_run(HERE / "small_sar_learned.yaml", "sar_learned", timeout_s=300.0)
    m = metrics(run_dir)
    assert m["final"]
    assert m["stop_reason"] == "target_found", out[-3000:]
    search = m["search"]
    assert search["correct"] is True, search
    assert search["error_m"] < 3.0, search
    det = m["detection"]
    assert det["source"] == "learned"
    # a real detector, scored against the truth: it finds things and makes mistakes
    assert det["tp"] > 20, det["tp"]
    assert det["fp"] > 0
    assert det["fn"] > 0
    assert 0.05 < det["coco"]["AP50"] < 0.95, det["coco"]
    # the person came into view before the search ended on them, and the detector's boxes matched theirs (IoU >= 0.5;
    # for a person a few pixels tall that can come a frame after the placements that confirmed them, as with the
    # stand-in: test_sar_with_box_only_detections_finds_the_person)
    in_view_s = det["person_first_in_view"]["t_s"]
    assert in_view_s is not None
    assert in_view_s <= m["time"]["complete_s"], (det["person_first_in_view"], m["time"])
    first_s = det["person_first_detected"]["t_s"]
    assert first_s is not None
    assert math.isfinite(first_s), det["person_first_detected"]
    assert first_s >= in_view_s
    assert_box_only_search(run_dir, m, "learned")

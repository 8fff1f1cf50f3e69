"""uav-train-detector's torch-free parts: CenterNet targets and crops by hand, the dataset reader's refusals, and
the held-out scoring (pycocotools) on hand-built detections with known answers.

(torch itself is opt-in, requirements-train.txt: the training loop runs in ``make train-detector``; the model it
produced is checked by the preflight test and ``bench/bench_detector.py``, docs/detector.md.)"""

from __future__ import annotations

import json
import math
from pathlib import Path

import numpy as np
import pytest

from uav_perception.training.data import DatasetSplit, Frame, TrainDataError, load_split
from uav_perception.training.evaluate import coco_scores
from uav_perception.training.targets import STRIDE, crop_boxes, make_targets


def test_an_objects_centre_cell_holds_its_peak_offset_and_size() -> None:
    # a 12 x 20 px person with its centre at (30, 50) (pixel edges): cell (row 12, col 7), offset (0.5, 0.5)
    boxes = np.array([[24.0, 40.0, 12.0, 20.0], [100.0, 8.0, 40.0, 20.0]], np.float32)
    heat, offset, logsize, mask = make_targets(boxes, np.array([0, 1]), 2, out_h=32, out_w=48, min_box_px=2.0)
    assert heat.shape == (2, 32, 48)
    assert heat[0, 12, 7] == 1.0
    assert heat[1, 4, 30] == 1.0  # the car: centre (120, 18) -> cell (4, 30)
    assert heat[0].max() == 1.0
    assert heat[0, 12, 9] < 0.5
    assert mask.sum() == 2
    assert mask[12, 7] == 1
    assert mask[4, 30] == 1
    np.testing.assert_allclose(offset[:, 12, 7], (0.5, 0.5))
    np.testing.assert_allclose(logsize[:, 12, 7], (math.log(12), math.log(20)), rtol=1e-6)
    # decoding as the exported model does gives the box back
    cx = (7 + offset[0, 12, 7]) * STRIDE
    cy = (12 + offset[1, 12, 7]) * STRIDE
    assert (cx, cy) == (30.0, 50.0)


def test_boxes_below_the_minimum_and_outside_the_grid_have_no_target() -> None:
    boxes = np.array([[10.0, 10.0, 1.5, 6.0], [500.0, 10.0, 10.0, 10.0]], np.float32)
    heat, _, _, mask = make_targets(boxes, np.array([0, 0]), 1, out_h=16, out_w=16, min_box_px=2.0)
    assert heat.max() == 0.0
    assert mask.sum() == 0


def test_a_crop_keeps_the_boxes_mostly_inside_it_in_crop_coordinates() -> None:
    image = np.zeros((480, 640, 3), np.uint8)
    boxes = np.array([[100.0, 100.0, 10.0, 10.0], [300.0, 300.0, 20.0, 20.0]], np.float32)
    rng = np.random.default_rng(0)
    for _ in range(20):
        crop, b, labels = crop_boxes(image, boxes, np.array([0, 1]), size=192, rng=rng, around=True)
        assert crop.shape == (192, 192, 3)
        assert len(b) >= 1  # the crop is drawn around one of the objects
        assert np.all(b[:, :2] >= 0)
        assert np.all(b[:, 0] + b[:, 2] <= 192)
        assert np.all(b[:, 1] + b[:, 3] <= 192)
        assert set(labels.tolist()) <= {0, 1}


def _frames(boxes_per_frame: list[list[list[float]]]) -> DatasetSplit:
    frames = tuple(
        Frame(k + 1, Path(f"{k}.png"), 640, 480, np.array(b, np.float32).reshape(-1, 4), np.zeros(len(b), np.int64))
        for k, b in enumerate(boxes_per_frame)
    )
    return DatasetSplit(Path("."), "test", ("person",), frames, (7,), {}, {5: 0}, "")


def test_held_out_scores_by_size_bin_have_known_answers() -> None:
    # frame 1: a 10 px person found; frame 2: a 16 px person found and a 4 px person missed; one false box
    data = _frames([[[100, 100, 10, 10]], [[200, 200, 16, 16], [50, 50, 4, 4]]])
    dets = [
        {"image_id": 1, "category_id": 5, "bbox": [100, 100, 10, 10], "score": 0.9},
        {"image_id": 2, "category_id": 5, "bbox": [200, 200, 16, 16], "score": 0.8},
        {"image_id": 2, "category_id": 5, "bbox": [400, 400, 16, 16], "score": 0.95},
    ]
    scores = coco_scores(data, dets)
    person = scores["person"]
    assert person["8-12"]["gt"] == 1
    assert person["8-12"]["AP50"] == pytest.approx(1.0)
    assert person["12-20"]["gt"] == 1
    assert person["12-20"]["AP50"] == pytest.approx(0.5, abs=0.01)  # the false 16 px box outranks the hit
    assert person["1-8"]["gt"] == 1
    assert person["1-8"]["AP50"] == pytest.approx(0.0)
    assert person[">32"]["gt"] == 0
    assert math.isnan(person[">32"]["AP50"])
    assert scores["all"]["all"]["gt"] == 3


def test_a_dataset_folder_that_is_missing_incomplete_or_without_the_split_is_refused(tmp_path: Path) -> None:
    with pytest.raises(TrainDataError, match=r"no dataset.json; make one: uav-dataset generate"):
        load_split(tmp_path, "train")
    (tmp_path / "dataset.json").write_text(json.dumps({"complete": False}))
    with pytest.raises(TrainDataError, match="incomplete; run the same uav-dataset generate command again"):
        load_split(tmp_path, "train")
    (tmp_path / "dataset.json").write_text(json.dumps({"complete": True}))
    (tmp_path / "annotations").mkdir()
    (tmp_path / "annotations" / "instances_test.json").write_text(
        json.dumps({"images": [], "annotations": [], "categories": [{"id": 5, "name": "person"}]})
    )
    with pytest.raises(TrainDataError, match=r"no split 'train' .* its splits: \['test'\]"):
        load_split(tmp_path, "train")
    with pytest.raises(TrainDataError, match=r"no category \['vehicle'\]"):
        load_split(tmp_path, "test")

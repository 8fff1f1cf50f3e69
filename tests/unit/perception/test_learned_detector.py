"""The learned detector's format: hand-built model outputs decoded, NMS, letterbox, and every bad model refused.

The decoding cases are built by hand (a candidate table with known boxes, scores and broken rows); the model
files are hand-made ONNX graphs (tests/helpers/onnx_models.py) loaded through onnxruntime exactly as the
``detector`` node loads them.
"""

from __future__ import annotations

import math
from pathlib import Path

import numpy as np
import pytest
from helpers.onnx_models import constant_detector
from onnx import TensorProto

from uav_common.errors import ResourceError
from uav_perception.core.detection.learned import (
    DecodeConfig,
    Letterbox,
    ModelSpec,
    TensorInfo,
    check_output,
    decode,
    letterbox,
    nms,
    validate_io,
)
from uav_perception.errors import ModelFileError, ModelFormatError
from uav_perception.shell.onnx_detector import OnnxDetector

W, H = 640, 480
IDENTITY = Letterbox(scale=1.0, pad_x=0.0, pad_y=0.0)


def table(*rows: list[float]) -> np.ndarray:
    """Candidates (``cx, cy, w, h, scores...``) -> the model output ``[1, 4 + C, N]``."""
    return np.asarray(rows, dtype=np.float32).T[None]


def run(out: np.ndarray, lb: Letterbox = IDENTITY, **cfg: float) -> tuple[list, dict]:
    dets, discarded = decode(out, lb, width_px=W, height_px=H, class_ids=[0, 2], cfg=DecodeConfig(**cfg))  # type: ignore[arg-type]
    return dets, dict(discarded)


def test_a_box_is_given_in_the_contracts_pixel_convention() -> None:
    # COCO box x 10..20, y 40..60 (pixel edges): columns 10..19, rows 40..59 -> centre (14.5, 49.5), size 10 x 20
    dets, discarded = run(table([15.0, 50.0, 10.0, 20.0, 0.9, 0.1]))
    assert discarded == {}
    (d,) = dets
    assert (d.center_u, d.center_v, d.size_u, d.size_v) == pytest.approx((14.5, 49.5, 10.0, 20.0))
    assert d.hypotheses == ((0, pytest.approx(0.9)),)


def test_the_best_class_decides_and_maps_to_the_ranges_class_id() -> None:
    (d,) = run(table([100.0, 100.0, 30.0, 20.0, 0.2, 0.7]))[0]
    assert d.hypotheses[0][0] == 2  # column 1 -> vehicle, id 2
    assert d.hypotheses[0][1] == pytest.approx(0.7)


def test_nms_keeps_the_best_of_overlapping_boxes_of_one_class_and_both_of_two_classes() -> None:
    out = table(
        [100.0, 100.0, 20.0, 40.0, 0.6, 0.0],  # person, overlaps the next one (IoU ~0.8)
        [101.0, 102.0, 20.0, 40.0, 0.9, 0.0],  # person, best
        [100.0, 100.0, 20.0, 40.0, 0.0, 0.5],  # vehicle at the same place: another class, kept
        [300.0, 300.0, 20.0, 40.0, 0.4, 0.0],  # person elsewhere
    )
    dets, _ = run(out)
    got = [(round(d.center_u), d.hypotheses[0][0], round(d.hypotheses[0][1], 2)) for d in dets]
    assert got == [(100, 0, 0.9), (100, 2, 0.5), (300, 0, 0.4)]


def test_nms_by_hand() -> None:
    boxes = np.array([[0, 0, 10, 10], [1, 1, 11, 11], [20, 20, 30, 30], [0, 0, 10, 10]], dtype=float)
    scores = np.array([0.5, 0.9, 0.3, 0.5])
    assert nms(boxes, scores, 0.5, 10).tolist() == [1, 2]
    assert nms(boxes, scores, 0.99, 10).tolist() == [1, 0, 2]  # identical boxes (IoU 1) still merge
    assert nms(boxes, scores, 0.5, 1).tolist() == [1]


def test_low_scores_are_not_detections_and_are_not_counted() -> None:
    dets, discarded = run(table([100.0, 100.0, 20.0, 20.0, 0.04, 0.01]), score_threshold=0.05)
    assert dets == []
    assert discarded == {}


def test_nan_empty_and_out_of_image_candidates_are_counted_and_discarded() -> None:
    out = table(
        [math.nan, 100.0, 20.0, 20.0, 0.9, 0.0],
        [100.0, 100.0, math.inf, 20.0, 0.9, 0.0],
        [100.0, 100.0, 20.0, 20.0, math.nan, 0.9],
        [100.0, 100.0, 0.0, 20.0, 0.9, 0.0],
        [100.0, 100.0, 20.0, -3.0, 0.9, 0.0],
        [-50.0, 100.0, 20.0, 20.0, 0.9, 0.0],
        [630.0, 100.0, 40.0, 20.0, 0.9, 0.0],  # right edge at 650 > 640 + 2
        [639.0, 479.0, 2.0, 2.0, 0.9, 0.0],  # the corner pixel: kept
        [640.0, 100.0, 4.0, 4.0, 0.9, 0.0],  # 2 px past the edge (within the 2 px margin): kept, clipped
    )
    dets, discarded = run(out)
    assert discarded == {"nan_box": 3, "empty_box": 2, "out_of_image": 2}
    assert len(dets) == 2
    for d in dets:
        assert d.center_u + d.size_u / 2 <= W - 0.5 + 1e-9
        assert d.center_v + d.size_v / 2 <= H - 0.5 + 1e-9


def test_a_letterboxed_input_maps_back_to_the_image() -> None:
    # a 640x480 image in a 320x320 input: scale 0.5, 40 px of padding above and below
    tensor, lb = letterbox(np.full((480, 640, 3), 255, np.uint8), (320, 320))
    assert tensor.shape == (1, 3, 320, 320)
    assert tensor.dtype == np.float32
    assert (lb.scale, lb.pad_x, lb.pad_y) == (0.5, 0.0, 40.0)
    assert tensor[0, :, 40:280].min() == pytest.approx(1.0)
    assert tensor[0, :, :40].max() == pytest.approx(114 / 255)
    # a box over image columns 100..139, rows 200..219 (edges 100..140, 200..220) is input edges 50..70, 140..150
    (d,) = run(table([60.0, 145.0, 20.0, 10.0, 0.9, 0.0]), lb)[0]
    assert (d.center_u, d.center_v, d.size_u, d.size_v) == pytest.approx((119.5, 209.5, 40.0, 20.0))


def test_an_image_of_the_inputs_size_passes_unchanged_and_a_dynamic_input_is_padded_to_32() -> None:
    img = np.random.default_rng(0).integers(0, 256, (480, 640, 3), dtype=np.uint8)
    tensor, lb = letterbox(img, (480, 640))
    assert (lb.scale, lb.pad_x, lb.pad_y) == (1.0, 0.0, 0.0)
    assert np.allclose(tensor[0].transpose(1, 2, 0), img.astype(np.float32) / 255, rtol=0, atol=1e-7)
    tensor, lb = letterbox(img[:470, :600], None)
    assert tensor.shape == (1, 3, 480, 608)
    assert (lb.pad_x, lb.pad_y) == (0.0, 0.0)
    with pytest.raises(ValueError, match="uint8 RGB"):
        letterbox(img.astype(np.float32), None)


GOOD_IN = [TensorInfo("images", (1, 3, 480, 640), "tensor(float)")]
GOOD_OUT = [TensorInfo("output0", (1, 6, 19200), "tensor(float)")]


@pytest.mark.parametrize(
    ("inputs", "outputs", "expected"),
    [
        (GOOD_IN * 2, GOOD_OUT, "2 inputs"),
        (
            [TensorInfo("images", (1, 1, 480, 640), "tensor(float)")],
            GOOD_OUT,
            "expected one input float32 \\[1, 3, H, W\\]",
        ),
        ([TensorInfo("images", (1, 3, 480, 640), "tensor(uint8)")], GOOD_OUT, "tensor\\(uint8\\)"),
        ([TensorInfo("images", (4, 3, 480, 640), "tensor(float)")], GOOD_OUT, "batch 4"),
        ([TensorInfo("images", (1, 3, 480, "w"), "tensor(float)")], GOOD_OUT, "fixes one of H, W"),
        (GOOD_IN, [], "no output"),
        (GOOD_IN, [TensorInfo("output0", (1, 19200), "tensor(float)")], "\\[1, 4 \\+ C, N\\]"),
        (GOOD_IN, [TensorInfo("output0", (1, 4, 19200), "tensor(float)")], "4 rows per candidate"),
    ],
)
def test_a_model_of_another_format_is_refused_naming_the_file_and_the_format(inputs, outputs, expected) -> None:  # type: ignore[no-untyped-def]
    with pytest.raises(ModelFormatError, match=f"^/m/x.onnx: .*{expected}"):
        validate_io("/m/x.onnx", inputs, outputs)


def test_a_good_format_is_read() -> None:
    assert validate_io("m", GOOD_IN, GOOD_OUT) == ModelSpec("images", (480, 640), 2)
    dyn = validate_io(
        "m",
        [TensorInfo("images", ("b", 3, "h", "w"), "tensor(float)")],
        [TensorInfo("o", (1, "c", "n"), "tensor(float)")],
    )
    assert dyn == ModelSpec("images", None, None)
    with pytest.raises(ModelFormatError, match="returned 3 class columns but its metadata uav_classes names 2"):
        check_output("m", np.zeros((1, 7, 10), np.float32), dyn, 2)
    with pytest.raises(ModelFormatError, match="returned float32 \\[6, 10\\]"):
        check_output("m", np.zeros((6, 10), np.float32), dyn, None)


# ---------------------------------------------------------------------------------------------- model files


def test_a_hand_made_model_runs_through_onnxruntime(tmp_path: Path) -> None:
    path = constant_detector(
        tmp_path / "m.onnx",
        [[100, 100, 20, 40, 0.9, 0.1], [300, 200, 50, 30, 0.05, 0.8], [math.nan, 1, 1, 1, 0.9, 0.0]],
    )
    model = OnnxDetector(path)
    assert model.class_names == ["person", "vehicle"]
    assert model.num_classes == 2
    dets, discarded = model.detect(np.zeros((480, 640, 3), np.uint8), [0, 2])
    assert [(d.center_u, d.hypotheses[0][0]) for d in dets] == [(99.5, 0), (299.5, 2)]
    assert dict(discarded) == {"nan_box": 1}


def test_a_missing_model_file_is_a_resource_error_naming_it(tmp_path: Path) -> None:
    with pytest.raises(
        ModelFileError, match=f"{tmp_path}/nope.onnx: no such model file; expected an ONNX detector"
    ) as err:
        OnnxDetector(tmp_path / "nope.onnx")
    assert isinstance(err.value, ResourceError)  # exit code 3


def test_a_corrupt_model_file_is_refused_naming_it(tmp_path: Path) -> None:
    bad = tmp_path / "corrupt.onnx"
    bad.write_bytes(b"\x08\x07garbage" * 100)
    with pytest.raises(ModelFileError, match=f"{bad}: not a loadable ONNX model"):
        OnnxDetector(bad)
    good = constant_detector(tmp_path / "good.onnx", [[100, 100, 20, 40, 0.9, 0.1]])
    cut = tmp_path / "truncated.onnx"
    cut.write_bytes(good.read_bytes()[: good.stat().st_size // 2])
    with pytest.raises(ModelFileError, match=f"{cut}: not a loadable ONNX model"):
        OnnxDetector(cut)


def test_a_model_of_the_wrong_output_shape_is_refused_naming_it(tmp_path: Path) -> None:
    # a classifier-like output [1, 6] (no candidates axis)
    path = constant_detector(tmp_path / "classifier.onnx", [[1, 2, 3, 4, 5, 6]], output_shape=[1, 6])
    with pytest.raises(
        ModelFormatError, match=f"{path}: output 'output0' is tensor\\(float\\) \\[1, 6\\]; expected one input"
    ):
        OnnxDetector(path)
    # metadata naming three classes for two class columns
    path = constant_detector(
        tmp_path / "names.onnx", [[1, 2, 3, 4, 0.5, 0.5]], class_names=["person", "vehicle", "dog"]
    )
    with pytest.raises(ModelFormatError, match=r"returned 2 class columns but declares|uav_classes names 3"):
        OnnxDetector(path)
    # a single-channel input
    path = constant_detector(tmp_path / "gray.onnx", [[1, 2, 3, 4, 0.5, 0.5]], input_shape=(1, 1, 480, 640))
    with pytest.raises(ModelFormatError, match="input 'images' is tensor\\(float\\) \\[1, 1, 480, 640\\]"):
        OnnxDetector(path)
    path = constant_detector(tmp_path / "u8.onnx", [[1, 2, 3, 4, 0.5, 0.5]], input_dtype=TensorProto.UINT8)
    with pytest.raises(ModelFormatError, match="tensor\\(uint8\\)"):
        OnnxDetector(path)

"""COCO RLE against pycocotools, and the text formats written and read back."""

from __future__ import annotations

import numpy as np
import pytest
import yaml
from pycocotools import mask as mask_utils

from uav_datasets.core import rle
from uav_datasets.core.formats import (
    data_yaml,
    kitti_calib,
    kitti_lines,
    kitti_occluded,
    mot_lines,
    parse_kitti,
    parse_mot,
    parse_yolo,
    seqinfo_ini,
    yolo_lines,
)
from uav_datasets.core.records import FrameRecord, InstanceLabel, size_bin


def _masks() -> list[np.ndarray]:
    rng = np.random.default_rng(3)
    out = [np.zeros((7, 5), bool), np.ones((7, 5), bool)]
    m = np.zeros((240, 320), bool)
    m[100:140, 30:37] = True
    m[0, 0] = m[-1, -1] = True
    out.append(m)
    out += [rng.random((48, 64)) < p for p in (0.02, 0.5, 0.97)]
    big = np.zeros((480, 640), bool)
    big[:, 600:] = True  # runs longer than 2^15 pixels: multi-group counts
    out.append(big)
    return out


@pytest.mark.parametrize("k", range(7))
def test_rle_matches_pycocotools(k: int) -> None:
    m = _masks()[k]
    ours = rle.encode(m)
    ref = mask_utils.encode(np.asfortranarray(m.astype(np.uint8)))
    assert ours["counts"] == ref["counts"].decode("ascii")
    assert ours["size"] == [int(v) for v in ref["size"]]
    np.testing.assert_array_equal(rle.decode(ours), m)
    rows, cols = np.nonzero(m)
    order = np.random.default_rng(k).permutation(len(rows))
    assert rle.encode_pixels(rows[order], cols[order], *m.shape) == ours
    assert rle.area(ours) == int(m.sum())
    ref_box = [int(v) for v in mask_utils.toBbox(ref).tolist()]
    assert list(rle.to_bbox(ours)) == ref_box
    assert rle.counts_from_string(ours["counts"]) == [
        int(v) for v in rle._runs(np.flatnonzero(m.ravel(order="F")), m.size)
    ]
    with pytest.raises(ValueError, match="sum to"):
        rle.decode({"size": [m.shape[0] + 1, m.shape[1]], "counts": ours["counts"]})


def _label(iid: int, box: tuple[int, int, int, int], cls: str = "person", vis: float = 1.0) -> InstanceLabel:
    return InstanceLabel(
        instance_id=iid, track_id=iid, class_name=cls, class_id=5 if cls == "person" else 6, object_name=f"{cls}_{iid}",
        bbox=box, bbox_loose=(box[0] - 0.5, box[1] - 0.5, box[2] + 1.0, box[3] + 1.0),
        segmentation={"size": [240, 320], "counts": "0"}, area=box[2] * box[3], unoccluded_pixels=box[2] * box[3],
        visible_fraction=vis, truncation=0.0, range_m=30.0, height_above_ground_m=0.0, camera_height_m=20.0,
        view_angle_deg=40.0, box3d_position_m=(1.0, 2.0, 3.0), box3d_size_m=(0.5, 0.5, 1.8), box3d_yaw_rad=0.3,
        location_camera_m=(0.5, 1.0, 25.0), rotation_y_rad=0.2, alpha_rad=0.18,
    )  # fmt: skip


def _frame(labels: tuple[InstanceLabel, ...], seq_frame: int = 1) -> FrameRecord:
    t = ((1.0, 0.0, 0.0, 5.0), (0.0, -1.0, 0.0, 6.0), (0.0, 0.0, -1.0, 40.0), (0.0, 0.0, 0.0, 1.0))
    return FrameRecord(
        index=seq_frame - 1, name=f"{seq_frame - 1:06d}", split="test", world_seed=3, world_name="w",
        world_hash="ab" * 32, sequence="s1", sequence_frame=seq_frame, timestamp_s=1.5, width=320,
        height=240, fx=200.0, fy=200.0, cx=159.5, cy=119.5, t_map_camera=t, altitude_agl_m=40.0, pitch_deg=90.0,
        yaw_deg=90.0, labels=labels,
    )  # fmt: skip


def test_yolo_kitti_mot_round_trip() -> None:
    labels = (_label(7, (0, 0, 1, 1)), _label(9, (301, 200, 19, 40), "vehicle", 0.4), _label(12, (100, 50, 7, 13)))
    idx = {"person": 0, "vehicle": 1}
    back = parse_yolo(yolo_lines(labels, idx, 320, 240), 320, 240)
    assert [k for k, _ in back] == [0, 1, 0]
    for (_, box), lab in zip(back, labels, strict=True):
        assert max(abs(a - b) for a, b in zip(box, lab.bbox, strict=True)) < 1e-5
    kitti = parse_kitti(kitti_lines(labels))
    assert [t for t, _ in kitti] == ["Pedestrian", "Car", "Pedestrian"]
    assert [tuple(round(v) for v in b) for _, b in kitti] == [lab.bbox for lab in labels]
    assert [kitti_occluded(v) for v in (1.0, 0.9, 0.6, 0.49)] == [0, 0, 1, 2]
    frames = [_frame(labels, 1), _frame(labels[1:], 2)]
    rows = parse_mot(mot_lines(frames))
    assert [(f, t) for f, t, *_ in rows] == [(1, 7), (1, 9), (1, 12), (2, 9), (2, 12)]
    assert rows[1][2] == (301.0, 200.0, 19.0, 40.0)
    assert rows[1][3] == 3  # a vehicle is MOT17's car
    assert rows[0][3] == 1  # a person is a pedestrian
    assert rows[1][4] == pytest.approx(0.4)
    assert "seqLength=2" in seqinfo_ini("s1", frames=2, rate_hz=10.0, width=320, height=240, ext=".png")
    assert "frameRate=10\n" in seqinfo_ini("s1", frames=2, rate_hz=10.0, width=320, height=240, ext=".png")
    data = yaml.safe_load(data_yaml(["train", "val"], ["person", "vehicle"]))
    assert data == {
        "path": ".",
        "train": "images/train",
        "val": "images/val",
        "nc": 2,
        "names": {0: "person", 1: "vehicle"},
    }
    with pytest.raises(ValueError, match="line 1"):
        parse_yolo("0 0.5 0.5", 320, 240)
    with pytest.raises(ValueError, match="line 1"):
        parse_mot("x,y")
    with pytest.raises(ValueError, match="15 fields"):
        parse_kitti("Car 0 0")


def test_kitti_calib_maps_map_points_into_the_image() -> None:
    rec = _frame(())
    lines = dict(line.split(": ", 1) for line in kitti_calib(rec).splitlines())
    p2 = np.array(lines["P2"].split(), float).reshape(3, 4)
    tr = np.array(lines["Tr_velo_to_cam"].split(), float).reshape(3, 4)
    t = np.array(rec.t_map_camera)
    point_cam = np.array([10.0, -5.0, 30.0])
    point_map = t[:3, :3] @ point_cam + t[:3, 3]
    cam = tr @ np.append(point_map, 1.0)
    np.testing.assert_allclose(cam, point_cam, atol=1e-9)
    uv = p2 @ np.append(cam, 1.0)
    np.testing.assert_allclose(uv[:2] / uv[2], [200 * 10 / 30 + 159.5, 200 * -5 / 30 + 119.5])


def test_records_round_trip_and_size_bins() -> None:
    rec = _frame((_label(7, (3, 4, 10, 10)),))
    again = FrameRecord.from_json(rec.to_json())
    assert again.to_json() == rec.to_json()
    assert again.labels[0].size_bin == "8-12"
    assert [size_bin(v) for v in (1.0, 7.99, 8.0, 12.0, 19.9, 20.0, 32.0, 500.0)] == [
        "1-8", "1-8", "8-12", "12-20", "12-20", "20-32", ">32", ">32",
    ]  # fmt: skip
    corners = rec.labels[0].box3d_corners_m
    assert corners.shape == (8, 3)
    assert corners[:, 2].min() == pytest.approx(3.0)
    assert corners[:, 2].max() == pytest.approx(4.8)

"""The pure labelling core on hand-built frames: boxes, projection, truncation, filters, frame geometry."""

from __future__ import annotations

import math

import numpy as np
import pytest

from uav_datasets.core import rle
from uav_datasets.core.config import LabelSpec
from uav_datasets.core.labels import box_corners, frame_geometry, label_instances, project_box, visible_instances
from uav_datasets.core.sampling import optical_pose
from uav_sim_bridge.core.camera import CameraModel, look_at
from uav_sim_bridge.core.objects import ObjectPose, WorldObject
from uav_sim_bridge.core.world_config import ObjectClass

CAM = CameraModel.simple(320, 240, 90.0)


def test_frame_geometry_of_sampled_poses() -> None:
    for pitch_deg in (0.0, 30.0, 89.0, 90.0):
        for yaw_deg in (0.0, 45.0, 200.0):
            pose = optical_pose([1.0, 2.0, 50.0], math.radians(pitch_deg), math.radians(yaw_deg))
            g = frame_geometry(pose, 10.0)
            assert g.altitude_agl_m == pytest.approx(40.0)
            assert g.pitch_deg == pytest.approx(pitch_deg, abs=1e-9)
            assert g.yaw_deg == pytest.approx(yaw_deg, abs=1e-6)
            axis = pose.rotation[:, 2]
            p, y = math.radians(pitch_deg), math.radians(yaw_deg)
            np.testing.assert_allclose(
                axis, [math.cos(p) * math.cos(y), math.cos(p) * math.sin(y), -math.sin(p)], atol=1e-12
            )
            assert pose.rotation[2, 0] == pytest.approx(0.0, abs=1e-12)  # no roll: image rows stay level
    # a nadir view with north at the top of the image (look_at's convention) heads north
    assert frame_geometry(look_at([0, 0, 30], [0, 0, 0]), 0.0).yaw_deg == pytest.approx(90.0)


def _person(iid: int, x: float, y: float, yaw: float = 0.0) -> WorldObject:
    return WorldObject(iid, ObjectClass.PERSON, f"person_{iid}", ObjectPose((x, y, 0.0), yaw), (0.4, 0.5, 1.75))


def test_project_box_matches_the_camera_model_and_clips_at_the_near_plane() -> None:
    pose = look_at([0.0, -20.0, 10.0], [0.0, 0.0, 0.0])
    inv = pose.inverse()
    obj = _person(5, 0.0, 0.0, 0.4)
    corners = box_corners(obj)
    uv, z = CAM.project(inv.apply(corners))
    assert (z > 0).all()
    x0, y0, x1, y1 = project_box(corners, CAM, inv)  # type: ignore[misc]
    assert (x0, y0, x1, y1) == pytest.approx(
        (uv[:, 0].min() + 0.5, uv[:, 1].min() + 0.5, uv[:, 0].max() + 0.5, uv[:, 1].max() + 0.5)
    )
    # a box around the camera: the near plane cuts it, the extent is finite and covers the image
    around = WorldObject(9, ObjectClass.VEHICLE, "v", ObjectPose((0.0, -20.0, 9.0)), (4.0, 4.0, 2.0))
    ext = project_box(box_corners(around), CAM, inv)
    assert ext is not None
    assert all(math.isfinite(v) for v in ext)
    assert ext[0] < 0
    assert ext[2] > CAM.width
    behind = _person(6, 0.0, -40.0)
    assert project_box(box_corners(behind), CAM, inv) is None


def test_visible_instances_and_labels() -> None:
    ids = np.zeros((240, 320), np.uint16)
    ids[100:120, 150:160] = 5  # person 5, fully visible
    ids[100:104, 170:172] = 6  # person 6: 8 pixels
    ids[200:202, 10:11] = 7  # person 7: 2 pixels, below min_pixels
    ids[0:50, 0:50] = 3  # a building: not a labelled class
    labelled = np.zeros(8, bool)
    labelled[[5, 6, 7]] = True
    cands = visible_instances(ids, labelled, 4)
    assert sorted(cands) == [5, 6]
    c5 = cands[5]
    assert (c5.x_min, c5.y_min, c5.x_max, c5.y_max, c5.visible_pixels) == (150, 100, 159, 119, 200)
    pose = look_at([0.0, -20.0, 10.0], [0.0, 0.0, 0.0])
    objects = {5: _person(5, 0.0, 0.0), 6: _person(6, 1.0, 2.0)}
    spec = LabelSpec(classes=("person",), min_visible_pixels=4)
    labels = label_instances(
        cands, objects=objects, unoccluded_pixels={5: 200, 6: 32}, camera=CAM, t_map_optical=pose,
        terrain_height=lambda x, y: -0.25, spec=spec,
    )  # fmt: skip
    assert [lab.instance_id for lab in labels] == [5, 6]
    a, b = labels
    assert a.bbox == (150, 100, 10, 20)
    assert rle.to_bbox(a.segmentation) == a.bbox
    assert rle.area(a.segmentation) == a.area == 200
    np.testing.assert_array_equal(rle.decode(a.segmentation), ids == 5)
    assert a.visible_fraction == 1.0
    assert b.visible_fraction == 0.25
    assert a.range_m == pytest.approx(math.dist((0, -20, 10), (0, 0, 0.875)))
    assert a.height_above_ground_m == pytest.approx(0.25)
    assert a.camera_height_m == pytest.approx(10.0)
    assert a.view_angle_deg == pytest.approx(math.degrees(math.atan2(10 - 0.875, 20)))
    assert a.truncation == 0.0
    assert a.location_camera_m[2] > 0
    assert a.track_id == 5
    # the filters
    assert [lab.instance_id for lab in label_instances(
        cands, objects=objects, unoccluded_pixels={5: 200, 6: 32}, camera=CAM, t_map_optical=pose,
        terrain_height=lambda x, y: 0.0, spec=LabelSpec(classes=("person",), min_visible_fraction=0.5),
    )] == [5]  # fmt: skip
    far = {5: _person(5, 0.0, 100.0), 6: _person(6, 1.0, 2.0)}
    assert [lab.instance_id for lab in label_instances(
        cands, objects=far, unoccluded_pixels={}, camera=CAM, t_map_optical=pose,
        terrain_height=lambda x, y: 0.0, spec=LabelSpec(classes=("person",), max_range_m=50.0),
    )] == [6]  # fmt: skip
    assert label_instances(
        cands, objects=objects, unoccluded_pixels={}, camera=CAM, t_map_optical=pose,
        terrain_height=lambda x, y: 0.0, spec=LabelSpec(classes=("vehicle",)),
    ) == []  # fmt: skip


def test_truncation_at_the_border() -> None:
    pose = look_at([0.0, 0.0, 20.0], [0.0, 0.0, 0.0])  # nadir, north up: x east to the right
    cam = CameraModel.simple(320, 240, 60.0)
    inv = pose.inverse()
    half_width_m = 20.0 * math.tan(math.radians(30.0))
    inside = WorldObject(5, ObjectClass.VEHICLE, "v", ObjectPose((0.0, 0.0, 0.0)), (4.0, 2.0, 1.5))
    edge = WorldObject(6, ObjectClass.VEHICLE, "w", ObjectPose((half_width_m, 0.0, 0.0)), (4.0, 2.0, 1.5))
    ids = np.zeros((240, 320), np.uint16)
    ids[110:130, 140:180] = 5
    ids[110:130, 300:320] = 6
    labelled = np.zeros(7, bool)
    labelled[[5, 6]] = True
    labels = label_instances(
        visible_instances(ids, labelled, 4), objects={5: inside, 6: edge}, unoccluded_pixels={}, camera=cam,
        t_map_optical=pose, terrain_height=lambda x, y: 0.0, spec=LabelSpec(),
    )  # fmt: skip
    assert labels[0].truncation == 0.0
    uv, _ = cam.project(inv.apply(box_corners(edge)))
    u0, u1 = uv[:, 0].min() + 0.5, uv[:, 0].max() + 0.5  # its projected box straddles the right edge
    assert u0 < cam.width < u1
    assert labels[1].truncation == pytest.approx(1.0 - (cam.width - u0) / (u1 - u0))
    assert 0.5 < labels[1].truncation < 0.7  # its top, nearer the camera, leaves the image more than its base
    x, _, w, _ = labels[1].bbox_loose
    assert x + w == pytest.approx(320.0)  # the loose box is clipped to the image
    ext = project_box(box_corners(inside), cam, inv)
    assert ext is not None
    assert labels[0].bbox_loose == pytest.approx((ext[0], ext[1], ext[2] - ext[0], ext[3] - ext[1]))

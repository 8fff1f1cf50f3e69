"""Ground-truth detections as a person walks in and out of the frame and of range."""

from __future__ import annotations

import math

import numpy as np
import pytest

from uav_sim_bridge.core.camera import CameraModel, look_at
from uav_sim_bridge.core.detections import DetectionConfig, ground_truth_detections, visible_candidates
from uav_sim_bridge.core.objects import ObjectPose, WorldObject
from uav_sim_bridge.core.transforms import RigidTransform
from uav_sim_bridge.core.world import World
from uav_sim_bridge.core.world_config import ObjectClass
from uav_sim_bridge.render import Renderer

CFG = DetectionConfig(classes=("person",), max_range_m=100.0, min_pixels=4)


@pytest.fixture(scope="module")
def scene(flat_world_with_people: tuple[World, Renderer]) -> tuple[World, Renderer]:
    return flat_world_with_people


def _detect(renderer: Renderer, cam: CameraModel, pose: RigidTransform, objs: dict[int, WorldObject]):
    """What the bridge does: render, find candidates, count their unoccluded pixels, register."""
    frame = renderer.render(cam, pose)
    cands = visible_candidates(frame.instance_id, pose, objs, CFG)
    alone = renderer.unoccluded_pixel_counts(cam, pose, cands)
    dets = ground_truth_detections(frame.instance_id, pose, {i: objs[i] for i in cands}, CFG, alone)
    # The candidates are exactly the detected objects, so the bridge computes detections for them only.
    assert dets == ground_truth_detections(frame.instance_id, pose, objs, CFG, alone)
    assert [d.instance_id for d in dets] == cands
    return dets, frame


def test_person_walks_through_the_frame(scene: tuple[World, Renderer]) -> None:
    world, renderer = scene
    person = world.objects_of_class(ObjectClass.PERSON)[0]
    cam = CameraModel.simple(320, 240, 60.0)
    pose = look_at([0.0, -40.0, 20.0], [0.0, 0.0, 0.0])  # looking north, the frame spans x in about [-25, 25]
    seen = []
    for x in np.arange(-60.0, 61.0, 5.0):
        moved = WorldObject(
            person.instance_id, person.object_class, person.name, ObjectPose((x, 0.0, 0.0)), person.size_m
        )
        renderer.set_object_pose(person.instance_id, moved.pose)
        dets, frame = _detect(renderer, cam, pose, {moved.instance_id: moved})
        seen.append(bool(dets))
        if dets:
            d = dets[0]
            assert d.instance_id == person.instance_id
            assert d.object_class is ObjectClass.PERSON
            ys, xs = np.nonzero(frame.instance_id == person.instance_id)
            assert (d.x_min, d.y_min, d.x_max, d.y_max) == (xs.min(), ys.min(), xs.max(), ys.max())
            assert d.range_m == pytest.approx(math.dist(moved.center_m, pose.translation_m))
            uv, _ = cam.project(pose.inverse().apply(moved.center_m[None]))
            assert d.x_min - 1 <= uv[0, 0] <= d.x_max + 1
    xs = np.arange(-60.0, 61.0, 5.0)
    inside = np.abs(xs) <= 20.0
    outside = np.abs(xs) >= 35.0
    assert all(np.array(seen)[inside])  # appears while in the frame
    assert not any(np.array(seen)[outside])  # and disappears when it leaves


def test_person_walks_out_of_range(scene: tuple[World, Renderer]) -> None:
    world, renderer = scene
    person = world.objects_of_class(ObjectClass.PERSON)[0]
    cam = CameraModel.simple(640, 480, 20.0)  # a narrow lens, so a person 150 m away is still many pixels
    eye = np.array([0.0, -10.0, 10.0])
    results = {}
    for dist in (60.0, 95.0, 105.0, 150.0):
        target = np.array([0.0, -10.0 + dist, 0.0])
        moved = WorldObject(
            person.instance_id, person.object_class, person.name, ObjectPose(tuple(target)), person.size_m
        )
        renderer.set_object_pose(person.instance_id, moved.pose)
        pose = look_at(eye, target + np.array([0.0, 0.0, 0.86]))
        dets, frame = _detect(renderer, cam, pose, {moved.instance_id: moved})
        assert (frame.instance_id == person.instance_id).sum() >= 4  # in frame at every distance
        results[dist] = bool(dets)
    assert results == {60.0: True, 95.0: True, 105.0: False, 150.0: False}


def test_occlusion_and_visible_fraction(scene: tuple[World, Renderer]) -> None:
    world, renderer = scene
    # the widest person in front, the slimmest behind (same height), both facing the camera: the one behind is
    # hidden
    people = sorted(world.objects_of_class(ObjectClass.PERSON), key=lambda o: o.shape[1])
    near, far = people[-1], people[0]
    cam = CameraModel.simple(320, 240, 40.0)
    pose = look_at([0.0, -20.0, 0.9], [0.0, 0.0, 0.9])  # eye level, looking north

    def place(x_far: float) -> list:
        objs = {
            near.instance_id: WorldObject(
                near.instance_id,
                near.object_class,
                near.name,
                ObjectPose((0.0, 0.0, 0.0), -math.pi / 2),
                near.size_m,
            ),
            far.instance_id: WorldObject(
                far.instance_id,
                far.object_class,
                far.name,
                ObjectPose((x_far, 4.0, 0.0), -math.pi / 2),
                far.size_m,
            ),
        }
        for o in objs.values():
            renderer.set_object_pose(o.instance_id, o.pose)
        return _detect(renderer, cam, pose, objs)[0]

    dets = {d.instance_id: d for d in place(0.0)}  # the far person right behind the near one
    assert dets[near.instance_id].visible_fraction == pytest.approx(1.0)
    # an articulated figure has gaps (between the legs, under the arms): at most a sliver shows through them
    assert far.instance_id not in dets or dets[far.instance_id].visible_fraction < 0.15
    dets = {d.instance_id: d for d in place(0.25)}  # half hidden
    assert 0.1 < dets[far.instance_id].visible_fraction < 0.9
    dets = {d.instance_id: d for d in place(3.0)}  # side by side
    assert dets[far.instance_id].visible_fraction == pytest.approx(1.0)


def test_classes_and_minimum_pixels() -> None:
    ids = np.zeros((10, 10), np.uint16)
    ids[2:4, 2:4] = 7  # 4 pixels
    ids[6, 6] = 8  # 1 pixel
    objs = [
        WorldObject(7, ObjectClass.VEHICLE, "car", ObjectPose((0.0, 0.0, 0.0)), (4.0, 2.0, 1.5)),
        WorldObject(8, ObjectClass.PERSON, "p", ObjectPose((1.0, 0.0, 0.0)), (0.5, 0.5, 1.7)),
        WorldObject(9, ObjectClass.TREE, "t", ObjectPose((1.0, 0.0, 0.0)), (3.0, 3.0, 9.0)),
    ]
    pose = RigidTransform.from_rpy([0.0, 0.0, 30.0])
    dets = ground_truth_detections(ids, pose, objs, DetectionConfig())
    assert [(d.instance_id, d.x_min, d.y_min, d.x_max, d.y_max) for d in dets] == [(7, 2, 2, 3, 3)]
    assert dets[0].visible_fraction == 1.0
    assert ground_truth_detections(ids, pose, objs, DetectionConfig(classes=("tree",))) == []
    far = DetectionConfig(max_range_m=10.0)
    assert ground_truth_detections(ids, pose, objs, far) == []
    assert visible_candidates(ids, pose, objs, DetectionConfig()) == [7]
    with pytest.raises(ValueError, match="unknown object class"):
        DetectionConfig(classes=("dragon",))


def test_unoccluded_pixels_count_each_pixel_once(scene: tuple[World, Renderer]) -> None:
    """Drawn alone, a person covers exactly the pixels it covers in the frame when nothing is in front, from any
    view: seen from above its head overlaps its torso and legs, and those pixels count once, not three times."""
    world, renderer = scene
    person, *others = world.objects_of_class(ObjectClass.PERSON)
    for k, o in enumerate(others):
        renderer.set_object_pose(o.instance_id, ObjectPose((80.0 + 5 * k, 80.0, 0.0)))
    renderer.set_object_pose(person.instance_id, ObjectPose((0.0, 0.0, 0.0), 0.3))
    cam = CameraModel.simple(320, 240, 60.0)
    for eye in ([0.0, 0.0, 15.0], [0.0, -10.0, 8.0], [3.0, -6.0, 2.0], [5.0, 5.0, 30.0], [0.0, -20.0, 1.0]):
        pose = look_at(eye, [0.0, 0.0, 0.8])
        visible = int((renderer.render(cam, pose).instance_id == person.instance_id).sum())
        assert visible > 10  # in view (the articulated figure, ~0.3 m across, covers ~19 px from 30 m up)
        assert renderer.unoccluded_pixel_counts(cam, pose, [person.instance_id]) == {person.instance_id: visible}


def test_unoccluded_pixels_of_static_objects(small_world: World, small_renderer: Renderer) -> None:
    """Buildings and trees can be drawn alone too; a building with nothing in front covers what it covers alone."""
    cam = CameraModel.simple(320, 240, 50.0)
    exact = 0
    buildings = small_world.objects_of_class(ObjectClass.BUILDING)
    for b in buildings:
        c = b.center_m
        pose = look_at(c + np.array([0.0, 0.0, 60.0]), c)
        ids = small_renderer.render(cam, pose).instance_id
        visible = int((ids == b.instance_id).sum())
        alone = small_renderer.unoccluded_pixel_counts(cam, pose, [b.instance_id])[b.instance_id]
        assert alone >= visible > 0
        rows, cols = np.nonzero(ids == b.instance_id)
        around = ids[max(0, rows.min() - 2) : rows.max() + 3, max(0, cols.min() - 2) : cols.max() + 3]
        cls = small_world.instance_class[around]
        if not np.isin(cls, [ObjectClass.TREE, ObjectClass.PERSON, ObjectClass.VEHICLE]).any():
            exact += 1
            assert alone == visible, b.name
    assert exact >= len(buildings) // 3
    tree = small_world.objects_of_class(ObjectClass.TREE)[0]
    pose = look_at(tree.center_m + np.array([0.0, -30.0, 20.0]), tree.center_m)
    assert small_renderer.unoccluded_pixel_counts(cam, pose, [tree.instance_id])[tree.instance_id] > 0
    with pytest.raises(KeyError, match="drawn alone"):
        small_renderer.unoccluded_pixel_counts(cam, pose, [1])  # the terrain

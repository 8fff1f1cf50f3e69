"""GL renderer against the world model: depth, ids, projection, culling; PNGs for people."""

from __future__ import annotations

import math
import threading
from pathlib import Path

import numpy as np
import pytest
from PIL import Image

from uav_sim_bridge.core import visualize
from uav_sim_bridge.core.camera import CameraConfig, CameraModel, MountConfig, look_at
from uav_sim_bridge.core.objects import ObjectPose
from uav_sim_bridge.core.transforms import RigidTransform
from uav_sim_bridge.core.world import World
from uav_sim_bridge.core.world_config import ObjectClass
from uav_sim_bridge.errors import RenderError
from uav_sim_bridge.render import Renderer, RenderSettings

NADIR = CameraModel.from_config("nadir", CameraConfig(hfov_deg=90.0, mount=MountConfig(rpy_deg=(0, 90, 0))))
FORWARD = CameraModel.from_config("forward", CameraConfig(hfov_deg=90.0, mount=MountConfig(rpy_deg=(0, 25, 0))))


@pytest.fixture(scope="module")
def flat_renderer(flat_world: World):
    r = Renderer(flat_world)
    yield r
    r.close()


@pytest.mark.parametrize("altitude_m", [50.0, 12.5, 120.0])
def test_nadir_centre_depth_is_altitude_over_flat_ground(flat_renderer: Renderer, altitude_m: float) -> None:
    pose = NADIR.optical_pose(RigidTransform.from_rpy([3.0, -7.0, altitude_m], yaw_rad=0.7))
    frame = flat_renderer.render(NADIR, pose)
    h, w = frame.depth_m.shape
    centre = frame.depth_m[h // 2 - 1 : h // 2 + 1, w // 2 - 1 : w // 2 + 1]
    assert np.abs(centre - altitude_m).max() < 0.01
    # z-depth of a nadir view over flat ground is the altitude everywhere
    assert np.nanmax(np.abs(frame.depth_m - altitude_m)) < 0.01
    assert (frame.instance_id == 1).all()


def _world_points(frame_depth: np.ndarray, cam: CameraModel, pose: RigidTransform) -> np.ndarray:
    rows, cols = np.mgrid[0 : cam.height, 0 : cam.width]
    pts = cam.unproject(np.stack([cols.ravel(), rows.ravel()], 1), frame_depth.ravel())
    return pose.apply(pts).reshape(cam.height, cam.width, 3)


POSES = [((0.0, 0.0), 0.4), ((150.0, -60.0), 2.0), ((-250.0, 130.0), -0.6), ((60.0, 200.0), 1.2)]


def _views(world: World, xy: tuple[float, float], yaw: float) -> list[tuple[CameraModel, RigidTransform]]:
    """The nadir and forward cameras of a vehicle 40 m above the ground at ``xy``, heading ``yaw``."""
    z = float(world.height_at(*xy)) + 40.0
    base = RigidTransform.from_rpy([xy[0], xy[1], z], yaw_rad=yaw)
    return [(cam, cam.optical_pose(base)) for cam in (NADIR, FORWARD)]


@pytest.mark.parametrize(("xy", "yaw"), POSES)
def test_segmentation_ids_and_depth_match_the_object_list(
    default_world: World, default_renderer: Renderer, xy: tuple[float, float], yaw: float
) -> None:
    for cam, pose in _views(default_world, xy, yaw):
        frame = default_renderer.render(cam, pose)
        ids = frame.instance_id
        assert ids.max() <= len(default_world.objects)
        sky = ids == 0
        assert np.array_equal(sky, np.isnan(frame.depth_m))
        p = _world_points(frame.depth_m, cam, pose)
        # terrain pixels lie on the terrain heightfield
        ter = ids == 1
        err = np.abs(p[ter][:, 2] - default_world.height_at(p[ter][:, 0], p[ter][:, 1]))
        assert np.percentile(err, 99.9) < 0.05, err.max()
        # object pixels lie inside (or on) the object's box
        for iid in np.unique(ids[~sky & ~ter]):
            obj = default_world.object(int(iid))
            local = obj.pose.to_local(p[ids == iid])
            sx, sy, sz = obj.size_m
            building = obj.object_class is ObjectClass.BUILDING
            tol = 1.0 if building else 0.6  # roof overhang, trunks
            below = 4.6 if building else 1.0  # walls reach down to the lowest corner of the lot
            if obj.object_class is ObjectClass.ROAD:
                lo = np.array(obj.pose.position_m) - [sx / 2, sy / 2, 0]
                inside = np.all((p[ids == iid] >= lo - 0.5) & (p[ids == iid] <= lo + [sx, sy, sz] + 0.5), axis=1)
            else:
                inside = (
                    (np.abs(local[:, 0]) <= sx / 2 + tol)
                    & (np.abs(local[:, 1]) <= sy / 2 + tol)
                    & (local[:, 2] >= -below)
                    & (local[:, 2] <= sz + 0.1)
                )
            assert inside.mean() > 0.995, (obj.name, inside.mean())


@pytest.mark.parametrize(("xy", "yaw"), POSES)
def test_the_instance_only_pass_gives_the_full_renders_ids(
    default_world: World, default_renderer: Renderer, xy: tuple[float, float], yaw: float
) -> None:
    """Detections use the cheaper instance-only pass: the same ids, 0 for the sky and beyond its far plane."""
    for cam, pose in _views(default_world, xy, yaw):
        full = default_renderer.render(cam, pose)
        ids = default_renderer.render_instances(cam, pose)
        assert ids.dtype == np.uint16
        assert np.array_equal(ids, full.instance_id)
        assert (ids == 0).any() == (cam is FORWARD)  # the forward camera sees the sky
        near_ids = default_renderer.render_instances(cam, pose, draw_within_m=80.0)
        # only tiles wholly beyond 80 m are skipped: what is nearer is exactly the full render's
        within = full.depth_m <= 80.0
        assert (near_ids[within] == full.instance_id[within]).all()
        if cam is FORWARD:
            assert (near_ids[full.depth_m > 200.0] == 0).mean() > 0.9  # the distant scene is not drawn


def test_the_detection_pass_gives_the_full_renders_ids_around_vehicles_exactly(
    default_world: World, default_renderer: Renderer
) -> None:
    """The bridge's detection-only render (nothing drawn past range + the largest object) and a full render, as
    the data engine re-renders a flight's frame, give the same id at every pixel within range, also where a
    vehicle meets a slope: the boxes of the ground-truth detections and of the dataset's labels are equal. A
    projection with a shorter far plane (what the bridge used before) changed the depth precision and with it
    a few pixels in most of these views, now and then the edge of a vehicle's box."""
    cam = CameraModel.from_config(
        "forward", CameraConfig(width=480, height=360, hfov_deg=90.0, mount=MountConfig(rpy_deg=(0, 25, 0)))
    )
    rng = np.random.default_rng(1)
    draw_within_m = 112.0  # the bridge's detection range (100 m) plus the largest object, plus 1 m
    views = 0
    for vehicle in default_world.objects_of_class(ObjectClass.VEHICLE)[:20]:
        ox, oy, oz = vehicle.pose.position_m
        for _ in range(2):  # 30-100 m away, 15-60 m above it, the vehicle anywhere in the frame
            d, a = rng.uniform(30.0, 100.0), rng.uniform(-math.pi, math.pi)
            base = RigidTransform.from_rpy(
                [ox - d * math.cos(a), oy - d * math.sin(a), oz + rng.uniform(15.0, 60.0)],
                yaw_rad=a + rng.uniform(-0.7, 0.7),
            )
            pose = cam.optical_pose(base)
            full = default_renderer.render(cam, pose)
            ids = default_renderer.render_instances(cam, pose, draw_within_m=draw_within_m)
            within = full.depth_m <= draw_within_m
            where = f"{vehicle.name}, view {views}"
            np.testing.assert_array_equal(ids[within], full.instance_id[within], err_msg=where)
            views += (full.instance_id == vehicle.instance_id).any()
    assert views >= 20  # most views show their vehicle
    with pytest.raises(ValueError, match="draw_within_m"):
        default_renderer.render_instances(cam, pose, draw_within_m=0.0)


def test_people_appear_where_the_camera_model_projects_them(default_world: World, default_renderer: Renderer) -> None:
    seen = 0
    for person in default_world.objects_of_class(ObjectClass.PERSON)[:10]:
        target = person.center_m
        pose = look_at(target + np.array([0.0, -6.0, 8.0]), target)
        cam = CameraModel.simple(320, 240, 60.0)
        frame = default_renderer.render(cam, pose)
        uv, z = cam.project(pose.inverse().apply(target[None]))
        u, v = np.rint(uv[0]).astype(int)
        if frame.instance_id[v, u] == person.instance_id:
            seen += 1
            assert abs(float(frame.depth_m[v, u]) - z[0]) < 0.6  # the body's front face is nearer than its centre
    assert seen >= 8  # a few may hide behind a tree


def test_moving_a_person(default_world: World) -> None:
    renderer = Renderer(default_world)
    try:
        person = default_world.objects_of_class(ObjectClass.PERSON)[0]
        cam = CameraModel.simple(160, 120, 60.0)
        spot = np.array([40.0, 0.0])
        ground = float(default_world.height_at(*spot))
        pose = look_at([spot[0], spot[1] - 5.0, ground + 6.0], [spot[0], spot[1], ground + 0.8])
        assert not (renderer.render(cam, pose).instance_id == person.instance_id).any()
        renderer.set_object_pose(person.instance_id, ObjectPose((spot[0], spot[1], ground), 0.3))
        assert (renderer.render(cam, pose).instance_id == person.instance_id).sum() > 100
        assert renderer.object_pose(person.instance_id).position_m[0] == spot[0]
        alone = renderer.unoccluded_pixel_counts(cam, pose, [person.instance_id])
        assert alone[person.instance_id] >= (renderer.render(cam, pose).instance_id == person.instance_id).sum()
        with pytest.raises(KeyError, match="not a movable"):
            renderer.set_object_pose(1, ObjectPose((0.0, 0.0, 0.0)))
    finally:
        renderer.close()


def test_culling_and_lod_do_not_change_near_content(default_world: World, default_renderer: Renderer) -> None:
    full = Renderer(default_world, RenderSettings(frustum_culling=False, lod_distance_m=1e9))
    culled_only = Renderer(default_world, RenderSettings(lod_distance_m=1e9))
    try:
        base = RigidTransform.from_rpy([-250.0, 130.0, float(default_world.height_at(-250, 130)) + 35], yaw_rad=-0.6)
        for cam in (NADIR, FORWARD):
            pose = cam.optical_pose(base)
            a = full.render(cam, pose)
            b = culled_only.render(cam, pose)
            np.testing.assert_array_equal(a.instance_id, b.instance_id)
            np.testing.assert_array_equal(a.color_rgb, b.color_rgb)
            assert culled_only.last_triangles < full.last_triangles
            c = default_renderer.render(cam, pose)  # with LOD: differs only far away
            differ = a.instance_id != c.instance_id
            if cam is FORWARD:
                assert differ.any()  # the forward camera sees distant low-detail trees
            if differ.any():
                assert (np.nan_to_num(a.depth_m[differ], nan=1e9) > 100.0).mean() > 0.95
    finally:
        full.close()
        culled_only.close()


def test_several_renderers_in_one_thread_keep_their_own_scenes(
    flat_renderer: Renderer, default_renderer: Renderer, default_world: World
) -> None:
    pose = NADIR.optical_pose(RigidTransform.from_rpy([150.0, -60.0, float(default_world.height_at(150, -60)) + 40]))
    a1 = default_renderer.render(NADIR, pose)
    flat = flat_renderer.render(NADIR, pose)
    a2 = default_renderer.render(NADIR, pose)
    extra = Renderer(default_world)  # a new context becomes current on creation
    try:
        a3 = default_renderer.render(NADIR, pose)
        b = extra.render(NADIR, pose)
    finally:
        extra.close()
    a4 = default_renderer.render(NADIR, pose)
    assert (flat.instance_id <= 1).all()  # the flat world has nothing but terrain
    assert len(np.unique(a1.instance_id)) > 3
    for other in (a2, a3, b, a4):
        np.testing.assert_array_equal(other.instance_id, a1.instance_id)
        np.testing.assert_array_equal(other.color_rgb, a1.color_rgb)


def test_renderer_is_bound_to_its_thread(flat_renderer: Renderer) -> None:
    errors: list[BaseException] = []

    def other() -> None:
        try:
            flat_renderer.render(NADIR, look_at([0, 0, 10], [0, 0, 0]))
        except BaseException as err:
            errors.append(err)

    t = threading.Thread(target=other)
    t.start()
    t.join(10)
    assert len(errors) == 1
    assert isinstance(errors[0], RenderError)


def test_save_pngs_for_people(default_world: World, default_renderer: Renderer, artifacts: Path) -> None:
    """Writes color / depth / class / instance PNGs of both cameras at home and over villages, and an overview.

    Nadir views are 60 m above each place; forward views come from 90 m south-west of
    it, 40 m above the ground, heading towards it.
    """
    frames: list[np.ndarray] = []
    places = [("home", (0.0, 0.0))] + [
        (f"village_{k}", tuple(v)) for k, v in enumerate(default_world.roads.villages_m[:3])
    ]
    for name, (x, y) in places:
        fx, fy = x - 64.0, y - 64.0
        views = [
            (NADIR, RigidTransform.from_rpy([x, y, float(default_world.height_at(x, y)) + 60.0], yaw_rad=0.8)),
            (
                FORWARD,
                RigidTransform.from_rpy(
                    [fx, fy, float(default_world.height_at(fx, fy)) + 40.0], yaw_rad=math.atan2(y - fy, x - fx)
                ),
            ),
        ]
        for cam, base in views:
            f = default_renderer.render(cam, cam.optical_pose(base))
            Image.fromarray(f.color_rgb).save(artifacts / f"{name}_{cam.name}_color.png")
            Image.fromarray(visualize.depth_image(f.depth_m)).save(artifacts / f"{name}_{cam.name}_depth.png")
            Image.fromarray(visualize.class_image(f.instance_id, default_world.instance_class)).save(
                artifacts / f"{name}_{cam.name}_class.png"
            )
            Image.fromarray(visualize.instance_image(f.instance_id)).save(artifacts / f"{name}_{cam.name}_instance.png")
            assert f.color_rgb.std() > 10  # textured, not a flat fill
            frames.append(f.color_rgb)
            if name.startswith("village"):  # a village shows buildings and a road
                classes = set(np.unique(default_world.instance_class[f.instance_id]).tolist())
                assert {int(ObjectClass.BUILDING), int(ObjectClass.ROAD)} <= classes, (name, cam.name, classes)
    for i in range(len(frames)):
        for j in range(i + 1, len(frames)):
            assert not np.array_equal(frames[i], frames[j]), "every view is different"
    overview = CameraModel.simple(1024, 768, 60.0)
    f = default_renderer.render(overview, look_at([0, -1050, 800], [0, 0, 0]))
    Image.fromarray(f.color_rgb).save(artifacts / "overview.png")
    assert (f.instance_id > 0).mean() > 0.3
    assert len(list(artifacts.glob("*.png"))) == 4 * 2 * 4 + 1
    assert math.isfinite(float(np.nanmean(f.depth_m)))


@pytest.mark.parametrize("eye_xy", [(0.0, 0.0), (-9.0, 6.0), (8.0, -7.0)])
def test_the_landing_pad_is_painted_at_home_and_nowhere_else(
    flat_renderer: Renderer, eye_xy: tuple[float, float]
) -> None:
    """Only the tiles touching the pad are drawn with the pad shader: the H, the ring and the concrete must still
    appear exactly around home, seen from straight above or from the side, and the grass beyond must not."""
    pose = NADIR.optical_pose(RigidTransform.from_rpy([eye_xy[0], eye_xy[1], 40.0], yaw_rad=0.3))
    frame = flat_renderer.render(NADIR, pose)
    half = flat_renderer.settings.pad_half_size_m
    # map points on the ground (z = 0): the H's middle bar, its ring, the concrete's corner, and grass outside
    points = {
        "bar": (0.0, 0.0),
        "ring": (0.72 * half, 0.0),
        "concrete": (-0.9 * half, 0.9 * half),
        "grass": (1.6 * half, -1.6 * half),
    }
    colour = {}
    for name, (x, y) in points.items():
        uv, _ = NADIR.project(pose.inverse().apply(np.array([[x, y, 0.0]])))
        col, row = np.rint(uv[0]).astype(int)
        colour[name] = frame.color_rgb[row, col].astype(int)
    r, g, b = colour["ring"]
    assert min(r, g) > 90, colour  # yellow paint
    assert b < 0.5 * r, colour
    assert np.ptp(colour["concrete"]) < 25, colour  # grey
    assert np.ptp(colour["bar"]) < 25, colour  # white paint: grey, and brighter than the concrete
    assert colour["bar"].min() > colour["concrete"].max() + 10, colour
    r, g, b = colour["grass"]
    assert g > b + 15, colour  # the flat world's grass, no pad

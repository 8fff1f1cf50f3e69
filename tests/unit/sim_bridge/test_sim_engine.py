"""BridgeEngine: camera scheduling, noise, collisions, terrain reports, object moves (GL, no ROS)."""

from __future__ import annotations

import math
from dataclasses import replace

import numpy as np
import pytest

from uav_common.geo import GeoPoint, LocalProjection
from uav_sim_bridge.config import SimBridgeConfig
from uav_sim_bridge.core.sensor_noise import NoiseConfig
from uav_sim_bridge.core.transforms import RigidTransform
from uav_sim_bridge.core.vehicle_state import VehicleState
from uav_sim_bridge.core.world import World
from uav_sim_bridge.core.world_config import ObjectClass
from uav_sim_bridge.engine import BridgeEngine
from uav_sim_bridge.render import Renderer

HOME = GeoPoint(47.397742, 8.545594, 488.0)


def _state(t: float, xyz: tuple[float, float, float], yaw: float = 0.0, v: float = 0.0) -> VehicleState:
    return VehicleState(t, RigidTransform.from_rpy(list(xyz), yaw_rad=yaw), np.array([v, 0.0, 0.0]))


@pytest.fixture(scope="module")
def engine_of(small_world: World, small_renderer: Renderer):
    def make(**changes: object) -> BridgeEngine:
        return BridgeEngine(replace(SimBridgeConfig(), **changes), small_world, small_renderer)  # type: ignore[arg-type]

    return make


def test_cameras_follow_their_rates_and_consumers(engine_of) -> None:
    eng = engine_of()
    wanted = {"nadir"}
    counts = {"nadir": 0, "forward": 0}
    for k in range(50):  # 1 s of 50 Hz states
        out = eng.step(
            _state(0.02 * k, (0.0, 0.0, 40.0)), home=None, wanted=lambda n: n in wanted, want_detections=False
        )
        for c in out.cameras:
            counts[c.camera.name] += 1
            assert c.frame.color_rgb.shape == (480, 640, 3)
            assert c.depth_m is c.frame.depth_m  # no noise configured
            assert c.detections is None
    assert counts == {"nadir": 5, "forward": 0}  # the default nadir (mapping) camera runs at 5 Hz
    wanted = {"nadir", "forward"}
    counts = {"nadir": 0, "forward": 0}
    for k in range(50, 100):  # the next second, both cameras consumed: each at its own rate
        out = eng.step(
            _state(0.02 * k, (0.0, 0.0, 40.0)), home=None, wanted=lambda n: n in wanted, want_detections=False
        )
        for c in out.cameras:
            counts[c.camera.name] += 1
    assert counts == {"nadir": 5, "forward": 10}
    out = engine_of().step(_state(0.0, (0.0, 0.0, 40.0)), home=None, wanted=lambda n: False)
    assert sorted(c.camera.name for c in out.cameras) == ["forward", "nadir"]  # detections still need them
    assert all(c.detections is not None for c in out.cameras)
    assert all(c.frame is None and c.depth_m is None for c in out.cameras)  # ... and only their instance ids


def test_detection_only_render_detects_what_the_full_render_does(engine_of, small_world: World) -> None:
    """With nothing but detections consumed, the cheap instance-only render (clipped past the detection
    range) must register the same objects, boxes and visible pixels as the full render."""
    eng_full, eng_cheap = engine_of(), engine_of()
    targets = [*small_world.objects_of_class(ObjectClass.PERSON), *small_world.objects_of_class(ObjectClass.VEHICLE)]
    seen, t = 0, 0.0
    for k, obj in enumerate(targets[:8]):
        ox, oy, oz = obj.pose.position_m
        for dist_m in (25.0, 70.0, 95.0):
            yaw = 0.7 * k  # approach from several sides, camera looking at the object
            x, y = ox - dist_m * math.cos(yaw), oy - dist_m * math.sin(yaw)
            t += 0.2  # both cameras due (nadir 5 Hz, forward 10 Hz)
            state = _state(t, (x, y, oz + 0.45 * dist_m), yaw=yaw)
            full = eng_full.step(state, home=None, wanted=lambda n: True)
            cheap = eng_cheap.step(state, home=None, wanted=lambda n: False)
            assert len(full.cameras) == len(cheap.cameras) == 2
            for a, b in zip(full.cameras, cheap.cameras, strict=True):
                assert b.frame is None
                da = {d.instance_id: d for d in a.detections or []}
                db = {d.instance_id: d for d in b.detections or []}
                assert da.keys() == db.keys(), (obj.name, dist_m, a.camera.name)
                for iid, d in da.items():
                    e = db[iid]
                    assert abs(d.visible_pixels - e.visible_pixels) <= max(2, 0.01 * d.visible_pixels)
                    assert abs(d.visible_fraction - e.visible_fraction) < 0.02
                    box_a, box_b = (d.x_min, d.y_min, d.x_max, d.y_max), (e.x_min, e.y_min, e.x_max, e.y_max)
                    assert box_a == pytest.approx(box_b, abs=1)
                seen += obj.instance_id in da
    assert seen >= 8  # the comparison saw the objects themselves, not just empty frames


def test_a_view_without_people_or_vehicles_is_not_rendered_for_detections(engine_of, small_world: World) -> None:
    """A detection-only camera skips its render when no person or vehicle can be in view; the detections are
    those of the full render and the objects' detections regardless."""
    eng_full, eng_cheap = engine_of(), engine_of()
    renders = []
    real = eng_cheap.renderer.render_instances
    targets = [*small_world.objects_of_class(ObjectClass.PERSON), *small_world.objects_of_class(ObjectClass.VEHICLE)]
    rng = np.random.default_rng(5)
    skipped = seen = 0
    t = 0.0
    try:
        eng_cheap.renderer.render_instances = lambda *a, **k: renders.append(1) or real(*a, **k)  # type: ignore[method-assign]
        for k in range(60):
            obj = targets[k % len(targets)]
            ox, oy, oz = obj.pose.position_m
            # around the objects, at random headings: sometimes facing them, often not
            x, y = ox + rng.uniform(-80.0, 80.0), oy + rng.uniform(-80.0, 80.0)
            t += 0.1
            state = _state(t, (x, y, oz + rng.uniform(15.0, 60.0)), yaw=rng.uniform(-math.pi, math.pi))
            before = len(renders)
            full = eng_full.step(state, home=None, wanted=lambda n: True)
            cheap = eng_cheap.step(state, home=None, wanted=lambda n: False)
            for a, b in zip(full.cameras, cheap.cameras, strict=True):
                assert b.detections is not None
                assert [d.instance_id for d in a.detections or []] == [d.instance_id for d in b.detections]
                seen += len(b.detections)
                if not eng_cheap.detectables_in_view(eng_cheap._detection_cameras[b.camera.name], b.t_map_optical):
                    assert b.detections == []
            skipped += 2 - (len(renders) - before)
    finally:
        del eng_cheap.renderer.render_instances
    assert skipped > 10  # both cases happened
    assert seen > 5
    # a person moved into an empty view is seen there (the spheres follow the objects)
    eng = engine_of()
    person = small_world.objects_of_class(ObjectClass.PERSON)[0]
    px, py, pz = person.pose.position_m
    cam = eng._detection_cameras["forward"]
    views = (
        cam.optical_pose(RigidTransform.from_rpy([px + dx, py + dy, pz + 25.0], yaw_rad=yaw))
        for dx in (-150.0, -60.0, 60.0, 150.0)
        for dy in (-150.0, -60.0, 60.0, 150.0)
        for yaw in (0.0, 1.6, 3.1, 4.7)
    )
    pose = next(v for v in views if not eng.detectables_in_view(cam, v))  # a view with nobody in it
    spot = pose.apply(np.array([[0.0, 0.0, 30.0]]))[0]  # 30 m ahead of the camera
    eng.move_object(person.instance_id, float(spot[0]), float(spot[1]), None, 0.0)
    assert eng.detectables_in_view(cam, pose)


def test_noise_degrades_only_what_it_should_and_is_reproducible(engine_of) -> None:
    noisy = NoiseConfig(enabled=True, seed=11)

    def run() -> list:
        eng = engine_of(noise=noisy)
        return [eng.step(_state(0.1 * k, (5.0, 5.0, 30.0)), home=None, wanted=lambda n: n == "nadir") for k in range(3)]

    a, b = run(), run()
    for x, y in zip(a, b, strict=True):
        np.testing.assert_array_equal(x.published_pose.matrix(), y.published_pose.matrix())
        np.testing.assert_array_equal(x.cameras[0].depth_m, y.cameras[0].depth_m)
    first = a[0]
    assert not np.allclose(first.published_pose.translation_m, first.state.position_m, atol=1e-6)
    assert np.linalg.norm(first.published_pose.translation_m - first.state.position_m) < 1.0
    cam = first.cameras[0]
    assert np.isnan(cam.depth_m).sum() > np.isnan(cam.frame.depth_m).sum()  # dropouts
    both = np.isfinite(cam.depth_m) & np.isfinite(cam.frame.depth_m)
    assert 0.0 < np.abs(cam.depth_m[both] - cam.frame.depth_m[both]).mean() < 1.0


def test_terrain_report_uses_roads_and_roofs(engine_of, small_world: World) -> None:
    eng = engine_of()
    b = small_world.objects_of_class(ObjectClass.BUILDING)[0]
    x, y, _ = b.pose.position_m
    over_roof = eng.terrain_report(_state(1.0, (x, y, b.pose.position_m[2] + b.size_m[2] + 20.0)), HOME)
    assert over_roof is not None
    assert over_roof.instance_id == b.instance_id
    assert over_roof.terrain_amsl_m > HOME.alt_amsl_m + small_world.height_at(x, y) + 2.5
    geo = LocalProjection(HOME).to_ned(GeoPoint(over_roof.lat_deg, over_roof.lon_deg, 0.0))
    assert geo[:2] == pytest.approx((y, x), abs=1e-6)
    beside_wall = eng.terrain_report(_state(1.0, (x, y, small_world.height_at(x, y) + 1.0)), HOME)
    assert beside_wall is not None
    assert beside_wall.instance_id == 1  # below the roof: the ground under the vehicle is the terrain
    home = eng.terrain_report(_state(1.0, (0.0, 0.0, 12.0)), HOME)
    assert home is not None
    assert (home.terrain_amsl_m, home.above_terrain_m) == pytest.approx((488.0, 12.0))
    assert eng.terrain_report(_state(1.0, (0.0, 0.0, 12.0)), None) is None


def test_collisions_with_walls_and_trees_but_not_ground_or_roofs(engine_of, small_world: World) -> None:
    b = small_world.objects_of_class(ObjectClass.BUILDING)[0]
    x, y, z = b.pose.position_m
    yaw = b.pose.yaw_rad
    ux, uy = math.cos(yaw), math.sin(yaw)
    outside = (x - ux * (b.size_m[0] / 2 + 6), y - uy * (b.size_m[0] / 2 + 6), z + 1.5)
    inside = (x, y, z + 1.5)
    eng = engine_of()
    quiet = lambda n: False  # noqa: E731
    assert eng.step(_state(0.0, outside), home=None, wanted=quiet, want_detections=False).new_contacts == []
    hits = eng.step(_state(0.5, inside), home=None, wanted=quiet, want_detections=False).new_contacts
    assert [(h.instance_id, h.object_class) for h in hits] == [(b.instance_id, ObjectClass.BUILDING)]
    # still touching the same wall: not reported again
    assert (
        eng.step(
            _state(0.52, (inside[0] + 0.01, inside[1], inside[2])), home=None, wanted=quiet, want_detections=False
        ).new_contacts
        == []
    )
    # standing on the ground, or on the roof: no collision
    eng = engine_of()
    gx, gy = 0.0, 0.0
    assert eng.step(_state(0.0, (gx, gy, 0.2)), home=None, wanted=quiet, want_detections=False).new_contacts == []
    roof_z, iid = small_world.ground_height_at(x, y)
    assert iid == b.instance_id
    assert (
        eng.step(_state(1.0, (x, y, roof_z + 0.3)), home=None, wanted=quiet, want_detections=False).new_contacts == []
    )
    # flying into a tree crown: the path between two states is swept, so entering the crown counts
    tree = small_world.objects_of_class(ObjectClass.TREE)[0]
    tx, ty, tz = tree.pose.position_m
    z_mid = tz + tree.size_m[2] * 0.6
    eng = engine_of()
    assert (
        eng.step(_state(3.0, (tx - 12.0, ty, z_mid)), home=None, wanted=quiet, want_detections=False).new_contacts == []
    )
    hits = eng.step(_state(3.5, (tx, ty, z_mid)), home=None, wanted=quiet, want_detections=False).new_contacts
    assert tree.instance_id in [h.instance_id for h in hits]
    assert {h.object_class for h in hits} == {ObjectClass.TREE}


def test_flying_into_the_terrain_is_a_collision(engine_of, small_world: World) -> None:
    # JSBSim's flat ground is clamped to the gear when the terrain jumps above it, so only the bridge can tell
    # that the vehicle went into a hillside: a swept position deeper than its radius below the surface.
    quiet = lambda n: False  # noqa: E731
    xs = np.linspace(-60.0, 60.0, 121)
    heights = small_world.height_at(xs, np.zeros_like(xs))
    low, high = int(np.argmin(heights)), int(np.argmax(heights))
    assert heights[high] - heights[low] > 2.0, "the test world needs some relief"
    cruise_z = float(heights[low]) + 1.0  # 1 m above the low point, below the high one
    eng = engine_of()
    first = eng.step(_state(0.0, (float(xs[low]), 0.0, cruise_z)), home=None, wanted=quiet, want_detections=False)
    assert first.new_contacts == []
    hits = eng.step(_state(5.0, (float(xs[high]), 0.0, cruise_z)), home=None, wanted=quiet, want_detections=False)
    terrain = [h for h in hits.new_contacts if h.object_class is ObjectClass.TERRAIN]
    assert len(terrain) == 1
    x_hit, _, z_ground = terrain[0].point_m
    assert z_ground > cruise_z + eng.cfg.collision.vehicle_radius_m  # where the path went under the surface
    assert min(xs[low], xs[high]) <= x_hit <= max(xs[low], xs[high])


def test_move_object_and_errors(engine_of, small_world: World) -> None:
    eng = engine_of()
    person = small_world.objects_of_class(ObjectClass.PERSON)[0]
    moved = eng.move_object(person.name, 30.0, -20.0, None, 1.0)
    assert moved.pose.position_m == pytest.approx((30.0, -20.0, small_world.ground_height_at(30.0, -20.0)[0]))
    assert eng.lookup(person.instance_id).pose == moved.pose
    hit = eng.step(
        _state(0.0, (30.0, -20.0, moved.pose.position_m[2] + 1.2)),
        home=None,
        wanted=lambda n: False,
        want_detections=False,
    )
    assert [c.instance_id for c in hit.new_contacts] == [person.instance_id]
    with pytest.raises(KeyError, match="cannot be moved"):
        eng.move_object("terrain", 0.0, 0.0, None, 0.0)
    with pytest.raises(KeyError):
        eng.move_object("nobody", 0.0, 0.0, None, 0.0)
    with pytest.raises(ValueError, match="finite"):
        eng.move_object(person.name, math.nan, 0.0, None, 0.0)


def test_object_poses_from_config(small_world: World, small_renderer: Renderer) -> None:
    person = small_world.objects_of_class(ObjectClass.PERSON)[1]
    cfg = replace(SimBridgeConfig(), object_poses={person.name: (12.0, 34.0, 90.0)})
    eng = BridgeEngine(cfg, small_world, small_renderer)
    pose = eng.lookup(person.name).pose
    assert pose.position_m[:2] == (12.0, 34.0)
    assert pose.yaw_rad == pytest.approx(math.pi / 2)
    assert small_renderer.object_pose(person.instance_id) == pose

"""World realism: articulated people and vehicles, moving objects, the sun, shadows, camera effects (GL, no ROS)."""

from __future__ import annotations

import math
from collections.abc import Iterator
from dataclasses import replace

import cv2
import numpy as np
import pytest
from sim_worlds import flat_config, small_config

from uav_common.config import ConfigError, from_mapping
from uav_sim_bridge.config import SimBridgeConfig, environment_presets, resolve_environment
from uav_sim_bridge.core import figures
from uav_sim_bridge.core.camera import CameraConfig, CameraModel, MountConfig, look_at
from uav_sim_bridge.core.camera_effects import (
    CameraEffects,
    CameraEffectsConfig,
    CameraMotion,
    DefocusConfig,
    ExposureConfig,
    SensorNoiseConfig,
    camera_rng,
)
from uav_sim_bridge.core.environment import EnvironmentConfig
from uav_sim_bridge.core.figures import VEHICLE_ROLES, PersonPose, VehicleType
from uav_sim_bridge.core.lighting import Lighting, lighting_for, sun_position
from uav_sim_bridge.core.motion import (
    ActorOverride,
    ActorsConfig,
    PeopleMotionConfig,
    VehicleMotionConfig,
    plan_motion,
)
from uav_sim_bridge.core.objects import ObjectPose
from uav_sim_bridge.core.transforms import RigidTransform
from uav_sim_bridge.core.vehicle_state import VehicleState
from uav_sim_bridge.core.world import World
from uav_sim_bridge.core.world_config import ObjectClass, PeopleConfig, WorldConfig
from uav_sim_bridge.engine import BridgeEngine
from uav_sim_bridge.errors import SimBridgeConfigError
from uav_sim_bridge.render import RenderedFrame, Renderer
from uav_sim_bridge.shell.world_store import generate_world

MOVERS = ActorsConfig(people=PeopleMotionConfig(moving=5), vehicles=VehicleMotionConfig(moving=3))


@pytest.fixture(scope="module")
def world() -> World:
    """A small world with every kind of content (its own copy: the tests below move its objects)."""
    return generate_world(small_config(seed=5))


@pytest.fixture(scope="module")
def renderer(world: World) -> Iterator[Renderer]:
    r = Renderer(world)
    yield r
    r.close()


@pytest.fixture(scope="module")
def flat_people() -> Iterator[tuple[World, Renderer]]:
    people = PeopleConfig(count=3, poses={"standing": 1.0}, height_m=(1.8, 1.8))
    w = generate_world(flat_config(people=people))
    r = Renderer(w)
    yield w, r
    r.close()


def _nadir(width: int = 320, height: int = 240) -> CameraModel:
    return CameraModel.simple(width, height, 90.0, name="nadir")


def _state(t: float, xyz: tuple[float, float, float], yaw: float = 0.0) -> VehicleState:
    return VehicleState(t, RigidTransform.from_rpy(list(xyz), yaw_rad=yaw))


def _env(preset: str, **over: object) -> EnvironmentConfig:
    return from_mapping(EnvironmentConfig, resolve_environment({"preset": preset, **over}), source=preset)


# ------------------------------------------------------------------------------------------------ people
def test_people_are_articulated_in_every_pose_and_deterministic() -> None:
    _faces, roles = figures.person_faces()
    assert set(roles.tolist()) == set(range(len(figures.PERSON_ROLES)))  # skin, clothes, shoes, hair...
    heights = {}
    for pose in PersonPose:
        v = figures.person_vertices([1.75], [1.0], [int(pose)], [0.3])[0]
        assert v.shape == (figures.person_vertices([1.6], [1.1], [0])[0].shape)  # one topology for every pose
        assert v[:, 2].min() == pytest.approx(0.0, abs=1e-9)  # stands (sits, lies) on the ground
        size = figures.person_boxes([1.75], [1.0], [int(pose)])[0]
        heights[pose] = size[2]
        if pose is not PersonPose.WALKING:  # a still pose: its box is the footprint centred on the origin
            lo, hi = v.min(axis=0), v.max(axis=0)
            np.testing.assert_allclose((lo[:2] + hi[:2]) / 2, 0.0, atol=1e-9)
            np.testing.assert_allclose(hi - np.array([*lo[:2], 0.0]), size, atol=1e-9)
        again = figures.person_vertices([1.75], [1.0], [int(pose)], [0.3])[0]
        assert np.array_equal(v, again)  # deterministic
    assert heights[PersonPose.STANDING] > 1.65
    assert heights[PersonPose.SITTING] < 1.3
    assert heights[PersonPose.LYING] < 0.5
    lying = figures.person_boxes([1.75], [1.0], [int(PersonPose.LYING)])[0]
    assert lying[0] > 1.6  # lying along its local x
    # the gait: limbs swing with the phase, the cycle repeats every stride
    a = figures.person_vertices([1.75], [1.0], [1], [0.0])[0]
    b = figures.person_vertices([1.75], [1.0], [1], [0.25])[0]
    c = figures.person_vertices([1.75], [1.0], [1], [1.0])[0]
    assert np.abs(a - b).max() > 0.2
    np.testing.assert_allclose(a, c, atol=1e-9)
    assert figures.gait_phase(1.45, 1.75) == pytest.approx(0.0, abs=1e-9)
    assert figures.gait_phase(0.725, 1.75) == pytest.approx(0.5)


def test_vehicles_have_body_cabin_wheels_and_windows() -> None:
    sizes = {t: figures.VEHICLE_SIZE_M[t] for t in VehicleType}
    assert sizes[VehicleType.CAR][0] < sizes[VehicleType.VAN][0] < sizes[VehicleType.TRUCK][0]
    assert sizes[VehicleType.CAR][2] < sizes[VehicleType.VAN][2] < sizes[VehicleType.TRUCK][2]
    for t in VehicleType:
        verts, faces, roles = figures.vehicle_template(t)
        names = {VEHICLE_ROLES[r] for r in roles.tolist()}
        assert {"paint", "glass", "tyre", "light", "tail_light"} <= names, t
        lo, hi = verts.min(axis=0), verts.max(axis=0)
        np.testing.assert_allclose((lo[:2] + hi[:2]) / 2, 0.0, atol=1e-9)
        assert lo[2] == pytest.approx(0.0)
        # every part (body, cabin, wheels, lights...) is a closed surface whose faces turn outwards: its signed
        # volume (divergence theorem) is positive
        assert all(v > 1e-4 for v in _part_volumes(verts, faces)), t
    faces, _ = figures.person_faces()
    for pose in PersonPose:
        verts = figures.person_vertices([1.75], [1.0], [int(pose)], [0.4])[0]
        assert all(v > 1e-5 for v in _part_volumes(verts, faces)), pose


def _part_volumes(verts: np.ndarray, faces: np.ndarray) -> list[float]:
    """Signed volume of each connected part of a mesh (parts share no vertex)."""
    parent = list(range(len(verts)))

    def find(i: int) -> int:
        while parent[i] != i:
            parent[i] = parent[parent[i]]
            i = parent[i]
        return i

    for a, b, c in faces:
        for x, y in ((a, b), (b, c)):
            parent[find(int(x))] = find(int(y))
    part = np.array([find(int(f[0])) for f in faces])
    tri = verts[faces]
    vol = np.einsum("ij,ij->i", tri[:, 0], np.cross(tri[:, 1], tri[:, 2])) / 6.0
    return [float(vol[part == p].sum()) for p in np.unique(part)]


def test_generated_people_and_vehicles_follow_the_config(world: World) -> None:
    people = world.objects_of_class(ObjectClass.PERSON)
    vehicles = world.objects_of_class(ObjectClass.VEHICLE)
    assert {p.kind for p in people} <= {"standing", "sitting", "lying"}
    assert len({p.kind for p in people}) >= 2
    assert {v.kind for v in vehicles} <= {"car", "van", "truck"}
    for p in people:
        h, b = p.shape
        assert 1.55 <= h <= 1.95
        np.testing.assert_allclose(p.size_m, figures.person_boxes([h], [b], [int(PersonPose.from_label(p.kind))])[0])
    for v in vehicles:
        assert v.size_m == figures.VEHICLE_SIZE_M[VehicleType.from_label(v.kind)]
    # the 3D box of every person and vehicle holds its mesh
    for o in people + vehicles:
        tris = world.triangles(world.face_instance == o.instance_id).reshape(-1, 3)
        local = o.pose.to_local(tris)
        half = np.array(o.size_m[:2]) / 2 + 1e-4
        assert np.all(np.abs(local[:, :2]) <= half), o.name
        assert local[:, 2].min() >= -1e-4, o.name
        assert local[:, 2].max() <= o.size_m[2] + 1e-4, o.name
    only_lying = replace(small_config(seed=5), people=PeopleConfig(count=4, poses={"lying": 1.0}))
    assert {p.kind for p in generate_world(only_lying).objects_of_class(ObjectClass.PERSON)} == {"lying"}


# ------------------------------------------------------------------------------------------------ motion
def test_motion_is_seeded_configurable_and_stays_on_roads_and_paths(world: World) -> None:
    plan = plan_motion(world.objects, world.roads, world.terrain.bounds_m, world.config, MOVERS)
    again = plan_motion(world.objects, world.roads, world.terrain.bounds_m, world.config, MOVERS)
    assert [m.obj.name for m in plan.movers] == [m.obj.name for m in again.movers]
    walkers = [m for m in plan.movers if m.obj.object_class is ObjectClass.PERSON]
    drivers = [m for m in plan.movers if m.obj.object_class is ObjectClass.VEHICLE]
    assert len(walkers) == 5
    assert len(drivers) == 3
    assert all(1.0 <= m.speed_mps <= 1.6 for m in walkers)
    assert all(7.0 <= m.speed_mps <= 13.0 for m in drivers)
    other = plan_motion(world.objects, world.roads, world.terrain.bounds_m, world.config, replace(MOVERS, seed=99))
    assert [m.obj.name for m in other.movers] != [m.obj.name for m in plan.movers]
    lines = np.concatenate([np.asarray(p) for p in world.roads.polylines])
    for t in (0.0, 7.3, 33.0, 120.0):
        states = plan.states_at(t, world.terrain)
        assert states == again.states_at(t, world.terrain)  # a pure function of time
        for m, st in zip(plan.movers, states, strict=True):
            x, y, z = st.pose.position_m
            assert z == pytest.approx(float(world.height_at(x, y)) + m.z_lift_m)
            if m.obj.object_class is ObjectClass.VEHICLE:  # in a lane: 1.4 m from the centreline (curves: less)
                d = float(np.min(np.hypot(lines[:, 0] - x, lines[:, 1] - y)))
                assert 0.5 < d < 2.5, (m.obj.name, t, d)
            speed = math.hypot(*st.velocity_mps[:2])
            assert speed == pytest.approx(m.speed_mps)
    # how many, which and how fast: per world and per run
    custom = ActorsConfig(
        people=PeopleMotionConfig(moving=0),
        vehicles=VehicleMotionConfig(moving=0),
        objects={"person_0002": ActorOverride(motion="path", path_m=((50.0, 50.0), (80.0, 50.0)), speed_mps=2.0)},
    )
    plan2 = plan_motion(world.objects, world.roads, world.terrain.bounds_m, world.config, custom)
    assert [m.obj.name for m in plan2.movers] == ["person_0002"]
    xs = [plan2.states_at(t, world.terrain)[0].pose.position_m[0] for t in np.arange(0.0, 30.0, 0.5)]
    assert min(xs) == pytest.approx(50.0, abs=1.1)
    assert max(xs) == pytest.approx(80.0, abs=1.1)
    world_cfg = replace(world.config, people=replace(world.config.people, moving=2))
    none = ActorsConfig()
    assert len(plan_motion(world.objects, world.roads, world.terrain.bounds_m, world_cfg, none).movers) == 2


def test_motion_errors_name_the_key(world: World) -> None:
    def plan(actors: ActorsConfig, cfg: WorldConfig | None = None, roads: object = None) -> object:
        return plan_motion(world.objects, roads or world.roads, world.terrain.bounds_m, cfg or world.config, actors)  # type: ignore[arg-type]

    with pytest.raises(SimBridgeConfigError, match=r"actors\.objects\.nobody: no person or vehicle"):
        plan(ActorsConfig(objects={"nobody": ActorOverride(motion="random")}))
    with pytest.raises(SimBridgeConfigError, match=r"actors\.objects\.vehicle_0000\.motion: random"):
        plan(ActorsConfig(objects={"vehicle_0000": ActorOverride(motion="random")}))
    with pytest.raises(SimBridgeConfigError, match=r"actors\.objects\.vehicle_0000\.pose: only people"):
        plan(ActorsConfig(objects={"vehicle_0000": ActorOverride(pose="lying")}))
    no_roads = replace(world.roads, polylines=())
    with pytest.raises(SimBridgeConfigError, match=r"actors\.vehicles\.moving: 2 vehicles should drive .* no roads"):
        plan(ActorsConfig(vehicles=VehicleMotionConfig(moving=2)), roads=no_roads)
    with pytest.raises(SimBridgeConfigError, match=r"actors\.objects\.person_0001\.motion: road: .* no road"):
        plan(ActorsConfig(objects={"person_0001": ActorOverride(motion="road")}), roads=no_roads)
    with pytest.raises(ValueError, match="motion: path needs path_m"):
        ActorOverride(motion="path")
    # the world file itself: a world without roads cannot have driving vehicles
    with pytest.raises(ConfigError, match=r"world\.yaml: top level: vehicles\.moving is 2 .* no roads"):
        from_mapping(
            WorldConfig,
            {"roads": {"villages": 0}, "vehicles": {"count": 3, "moving": 2}},
            source="world.yaml",
        )
    with pytest.raises(ConfigError, match=r"'people'.*moving must be in \[0, count = 3\]"):
        from_mapping(WorldConfig, {"people": {"count": 3, "moving": 4}}, source="world.yaml")


def test_moving_person_ground_truth_matches_its_rendered_mask(flat_people: tuple[World, Renderer]) -> None:
    world, renderer = flat_people
    walker = world.objects_of_class(ObjectClass.PERSON)[0]
    actors = ActorsConfig(
        objects={walker.name: ActorOverride(motion="path", path_m=((30.0, 30.0), (42.0, 36.0)), speed_mps=1.4)}
    )
    cams = {
        "nadir": CameraConfig(width=320, height=240, hfov_deg=70.0, rate_hz=2.0, mount=MountConfig(rpy_deg=(0, 90, 0)))
    }
    cfg = replace(
        SimBridgeConfig(),
        cameras=cams,
        detections=replace(SimBridgeConfig().detections, cameras=("nadir",)),
        actors=actors,
    )
    eng = BridgeEngine(cfg, world, renderer)
    cam = eng.cameras["nadir"]
    seen = 0
    previous = None
    for k in range(12):  # 6 s of a walk, one frame every 0.5 s
        t = 0.5 * k
        out = eng.step(_state(t, (36.0, 33.0, 18.0)), home=None, wanted=lambda _n: True)
        (cam_out,) = out.cameras
        assert cam_out.frame is not None
        assert cam_out.detections is not None
        truth = next(s for s in eng.object_states() if s.obj.instance_id == walker.instance_id)
        assert truth.moving
        assert truth.obj.kind == "walking"
        mask = cam_out.frame.instance_id == walker.instance_id
        assert mask.sum() > 30
        rows, cols = np.nonzero(mask)
        # the ground-truth box centre projects onto the person's pixels, at the mask's centre
        uv, _ = cam.project(cam_out.t_map_optical.inverse().apply(truth.obj.center_m[None]))
        u, v = uv[0]
        assert abs(u - cols.mean()) < 4.0, (t, u, cols.mean())
        assert abs(v - rows.mean()) < 4.0, (t, v, rows.mean())
        det = next(d for d in cam_out.detections if d.instance_id == walker.instance_id)
        np.testing.assert_allclose(det.position_m, truth.obj.center_m, atol=1e-9)
        assert (det.x_min, det.y_min, det.x_max, det.y_max) == (cols.min(), rows.min(), cols.max(), rows.max())
        if previous is not None:
            moved = np.hypot(*(np.array(truth.obj.pose.position_m[:2]) - previous))
            assert moved == pytest.approx(0.7, abs=0.05)  # 1.4 m/s for 0.5 s
        previous = np.array(truth.obj.pose.position_m[:2])
        seen += 1
    assert seen == 12
    # lockstep: the same time gives the same world, whatever happened in between
    eng.sync_movers(2.0, render=True)
    a = renderer.render(cam, look_at([36.0, 33.0, 18.0], [36.0, 33.0, 0.0])).instance_id
    eng.sync_movers(5.5, render=True)
    eng.sync_movers(2.0, render=True)
    b = renderer.render(cam, look_at([36.0, 33.0, 18.0], [36.0, 33.0, 0.0])).instance_id
    assert np.array_equal(a, b)


def test_moved_objects_leave_their_path_and_states_are_published(world: World, renderer: Renderer) -> None:
    cfg = replace(
        SimBridgeConfig(), actors=MOVERS, publish=replace(SimBridgeConfig().publish, object_states_rate_hz=2.0)
    )
    eng = BridgeEngine(cfg, world, renderer)
    walker = next(m.obj for m in eng.motion.movers if m.obj.object_class is ObjectClass.PERSON)
    got = [eng.step(_state(0.1 * k, (0.0, 0.0, 300.0)), home=None, wanted=lambda _n: False).objects for k in range(11)]
    published = [o for o in got if o is not None]
    assert len(published) == 3  # t = 0, 0.5, 1.0 at 2 Hz
    assert {s.obj.instance_id for s in published[0]} == {m.obj.instance_id for m in eng.motion.movers}
    first = {s.obj.instance_id: s.obj.pose.position_m for s in published[0]}
    last = {s.obj.instance_id: s.obj.pose.position_m for s in published[-1]}
    assert all(math.dist(first[i], last[i]) > 0.5 for i in first)  # everyone moved in one second
    moved = eng.move_object(walker.name, 10.0, 10.0, None, 0.0)
    assert moved.kind != "walking"  # stopped walking: back in its still pose
    for t in (2.0, 3.0):
        eng.sync_movers(t)
        st = next(s for s in eng.object_states() if s.obj.instance_id == walker.instance_id)
        assert not st.moving
        assert st.obj.pose.position_m[:2] == (10.0, 10.0)
    # collisions follow the moving vehicles
    driver = next(m for m in eng.motion.movers if m.obj.object_class is ObjectClass.VEHICLE)
    t = 4.0
    st = next(s for s in eng.motion.states_at(t, world.terrain) if s.instance_id == driver.obj.instance_id)
    x, y, z = st.pose.position_m
    side = 0.5 * driver.obj.size_m[1] + 0.2  # just beside its door: the sphere (0.35 m) touches the side
    yaw = st.pose.yaw_rad
    out = eng.step(
        _state(t, (x - math.sin(yaw) * side, y + math.cos(yaw) * side, z + 0.7)), home=None, wanted=lambda _n: False
    )
    assert driver.obj.instance_id in {c.instance_id for c in out.new_contacts}


# ------------------------------------------------------------------------------------------------ sun and light
def test_sun_position_from_time_date_and_latitude() -> None:
    az, el = sun_position(12.0, 172, 47.4)
    assert el == pytest.approx(90 - 47.4 + 23.44, abs=0.6)
    assert az == pytest.approx(180.0, abs=1.0)
    az, el = sun_position(12.0, 80, 0.0)  # equinox at the equator: overhead
    assert el > 88.0
    morning, evening = sun_position(8.0, 172, 47.4), sun_position(16.0, 172, 47.4)
    assert 60 < morning[0] < 120
    assert 240 < evening[0] < 300
    assert morning[1] == pytest.approx(evening[1], abs=0.6)
    az, el = sun_position(12.0, 172, -34.0)  # southern hemisphere: the noon sun is in the north
    assert az < 1.0 or az > 359.0
    assert sun_position(4.0, 172, 47.4)[1] < 0.0 < sun_position(4.5, 172, 47.4)[1]  # sunrise ~4:10 solar time
    with pytest.raises(ValueError, match=r"time_of_day_h must be in \[0, 24\)"):
        sun_position(24.5, 172, 47.4)


def test_light_follows_the_sun_and_the_weather() -> None:
    assert lighting_for(EnvironmentConfig(), 47.4) == Lighting.clean()
    noon = lighting_for(EnvironmentConfig(time_of_day_h=12.0), 47.4)
    low = lighting_for(EnvironmentConfig(time_of_day_h=5.0), 47.4)
    dusk = lighting_for(EnvironmentConfig(time_of_day_h=20.2), 47.4)
    assert low.sun_rgb[0] / low.sun_rgb[2] > 1.5 > noon.sun_rgb[0] / noon.sun_rgb[2]  # a low sun is red
    assert sum(low.sun_rgb) < sum(noon.sun_rgb)
    assert sum(dusk.sun_rgb) == 0.0
    assert sum(dusk.sky_rgb) < sum(low.sky_rgb) < sum(noon.sky_rgb)  # the sky darkens towards night
    assert sum(dusk.zenith_rgb) < sum(noon.zenith_rgb)
    assert sum(low.glow_rgb) > 0.0 == sum(noon.glow_rgb)
    grey = lighting_for(EnvironmentConfig(time_of_day_h=12.0, overcast=1.0), 47.4)
    assert sum(grey.sun_rgb) < 0.15 * sum(noon.sun_rgb)
    assert not grey.shadows
    foggy = lighting_for(EnvironmentConfig(time_of_day_h=12.0, visibility_m=500.0), 47.4)
    assert foggy.haze_per_m == pytest.approx(3.912 / 500.0)
    assert foggy.haze_max == 1.0
    with pytest.raises(ValueError, match="night is not simulated"):
        lighting_for(EnvironmentConfig(time_of_day_h=0.5), 47.4)


def test_environment_presets_and_bad_input() -> None:
    presets = environment_presets()
    assert {"clean", "clear_noon", "low_sun", "haze", "dusk_noise", "motion_blur"} <= set(presets)
    for name in presets:
        env = _env(name)
        assert env.preset == name
        lighting_for(env, 47.4)  # the sun is up (or in twilight) in every preset
    clean = _env("clean")
    assert clean == EnvironmentConfig()
    assert not clean.has_camera_effects
    assert clean.depth_noise is None
    merged = _env("dusk_noise", cameras={"forward": {"jpeg_quality": 50}})
    assert merged.effects_for("forward").jpeg_quality == 50
    assert merged.effects_for("forward").noise == merged.effects_for("nadir").noise  # the rest from default
    with pytest.raises(ConfigError, match=r"unknown environment preset 'sunny'.*presets: .*clean"):
        resolve_environment({"preset": "sunny"})
    with pytest.raises(ConfigError, match=r"'environment' has unknown key\(s\) 'fog'"):
        from_mapping(EnvironmentConfig, resolve_environment({"fog": 0.3}), source="x.yaml", prefix="environment")
    with pytest.raises(ConfigError, match=r"x\.yaml: 'environment': time_of_day_h must be in \[0, 24\)"):
        from_mapping(
            EnvironmentConfig, resolve_environment({"time_of_day_h": 25}), source="x.yaml", prefix="environment"
        )
    with pytest.raises(ConfigError, match=r"environment\.cameras\.default\.jpeg_quality"):
        from_mapping(
            EnvironmentConfig,
            resolve_environment({"cameras": {"default": {"jpeg_quality": "high"}}}),
            source="x.yaml",
            prefix="environment",
        )
    with pytest.raises(ConfigError, match=r"environment\.cameras names unknown camera\(s\) \['thermal'\]"):
        from_mapping(SimBridgeConfig, {"environment": {"cameras": {"thermal": {}}}}, source="sim_bridge.yaml")


# ------------------------------------------------------------------------------------------------ shadows
def _terrain_brightness(frame, cam: CameraModel, pose: RigidTransform, world: World, xy: np.ndarray) -> float:
    """Mean grey level of the terrain pixels at map points ``xy`` (N, 2)."""
    pts = np.column_stack([xy, world.height_at(xy[:, 0], xy[:, 1])])
    uv, _ = cam.project(pose.inverse().apply(pts))
    u = np.round(uv[:, 0]).astype(int)
    v = np.round(uv[:, 1]).astype(int)
    ok = (u >= 0) & (u < cam.width) & (v >= 0) & (v < cam.height)
    u, v = u[ok], v[ok]
    terrain = frame.instance_id[v, u] == 1
    return float(frame.color_rgb[v[terrain], u[terrain]].mean())


def test_shadows_fall_on_the_side_opposite_the_sun(world: World, renderer: Renderer) -> None:
    # a building (static shadow map) and a standing person (the people/vehicle map), sun low in the east or west
    building = max(world.objects_of_class(ObjectClass.BUILDING), key=lambda b: b.size_m[2])
    bx, by, _ = building.pose.position_m
    reach = 0.5 * math.hypot(*building.size_m[:2])
    cam = _nadir(480, 480)
    try:
        west = np.array([[bx - reach - d, by + o] for d in (2.0, 3.5, 5.0) for o in (-2.0, 0.0, 2.0)])
        east = west * [[-1.0, 1.0]] + [[2.0 * bx, 0.0]]
        for sun_az, dark, bright in ((90.0, west, east), (270.0, east, west)):  # sun in the east: shade in the west
            env = EnvironmentConfig(sun_azimuth_deg=sun_az, sun_elevation_deg=35.0, shadows=True)
            renderer.set_lighting(lighting_for(env, 47.4))
            pose = look_at([bx, by, float(world.height_at(bx, by)) + 70.0], [bx, by, 0.0])
            frame = renderer.render(cam, pose)
            shade = _terrain_brightness(frame, cam, pose, world, dark)
            lit = _terrain_brightness(frame, cam, pose, world, bright)
            assert shade < 0.75 * lit, (sun_az, shade, lit)
            renderer.set_lighting(lighting_for(replace(env, shadows=False), 47.4))
            frame = renderer.render(cam, pose)
            shade = _terrain_brightness(frame, cam, pose, world, dark)
            lit = _terrain_brightness(frame, cam, pose, world, bright)
            assert shade > 0.85 * lit  # without shadows neither side is dark
        assert renderer.static_shadow_renders == 2  # once per sun position, not per frame
    finally:
        renderer.set_lighting(Lighting.clean())


def test_people_cast_shadows_too(flat_people: tuple[World, Renderer]) -> None:
    world, renderer = flat_people
    person = world.objects_of_class(ObjectClass.PERSON)[1]
    renderer.set_object_pose(person.instance_id, ObjectPose((-30.0, 40.0, 0.0), 0.0))
    cam = _nadir(480, 480)
    pose = look_at([-30.0, 40.0, 9.0], [-30.0, 40.0, 0.0])
    try:
        renderer.set_lighting(
            lighting_for(EnvironmentConfig(sun_azimuth_deg=90.0, sun_elevation_deg=30.0, shadows=True), 47.4)
        )
        stamps = renderer.object_shadow_stamps
        frame = renderer.render(cam, pose)
        assert renderer.object_shadow_stamps == stamps + 1  # the person was drawn into the shadow map
        west = np.array([[-30.0 - d, 40.0 + o] for d in (0.8, 1.4, 2.0) for o in (-0.1, 0.0, 0.1)])
        east = west * [[-1, 1]] + [[-60.0, 0.0]]
        assert _terrain_brightness(frame, cam, pose, world, west) < 0.75 * _terrain_brightness(
            frame, cam, pose, world, east
        )
    finally:
        renderer.set_lighting(Lighting.clean())
        renderer.set_object_pose(person.instance_id, person.pose)


def test_moving_shadows_redraw_only_what_moved_and_match_a_fresh_map(world: World) -> None:
    # people and vehicles moved a few times (each move redraws only them and their neighbours in the shadow map):
    # the map is then exactly the one a renderer that only ever saw them at their last poses draws
    movers = [*world.objects_of_class(ObjectClass.PERSON)[:3], *world.objects_of_class(ObjectClass.VEHICLE)[:2]]
    env = EnvironmentConfig(sun_azimuth_deg=120.0, sun_elevation_deg=25.0, shadows=True)
    cam, view = _nadir(160, 120), look_at([0.0, 0.0, 200.0], [0.0, 1.0, 0.0])

    def shadow_map(shifts: list[float]) -> np.ndarray:
        r = Renderer(world, SimBridgeConfig().render)
        try:
            r.set_lighting(lighting_for(env, 47.4))
            for d in shifts:
                for obj in movers:
                    x, y, z = obj.pose.position_m
                    r.set_object_pose(obj.instance_id, ObjectPose((x + d, y + 0.5 * d, z), 0.3 * d))
                r.render(cam, view)
            with r.ctx:
                return np.frombuffer(r._shadow_static[0].read(), dtype=np.float32).copy()
        finally:
            r.close()

    moved, fresh = shadow_map([0.0, 1.5, 4.0, 0.8]), shadow_map([0.8])
    assert not np.array_equal(moved, shadow_map([0.0]))  # they cast shadows where they stand
    np.testing.assert_array_equal(moved, fresh)


# ------------------------------------------------------------------------------------------------ camera effects
@pytest.fixture(scope="module")
def rendered(world: World, renderer: Renderer):
    renderer.set_lighting(Lighting.clean())
    cam = CameraModel.simple(320, 240, 90.0, name="nadir")
    vx, vy = world.roads.villages_m[0]
    pose = look_at([vx, vy, float(world.height_at(vx, vy)) + 40.0], [vx + 30.0, vy, 0.0])
    return cam, renderer.render(cam, pose)


def _apply(cam: CameraModel, frame, cfg: CameraEffectsConfig, seed: int = 0, motion: CameraMotion | None = None):
    fx = CameraEffects(cfg, cam.width, cam.height, cam.fx, cam.fy, cam.cx, cam.cy, camera_rng(seed, cam.name))
    return fx.apply(frame.color_rgb, frame.depth_m, 0.0, motion)


def _sharpness(img: np.ndarray) -> float:
    return float(cv2.Laplacian(cv2.cvtColor(img, cv2.COLOR_RGB2GRAY), cv2.CV_64F).var())


def test_each_camera_effect_changes_the_image_measurably(rendered) -> None:
    cam, frame = rendered
    base = frame.color_rgb.astype(np.float64)

    def diff(cfg: CameraEffectsConfig, **kw: object) -> np.ndarray:
        out = _apply(cam, frame, cfg, **kw).color_rgb  # type: ignore[arg-type]
        assert out.shape == frame.color_rgb.shape
        assert out.dtype == np.uint8
        return out.astype(np.float64) - base

    noise = diff(CameraEffectsConfig(noise=SensorNoiseConfig(full_well_e=2000.0, read_noise_e=5.0)))
    assert 1.0 < noise.std() < 8.0
    assert abs(noise.mean()) < 0.5
    vig = diff(CameraEffectsConfig(vignetting=0.4))
    assert vig[:20, :20].mean() < -25.0
    assert abs(vig[110:130, 150:170].mean()) < 2.0
    dark = RenderedFrame((frame.color_rgb // 3).astype(np.uint8), frame.depth_m, frame.instance_id)
    auto = _apply(cam, dark, CameraEffectsConfig(exposure=ExposureConfig(target=0.42, max_gain=8.0)))
    assert auto.exposure_s > 0.004
    assert auto.color_rgb.mean() > 2.0 * dark.color_rgb.mean()
    assert auto.gain >= 1.0
    jpeg = diff(CameraEffectsConfig(jpeg_quality=30))
    assert np.abs(jpeg).mean() > 1.0
    blur = _apply(
        cam,
        frame,
        CameraEffectsConfig(
            exposure=ExposureConfig(auto=False, exposure_s=0.02, reference_exposure_s=0.02), motion_blur=True
        ),
        motion=CameraMotion((20.0, 0.0, 0.0), (0.0, 1.0, 0.0)),  # 20 m/s sideways, panning at 1 rad/s
    )
    assert blur.blur_px > 2.0
    assert _sharpness(blur.color_rgb) < 0.7 * _sharpness(frame.color_rgb)
    still = _apply(
        cam,
        frame,
        CameraEffectsConfig(
            exposure=ExposureConfig(auto=False, exposure_s=0.02, reference_exposure_s=0.02), motion_blur=True
        ),
        motion=CameraMotion(),
    )
    assert np.array_equal(still.color_rgb, frame.color_rgb)  # a camera at rest does not blur
    near_focus = _apply(cam, frame, CameraEffectsConfig(defocus=DefocusConfig(focus_distance_m=2.0, aperture_mm=40.0)))
    assert _sharpness(near_focus.color_rgb) < 0.7 * _sharpness(frame.color_rgb)
    in_focus = _apply(cam, frame, CameraEffectsConfig(defocus=DefocusConfig(focus_distance_m=40.0, aperture_mm=2.0)))
    assert np.array_equal(in_focus.color_rgb, frame.color_rgb)
    # seeded: the same seed gives the same image, another seed another one
    cfg = CameraEffectsConfig(noise=SensorNoiseConfig())
    assert np.array_equal(_apply(cam, frame, cfg, seed=3).color_rgb, _apply(cam, frame, cfg, seed=3).color_rgb)
    assert not np.array_equal(_apply(cam, frame, cfg, seed=3).color_rgb, _apply(cam, frame, cfg, seed=4).color_rgb)
    drops = CameraEffects(CameraEffectsConfig(drop_probability=0.2), 32, 24, 16.0, 16.0, 15.5, 11.5, camera_rng(1, "x"))
    assert 20 < sum(drops.drop() for _ in range(200)) < 60


def test_clean_preset_applies_nothing(world: World, renderer: Renderer) -> None:
    cfg = replace(SimBridgeConfig(), environment=_env("clean"))
    eng = BridgeEngine(cfg, world, renderer)
    assert eng.effects == {}
    state = _state(0.0, (40.0, -60.0, float(world.height_at(40.0, -60.0)) + 35.0), yaw=0.4)
    out = eng.step(state, home=None, wanted=lambda _n: True, want_detections=False)
    for c in out.cameras:
        bypassed = renderer.render(c.camera, c.t_map_optical)  # the effects stage skipped entirely
        assert np.array_equal(c.frame.color_rgb, bypassed.color_rgb)
        assert np.array_equal(c.depth_m, bypassed.depth_m, equal_nan=True)
        assert np.array_equal(c.frame.instance_id, bypassed.instance_id)


def test_latency_and_dropped_frames_in_the_engine(world: World, renderer: Renderer) -> None:
    env = _env("clean", cameras={"nadir": {"latency_s": 0.2, "drop_probability": 0.3, "noise": {}}})
    cams = {"nadir": replace(SimBridgeConfig().cameras["nadir"], rate_hz=10.0, width=160, height=120)}
    cfg = replace(
        SimBridgeConfig(),
        cameras=cams,
        environment=env,
        detections=replace(SimBridgeConfig().detections, cameras=("nadir",)),
    )
    eng = BridgeEngine(cfg, world, renderer)
    images: list[tuple[float, float]] = []
    dets = 0
    infos: list[float] = []  # the stamps the node publishes a camera_info with (delivered and not sent yet)
    for k in range(40):
        t = round(0.1 * k, 6)
        out = eng.step(_state(t, (0.0, 0.0, 300.0)), home=None, wanted=lambda _n: True)
        for c in out.cameras:
            if c.delivered and not c.info_sent:
                infos.append(round(c.t_capture_s, 6))
            if c.frame is not None:
                images.append((t, c.t_capture_s))
                assert c.detections is None  # the detections went out on time, with their own frame
            if c.detections is not None:
                dets += 1
                assert c.t_capture_s == pytest.approx(t)
    assert dets == 40  # ground truth is never late nor lost
    assert len(infos) == len(set(infos)) == 40, "one camera_info per captured frame, not one more with its images"
    assert all(t_out == pytest.approx(t_cap + 0.2) for t_out, t_cap in images)
    assert 15 < len(images) < 36  # ~30 % dropped (seeded); the last 0.2 s still in flight


def test_a_delayed_camera_delivers_the_same_effected_image_later(world: World, renderer: Renderer) -> None:
    # a delayed camera's effects finish in the effects thread while the next steps run (they are waited for at
    # delivery): the image is the one an undelayed camera delivers at capture time, bit for bit
    def frames(latency_s: float) -> dict[float, np.ndarray]:
        env = _env("clean", cameras={"nadir": {"latency_s": latency_s, "noise": {}, "jpeg_quality": 70}})
        cams = {"nadir": replace(SimBridgeConfig().cameras["nadir"], rate_hz=10.0, width=160, height=120)}
        dets = replace(SimBridgeConfig().detections, cameras=("nadir",))
        eng = BridgeEngine(replace(SimBridgeConfig(), cameras=cams, environment=env, detections=dets), world, renderer)
        got = {}
        try:
            for k in range(12):
                t = round(0.1 * k, 6)
                for c in eng.step(_state(t, (3.0 * k, 0.0, 120.0)), home=None, wanted=lambda _n: True).cameras:
                    if c.frame is not None:
                        got[round(c.t_capture_s, 6)] = c.frame.color_rgb.copy()
        finally:
            eng.close()
        return got

    now, later = frames(0.0), frames(0.25)
    assert len(later) == 12 - 3  # the last 0.25 s are still in flight
    for t_capture, img in later.items():
        assert np.array_equal(img, now[t_capture])
    assert not np.array_equal(later[0.0], later[0.5])  # and they are images of different places

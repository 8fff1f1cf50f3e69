"""A flight as a sequence: a recorded run's bag (written here with rosbags) becomes a tracking sequence.

The run is a search and rescue over the small world: the person of interest stands where the scenario
put it (``search.person.position_m``, stood on the ground by the bridge's rule) and the drone flies
towards it. The sequence's frames fall on the camera's rate grid, the poses are the odometry's, the
person keeps one track id in every frame, MOTChallenge files read back to the labels, and every check
passes.
"""

from __future__ import annotations

import math
from pathlib import Path

import numpy as np
import pytest
import yaml
from ds_data import SMALL_WORLD, small_dataset
from helpers.bags import BagKit
from helpers.paths import CONFIG

from uav_common.config import deep_merge
from uav_common.robot import load_robot_description
from uav_datasets.core.config import load_dataset_config
from uav_datasets.core.formats import parse_mot
from uav_datasets.errors import DatasetConfigError, FlightError
from uav_datasets.shell.check import check_dataset
from uav_datasets.shell.folder import read_records
from uav_datasets.shell.generate import generate
from uav_datasets.shell.worlds import load_world
from uav_sim_bridge.core.camera import CameraConfig, CameraModel, MountConfig
from uav_sim_bridge.core.transforms import RigidTransform
from uav_sim_bridge.core.world_config import load_world_config

pytestmark = pytest.mark.slow
T0 = 100.0  # sim time of the first state (a SITL does not start at 0)
RATE = 50.0  # states per second
DURATION_S = 6.0
SPEED = 8.0
AGL = 20.0
# 320 x 240: the articulated person (0.3 m across the shoulders) is under a pixel wide at 160 x 120 from 40 m,
# and its few pixels come and go from frame to frame
FORWARD = {
    "width": 320,
    "height": 240,
    "hfov_deg": 90.0,
    "rate_hz": 10.0,
}


def _clear_spot(world_yaml: Path, cache: Path) -> tuple[float, float]:
    world = load_world(load_world_config(world_yaml), cache)
    for r in range(40, 160, 10):
        for a in np.linspace(0, 2 * math.pi, 24, endpoint=False):
            x, y = r * math.cos(a), r * math.sin(a)
            ring = [
                (x + d * math.cos(b), y + d * math.sin(b))
                for d in (0.0, 3.0, 8.0)
                for b in np.linspace(0, 2 * math.pi, 8)
            ]
            ring += [(x - d, y) for d in range(0, 70, 5)]  # the line of sight from the west
            if all(world.surface_height_at(px, py)[0] - float(world.height_at(px, py)) < 0.3 for px, py in ring):
                return x, y
    raise AssertionError("no clear spot in the test world")


@pytest.fixture(scope="module")
def run(tmp_path_factory: pytest.TempPathFactory) -> tuple[Path, Path, tuple[float, float], Path]:
    tmp = tmp_path_factory.mktemp("flight")
    cache = tmp / "cache"
    world_yaml = tmp / "ds_world.yaml"
    world_yaml.write_text(SMALL_WORLD)
    px, py = _clear_spot(world_yaml, cache)
    scenario = {
        "name": "synthetic_sar",
        "mission": "search_and_rescue",
        "world": {"config": str(world_yaml)},
        "search": {"person": {"name": "person_0003", "position_m": [px, py]}},
        "node_params": {
            "sim_bridge": {
                "cameras": {
                    "forward": FORWARD,
                    "nadir": {**FORWARD, "rate_hz": 5.0},
                }
            }
        },
    }
    world = load_world(load_world_config(world_yaml), cache)
    bag = tmp / "run" / "run.bag"
    bag.parent.mkdir()
    kit = BagKit(bag)
    kit.write("/scenario/config", T0, kit.string("# Effective scenario\n" + yaml.safe_dump(scenario)))
    n = round(DURATION_S * RATE)
    for k in range(n):
        t = T0 + k / RATE
        x = px - 60.0 + SPEED * (t - T0)
        z = float(world.height_at(x, py)) + AGL
        kit.write("/uav/ground_truth/odom", t, kit.odom(t, x, py, z))  # heading east, level
    kit.close()
    return bag.parent, cache, (px, py), tmp


def test_a_recorded_flight_becomes_a_consistent_sequence(run: tuple[Path, Path, tuple[float, float], Path]) -> None:
    run_dir, cache, (px, py), tmp = run
    cfg = load_dataset_config(
        small_dataset(
            tmp, source="flight", flight={"run": str(run_dir), "camera": "forward", "split": "test"}, frames=None
        )
    )
    out = tmp / "sequence"
    result = generate(cfg, out, cache_dir=cache)
    frames = read_records(out)
    assert result.frames == len(frames) == 60  # 6 s of a 10 Hz camera
    stamps = [rec.timestamp_s for rec in frames]
    np.testing.assert_allclose(stamps, [T0 + k / 10.0 for k in range(60)], atol=1e-9)
    assert [rec.sequence_frame for rec in frames] == list(range(1, 61))
    assert {rec.sequence for rec in frames} == {"run-forward"}
    # the camera sits where the robot description puts it, as the bridge of the run had it
    mount = load_robot_description(CONFIG / "robot.yaml").mount("forward")
    cam = CameraModel.from_config(
        "forward",
        CameraConfig(**FORWARD, mount=MountConfig(mount.xyz_m, mount.rpy_deg)),  # type: ignore[arg-type]
    )
    world = load_world(load_world_config(tmp / "ds_world.yaml"), cache)
    for rec in frames[::7]:
        x = px - 60.0 + SPEED * (rec.timestamp_s - T0)
        base = RigidTransform.from_rpy([x, py, float(world.height_at(x, py)) + AGL])
        np.testing.assert_allclose(np.array(rec.t_map_camera), cam.optical_pose(base).matrix(), atol=1e-6)
    # the person of interest: where the scenario put it, one track id throughout
    person = next(o for o in world.objects if o.name == "person_0003")
    seen = [(rec.sequence_frame, lab) for rec in frames for lab in rec.labels if lab.object_name == "person_0003"]
    assert len(seen) >= 15, f"the person was labelled in only {len(seen)} frames"
    assert {lab.track_id for _, lab in seen} == {person.instance_id}
    ground = world.ground_height_at(px, py)[0]
    for _, lab in seen:
        assert lab.box3d_position_m == pytest.approx((px, py, ground), abs=1e-3)
    # it grows as the drone closes in
    first, last = seen[0][1], seen[-1][1]
    assert last.area > first.area
    # MOTChallenge: the same boxes and ids, frame by frame
    rows = parse_mot((out / "mot" / "run-forward" / "gt" / "gt.txt").read_text())
    track = [(f, box) for f, t, box, _c, _v in rows if t == person.instance_id]
    assert [(f, tuple(float(v) for v in lab.bbox)) for f, lab in seen] == track
    ini = (out / "mot" / "run-forward" / "seqinfo.ini").read_text()
    assert "seqLength=60" in ini
    assert "frameRate=10" in ini
    assert (out / "mot" / "run-forward" / "img1" / "000001.png").resolve() == (out / frames[0].files["image"]).resolve()
    assert (out / "mot" / "seqmaps" / "uav-test.txt").read_text().split() == ["name", "run-forward"]
    report = check_dataset(out)
    assert report.ok, report.text()
    assert any(name.startswith("MOT round trip") for name, _, _ in report.results)
    # a window of the flight and a frame cap
    window = deep_merge(cfg.to_mapping(), {"flight": {"start_s": 1.0, "end_s": 2.0}})
    from uav_datasets.core.config import dataset_config_from_mapping  # noqa: PLC0415

    short = dataset_config_from_mapping(window, source="test")
    res = generate(short, tmp / "window", cache_dir=cache)
    assert res.frames == 11
    assert read_records(tmp / "window")[0].timestamp_s == pytest.approx(T0 + 1.0)


def test_bad_flights_say_what_is_wrong(run: tuple[Path, Path, tuple[float, float], Path]) -> None:
    run_dir, cache, _, tmp = run
    nowhere = load_dataset_config(
        small_dataset(tmp, source="flight", flight={"run": str(tmp / "no_run"), "camera": "forward"})
    )
    with pytest.raises(FlightError, match="no such run folder or bag"):
        generate(nowhere, tmp / "x1", cache_dir=cache)
    wrong_cam = load_dataset_config(
        small_dataset(tmp, source="flight", flight={"run": str(run_dir), "camera": "thermal"})
    )
    with pytest.raises(DatasetConfigError, match="'thermal' is not a camera of the run; its cameras: forward, nadir"):
        generate(wrong_cam, tmp / "x2", cache_dir=cache)
    empty = tmp / "empty" / "run.bag"
    empty.parent.mkdir()
    kit = BagKit(empty)
    kit.write("/scenario/config", T0, kit.string("name: x\nmission: loiter\n"))
    kit.close()
    no_odom = load_dataset_config(
        small_dataset(tmp, source="flight", flight={"run": str(empty.parent), "camera": "forward"})
    )
    with pytest.raises(FlightError, match="no /uav/ground_truth/odom"):
        generate(no_odom, tmp / "x3", cache_dir=cache)
    cut = tmp / "cut" / "run.bag"
    cut.parent.mkdir()
    data = (run_dir / "run.bag").read_bytes()
    cut.write_bytes(data[: len(data) // 2])
    truncated = load_dataset_config(small_dataset(tmp, source="flight", flight={"run": str(cut), "camera": "forward"}))
    with pytest.raises(FlightError, match="reindex"):
        generate(truncated, tmp / "x4", cache_dir=cache)


def test_walkers_and_drivers_are_where_the_bridge_had_them_at_each_frame(tmp_path: Path) -> None:
    """A world with movers: every frame places them at its own simulation time, as the bridge's engine does
    (``MotionPlan.states_at``), so the labels follow the people and vehicles the run saw move."""
    from uav_datasets.shell.flight import load_flight  # noqa: PLC0415
    from uav_sim_bridge.core.motion import ActorsConfig, plan_motion  # noqa: PLC0415

    world_yaml = tmp_path / "movers.yaml"
    world_yaml.write_text(SMALL_WORLD.replace("people: {count: 16}", "people: {count: 16, moving: 4}")
                          .replace("vehicles: {count: 8}", "vehicles: {count: 8, moving: 3}"))  # fmt: skip
    cache = tmp_path / "cache"
    world = load_world(load_world_config(world_yaml), cache)
    scenario = {
        "name": "movers",
        "mission": "loiter",
        "world": {"config": str(world_yaml)},
        "node_params": {"sim_bridge": {"cameras": {"forward": FORWARD, "nadir": {**FORWARD, "rate_hz": 5.0}}}},
    }
    bag = tmp_path / "run" / "run.bag"
    bag.parent.mkdir()
    kit = BagKit(bag)
    kit.write("/scenario/config", T0, kit.string("# Effective scenario\n" + yaml.safe_dump(scenario)))
    for k in range(round(3.0 * RATE)):
        t = T0 + k / RATE
        kit.write("/uav/ground_truth/odom", t, kit.odom(t, 0.0, 0.0, float(world.height_at(0.0, 0.0)) + AGL))
    kit.close()
    cfg = load_dataset_config(
        small_dataset(tmp_path, source="flight", flight={"run": str(bag.parent), "camera": "forward"})
    )
    flight, _ = load_flight(cfg, bag.parent, lambda wc: load_world(wc, cache))
    motion = plan_motion(world.objects, world.roads, world.terrain.bounds_m, world.config, ActorsConfig())
    assert len(motion.movers) == 7
    assert len(flight.frames) == 24  # the config's frame limit: 2.3 s of a 10 Hz camera
    for plan in (flight.frames[0], flight.frames[-1]):
        poses = dict(plan.object_poses)
        for st in motion.states_at(plan.timestamp_s, world.terrain):
            assert poses[st.instance_id] == st.pose
    first, last = dict(flight.frames[0].object_poses), dict(flight.frames[-1].object_poses)
    moved_m = [
        math.dist(first[m.obj.instance_id].position_m, last[m.obj.instance_id].position_m) for m in motion.movers
    ]
    assert min(moved_m) > 1.0, moved_m  # 2.3 s at walking (>= 1 m/s) and road speeds

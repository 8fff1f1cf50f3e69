"""Camera faults injected in flight: the pure model (each type, determinism by seed, bad input) and the engine
applying it to rendered frames (GL, no ROS)."""

from __future__ import annotations

import math
from dataclasses import replace

import numpy as np
import pytest

from uav_common.config import ConfigError, from_mapping
from uav_sim_bridge.config import SimBridgeConfig
from uav_sim_bridge.core.camera_faults import (
    CAMERA_FAULT_TYPES,
    CameraFaults,
    CameraFaultsConfig,
    Verdict,
    garbage_color,
    garbage_depth,
)
from uav_sim_bridge.core.transforms import RigidTransform
from uav_sim_bridge.core.vehicle_state import VehicleState
from uav_sim_bridge.core.world import World
from uav_sim_bridge.core.world_config import ObjectClass
from uav_sim_bridge.engine import BridgeEngine
from uav_sim_bridge.errors import CameraFaultError, SimBridgeError
from uav_sim_bridge.render import Renderer


def _model(seed: int = 3, p: float = 0.5) -> CameraFaults[int]:
    rngs = {n: np.random.default_rng([seed, i]) for i, n in enumerate(("nadir", "forward"))}
    return CameraFaults(rngs, intermittent_drop_probability=p)


def _run(model: CameraFaults[int], camera: str, frames: range) -> list[tuple[Verdict, int | None]]:
    out = []
    for k in frames:
        r = model.apply(camera, k)
        out.append((r.verdict, r.frame))
    return out


# ------------------------------------------------------------------------------------------------ the pure model
def test_ok_delivers_every_frame_and_off_none_until_cleared() -> None:
    m = _model()
    assert m.fault("nadir") == "ok"
    assert _run(m, "nadir", range(3)) == [(Verdict.DELIVERED, k) for k in range(3)]
    m.set("nadir", "off")
    assert _run(m, "nadir", range(3, 6)) == [(Verdict.OFF, None)] * 3
    assert _run(m, "forward", range(2)) == [(Verdict.DELIVERED, 0), (Verdict.DELIVERED, 1)]  # the other camera
    m.set("nadir", "ok")
    assert _run(m, "nadir", range(6, 8)) == [(Verdict.DELIVERED, 6), (Verdict.DELIVERED, 7)]


def test_stuck_repeats_the_last_good_frame_and_clears() -> None:
    m = _model()
    _run(m, "nadir", range(5))
    m.set("nadir", "stuck")
    assert _run(m, "nadir", range(5, 9)) == [(Verdict.STUCK, 4)] * 4  # the last frame before the fault
    m.set("nadir", "stuck")  # again: still the same frame
    assert m.apply("nadir", 9).frame == 4
    m.set("nadir", "ok")
    assert m.apply("nadir", 10).frame == 10
    # a frame with detections only is never the one kept...
    m.apply("nadir", 11, complete=False)
    m.set("nadir", "stuck")
    assert m.apply("nadir", 12).frame == 10
    # ... and with no image ever delivered, the first complete frame under the fault is
    fresh = _model()
    fresh.set("forward", "stuck")
    assert fresh.apply("forward", 0, complete=False) == fresh.apply("forward", 1, complete=False)
    assert fresh.apply("forward", 0, complete=False).frame is None
    assert [fresh.apply("forward", k).frame for k in (2, 3, 4)] == [2, 2, 2]


def test_garbage_hands_the_frame_back_for_its_pixels_to_be_replaced() -> None:
    m = _model()
    m.apply("nadir", 1)
    m.set("nadir", "garbage")
    assert m.apply("nadir", 2).verdict is Verdict.GARBAGE
    m.set("nadir", "stuck")  # garbage frames are not good frames
    assert m.apply("nadir", 3).frame == 1

    rng = np.random.default_rng(1)
    color = garbage_color(rng, 12, 16)
    assert color.shape == (12, 16, 3)
    assert color.dtype == np.uint8
    assert len(np.unique(color)) > 150  # noise over the whole range, not a constant image
    depth = garbage_depth(rng, 12, 16, 0.5, 300.0)
    assert depth.shape == (12, 16)
    assert depth.dtype == np.float32
    assert np.all(np.isfinite(depth))
    assert depth.min() >= 0.5
    assert depth.max() < 300.0
    assert depth.std() > 50.0
    np.testing.assert_array_equal(
        garbage_color(np.random.default_rng(9), 4, 4), garbage_color(np.random.default_rng(9), 4, 4)
    )


def test_intermittent_drops_at_its_rate_deterministically_by_seed() -> None:
    def drops(seed: int, p: float = 0.5) -> list[bool]:
        m = _model(seed, p)
        m.set("forward", "intermittent")
        return [m.apply("forward", k).verdict is Verdict.DROPPED for k in range(2000)]

    a = drops(7)
    assert a == drops(7)  # the same seed, the same frames lost
    assert a != drops(8)
    assert 0.45 < np.mean(a) < 0.55
    assert 0.15 < np.mean(drops(7, 0.2)) < 0.25
    # what is not dropped is delivered as captured, and remembered as the last good frame
    m = _model(7)
    m.set("forward", "intermittent")
    delivered = [r.frame for k in range(50) if (r := m.apply("forward", k)).verdict is Verdict.DELIVERED]
    assert delivered
    assert delivered == sorted(delivered)
    m.set("forward", "stuck")
    assert m.apply("forward", 99).frame == delivered[-1]
    # one camera's draws do not shift another's
    m1, m2 = _model(7), _model(7)
    m1.set("forward", "intermittent")
    m2.set("forward", "intermittent")
    m2.set("nadir", "intermittent")
    for k in range(20):
        m2.apply("nadir", k)
    assert [m1.apply("forward", k).verdict for k in range(50)] == [m2.apply("forward", k).verdict for k in range(50)]


def test_bad_input_is_a_clear_error() -> None:
    m = _model()
    with pytest.raises(CameraFaultError, match=r"unknown camera 'down'; this bridge runs forward, nadir"):
        m.set("down", "off")
    with pytest.raises(CameraFaultError, match=r"unknown camera fault type 'wrong'; known: ok, off, stuck"):
        m.set("nadir", "wrong")
    with pytest.raises(CameraFaultError, match="unknown camera"):
        m.apply("down", 1)
    assert m.fault("nadir") == "ok"  # a refused fault changes nothing
    with pytest.raises(CameraFaultError, match="at least one camera"):
        CameraFaults({})
    with pytest.raises(CameraFaultError, match=r"in \(0, 1\)"):
        CameraFaults({"nadir": np.random.default_rng(0)}, intermittent_drop_probability=1.0)
    with pytest.raises(CameraFaultError, match="positive size"):
        garbage_color(np.random.default_rng(0), 0, 4)
    with pytest.raises(CameraFaultError, match="near_m < far_m"):
        garbage_depth(np.random.default_rng(0), 4, 4, 5.0, math.inf)
    assert issubclass(CameraFaultError, SimBridgeError)
    assert issubclass(CameraFaultError, ValueError)
    assert CAMERA_FAULT_TYPES == ("ok", "off", "stuck", "garbage", "intermittent")
    with pytest.raises(ConfigError, match="intermittent_drop_probability"):
        from_mapping(SimBridgeConfig, {"camera_faults": {"intermittent_drop_probability": 0.0}}, source="t.yaml")
    with pytest.raises(ConfigError, match="camera_faults"):
        from_mapping(SimBridgeConfig, {"camera_faults": {"drop": 0.1}}, source="t.yaml")
    assert CameraFaultsConfig().intermittent_drop_probability == 0.5


# ------------------------------------------------------------------------------------------------ the engine
def _state(t: float, xyz: tuple[float, float, float], yaw: float = 0.0) -> VehicleState:
    return VehicleState(t, RigidTransform.from_rpy(list(xyz), yaw_rad=yaw), np.zeros(3))


@pytest.fixture(scope="module")
def engine(small_world: World, small_renderer: Renderer) -> BridgeEngine:
    return BridgeEngine(SimBridgeConfig(), small_world, small_renderer)


def _view_of_a_person(eng: BridgeEngine, world: World) -> tuple[float, float, float, float]:
    """A pose 30 m from a person, 15 m up, facing it: the forward camera sees it (ground-truth boxes)."""
    for person in world.objects_of_class(ObjectClass.PERSON):
        px, py, pz = person.pose.position_m
        for k in range(8):
            yaw = k * math.pi / 4
            x, y = px - 30.0 * math.cos(yaw), py - 30.0 * math.sin(yaw)
            out = eng.step(_state(0.0, (x, y, pz + 15.0), yaw), home=None, wanted=lambda n: n == "forward")
            fwd = [c for c in out.cameras if c.camera.name == "forward"]
            if fwd and fwd[0].detections:
                return x, y, pz + 15.0, yaw
    pytest.skip("no person in view from any tried pose")


def test_the_engine_applies_each_fault_to_what_the_camera_delivers(engine: BridgeEngine, small_world: World) -> None:
    eng = engine
    x, y, z, yaw = _view_of_a_person(eng, small_world)
    t = [10.0]

    def frame(dx: float = 0.0):  # the next forward frame (10 Hz), the vehicle moving along x
        t[0] += 0.1
        out = eng.step(_state(t[0], (x + dx, y, z), yaw), home=None, wanted=lambda n: n == "forward")
        fwd = [c for c in out.cameras if c.camera.name == "forward"]
        return fwd[0] if fwd else None

    good = frame()
    assert good is not None
    assert good.delivered
    assert good.fault == ""
    assert good.detections
    assert good.detector_boxes is good.detections

    eng.set_camera_fault("forward", "stuck")
    for dx in (2.0, 4.0):
        s = frame(dx)
        assert s.fault == "stuck"
        assert s.delivered
        assert s.t_capture_s == pytest.approx(t[0])  # the new stamp...
        np.testing.assert_array_equal(s.frame.color_rgb, good.frame.color_rgb)  # ... on the old image
        np.testing.assert_array_equal(s.depth_m, good.depth_m)
        assert [d.instance_id for d in s.detector_boxes] == [d.instance_id for d in good.detections]
        assert s.detections is not None  # the scene's truth is still the current view's
    eng.set_camera_fault("forward", "ok")
    live = frame(6.0)
    assert live.fault == ""
    assert not np.array_equal(live.frame.color_rgb, good.frame.color_rgb)

    eng.set_camera_fault("forward", "off")
    off = frame()
    assert off is not None
    assert off.fault == "off"
    assert not off.delivered
    assert off.frame is None
    assert off.depth_m is None
    assert off.detector_boxes is None
    assert off.detections  # ... the truth remains, for the scorer

    eng.set_camera_fault("forward", "garbage")
    g = frame()
    assert g.fault == "garbage"
    assert g.delivered
    assert g.detector_boxes == []
    assert g.frame.color_rgb.shape == good.frame.color_rgb.shape
    assert g.frame.color_rgb.dtype == np.uint8
    assert g.depth_m.shape == good.depth_m.shape
    assert g.depth_m.dtype == np.float32
    assert np.abs(np.diff(g.frame.color_rgb.astype(np.int16), axis=1)).mean() > 60.0  # noise, not a picture
    assert np.abs(np.diff(good.frame.color_rgb.astype(np.int16), axis=1)).mean() < 30.0

    eng.set_camera_fault("forward", "intermittent")
    verdicts = [f.fault for f in (frame() for _ in range(40))]
    assert 8 < verdicts.count("dropped") < 32
    assert verdicts.count("dropped") + verdicts.count("") == 40
    eng.set_camera_fault("forward", "ok")
    with pytest.raises(CameraFaultError, match="unknown camera 'down'"):
        eng.set_camera_fault("down", "off")
    with pytest.raises(CameraFaultError, match="unknown camera fault type 'wrong'"):
        eng.set_camera_fault("nadir", "wrong")


def test_the_faults_generators_follow_the_configured_seed(small_world: World, small_renderer: Renderer) -> None:
    def lost(seed: int) -> list[str]:
        cfg = replace(SimBridgeConfig(), camera_faults=CameraFaultsConfig(seed=seed))
        eng = BridgeEngine(cfg, small_world, small_renderer)
        eng.set_camera_fault("nadir", "intermittent")
        out = []
        for k in range(30):  # nadir at 5 Hz: one frame a step of 0.2 s
            step = eng.step(_state(0.2 * k, (0.0, 0.0, 40.0)), home=None, wanted=lambda n: n == "nadir")
            nadir = [c for c in step.cameras if c.camera.name == "nadir"]
            out.append("kept" if nadir and nadir[0].delivered and nadir[0].frame is not None else "lost")
        eng.close()
        return out

    a = lost(1)
    assert a == lost(1)
    assert a != lost(2)
    assert 5 < a.count("lost") < 25

"""Camera faults in a scenario: the ``faults`` keys for the range's cameras, the actions the mission manager sends
to the sim bridge, and what the scorer makes of the camera's frames after a fault (pure parts)."""

from __future__ import annotations

import math
from pathlib import Path

import numpy as np
import pytest
from helpers.paths import REPO

from uav_common.config import ConfigError
from uav_scenarios.core.config import FaultSpec, ScoringSpec, load_scenario
from uav_scenarios.core.faults import CAMERA, camera_name, fault_actions, not_simulated
from uav_scenarios.core.scoring.cameras import CameraFrameSample, CameraWatch, noise_level
from uav_scenarios.core.scoring.faults import fault_summary
from uav_scenarios.core.scoring.run import RunScorer
from uav_scenarios.core.scoring.types import FaultSample, SceneTruth
from uav_scenarios.report.html import faults_table


def write(tmp_path: Path, body: str) -> Path:
    path = tmp_path / "s.yaml"
    path.write_text(f"name: x\nmission: loiter\nworld: {{config: {REPO / 'config/worlds/default.yaml'}}}\n{body}")
    return path


# ---- the scenario's keys --------------------------------------------------------------------------------------
def test_camera_faults_load_and_bad_ones_name_the_key(tmp_path: Path) -> None:
    body = (
        "faults:\n"
        "  - {at_s: 200, unit: camera_nadir, type: stuck, duration_s: 30}\n"
        "  - {at_s: 10, unit: camera_forward, type: intermittent}\n"
        "  - {at_s: 20, unit: camera_forward, type: garbage}\n"
        "  - {at_s: 30, unit: camera_nadir, type: off}\n"  # YAML's bare off (false): off
    )
    s = load_scenario(write(tmp_path, body))
    assert [(f.unit, f.type) for f in s.faults] == [
        ("camera_nadir", "stuck"),
        ("camera_forward", "intermittent"),
        ("camera_forward", "garbage"),
        ("camera_nadir", "off"),
    ]
    # camera faults are the bridge's: any autopilot personality takes them
    s = load_scenario(write(tmp_path, "autopilot: ardupilot\nfaults: [{at_s: 5, unit: camera_nadir, type: off}]\n"))
    assert s.faults[0].unit == "camera_nadir"
    with pytest.raises(ConfigError, match=r"faults.*camera_nadir wrong is not simulated; a camera takes"):
        load_scenario(write(tmp_path, "faults: [{at_s: 5, unit: camera_nadir, type: wrong}]\n"))
    with pytest.raises(ConfigError, match=r"faults.*instance: camera_forward is one camera: its instance must be 0"):
        load_scenario(write(tmp_path, "faults: [{at_s: 5, unit: camera_forward, type: off, instance: 1}]\n"))
    with pytest.raises(ConfigError, match=r"faults.*unit: unknown fault unit 'camera_down'"):
        load_scenario(write(tmp_path, "faults: [{at_s: 5, unit: camera_down, type: off}]\n"))
    with pytest.raises(ConfigError, match=r"faults.*duration_s"):
        load_scenario(write(tmp_path, "faults: [{at_s: 5, unit: camera_nadir, type: off, duration_s: -1}]\n"))
    assert not_simulated("camera_nadir", "ok") == ""
    assert "not a MAVLink FAILURE_UNIT nor a camera of the range" in not_simulated("lidar", "off")
    assert set(CAMERA) == {"camera_nadir", "camera_forward"}


def test_the_camera_faults_stress_preset_scripts_both_cameras() -> None:
    s = load_scenario(
        REPO / "config/scenarios/loiter.yaml", stress=("camera_faults",), stress_dir=REPO / "config/stress"
    )
    assert [(f.at_s, f.unit, f.type, f.duration_s) for f in s.faults] == [
        (60.0, "camera_nadir", "intermittent", 30.0),
        (120.0, "camera_forward", "stuck", 20.0),
    ]


def test_camera_actions_name_the_bridge_camera_and_clear_with_ok() -> None:
    actions = fault_actions(
        [
            FaultSpec(at_s=200.0, unit="camera_nadir", type="stuck", duration_s=30.0),
            FaultSpec(at_s=120.0, unit="gps", type="off"),
        ]
    )
    assert [(a.at_s, a.label, a.camera) for a in actions] == [
        (120.0, "gps off", ""),
        (200.0, "camera_nadir stuck", "nadir"),
        (230.0, "camera_nadir ok (end of fault 0)", "nadir"),
    ]
    assert camera_name("camera_forward") == "forward"
    assert camera_name("gps") == ""


# ---- what the scorer sees --------------------------------------------------------------------------------------
def frames(watch: CameraWatch, cam: str, times: np.ndarray, digest=lambda t: int(t * 100), noise=10.0) -> list:
    out = []
    for t in times:
        out += watch.add(CameraFrameSample(float(t), cam, digest(t), noise))
    return out


def test_the_watch_sees_frames_stop_resume_freeze_and_turn_to_noise() -> None:
    w = CameraWatch(stale_after_s=1.0)
    assert frames(w, "nadir", np.arange(0.0, 5.0, 0.2)) == []  # a healthy camera: no change
    assert w.open_gaps(5.5) == []
    # off from 5 s: after a second of silence the frames stopped; at 9 s they resume
    stopped = w.open_gaps(6.0)
    assert stopped == [(pytest.approx(5.8), "camera nadir: frames stopped")]
    assert w.open_gaps(7.0) == stopped  # it only looks
    assert frames(w, "nadir", [9.0]) == [
        (pytest.approx(5.8), "camera nadir: frames stopped"),
        (9.0, "camera nadir: frames resumed after a 4.2 s gap"),
    ]
    assert w.open_gaps(9.5) == []
    # stuck: the same picture with new stamps
    changes = frames(w, "nadir", np.arange(9.2, 10.5, 0.2), digest=lambda t: 7)
    assert changes == [(pytest.approx(9.6), "camera nadir: image frozen (the same picture 3 frames in a row)")]
    assert frames(w, "nadir", [10.6]) == [(10.6, "camera nadir: image moving again")]
    # garbage
    assert frames(w, "nadir", [10.8, 11.0], noise=85.0) == [(10.8, "camera nadir: image is noise (85)")]
    assert frames(w, "nadir", [11.2]) == [(11.2, "camera nadir: image is a picture again")]
    assert frames(w, "nadir", [11.0]) == []  # older than the last frame: ignored
    # the counts over a window
    win = w.window("nadir", 9.0, 10.5)  # after 9.0, before 10.5: 9.2 ... 10.4
    assert win["frames"] == 7
    assert win["distinct_images"] == 1
    assert win["rate_hz"] == pytest.approx(7 / 1.5)
    quiet = w.window("nadir", 5.0, 9.0)
    assert quiet["frames"] == 0
    assert quiet["rate_before_hz"] == pytest.approx(19 / 4.0)  # 1.2 ... 4.8 s
    assert w.window("nadir", 10.7, 11.2)["noise_frames"] == 2
    # a fault applied after the state at 4.8 s (a float a hair below the frame's stamp): that frame came before it
    late = w.window("nadir", 4.8 - 1e-12, 6.1)
    assert late["frames"] == 0
    assert late["rate_before_hz"] == pytest.approx(7 / 1.3)  # 3.6 ... 4.8 s
    with pytest.raises(ValueError, match="frozen_after"):
        CameraWatch(frozen_after=1)


def test_noise_level_tells_noise_from_a_picture() -> None:
    rng = np.random.default_rng(0)
    noise = rng.integers(0, 256, (120, 160, 3), dtype=np.uint8)
    assert noise_level(noise) == pytest.approx(85.0, abs=2.0)
    y, x = np.mgrid[0:120, 0:160]
    picture = np.stack([x, y, (x + y) // 2], axis=-1).astype(np.uint8)  # smooth gradients
    assert noise_level(picture) < 5.0
    assert math.isnan(noise_level(np.zeros((0, 4, 3), dtype=np.uint8)))


def test_a_camera_fault_in_the_faults_section_with_what_followed() -> None:
    s = RunScorer(spec=ScoringSpec(), truth=SceneTruth(bounds_m=(-100.0, -100.0, 100.0, 100.0)))
    s.start_t_s = 0.0
    for k in range(50):  # 10 s of nadir frames at 5 Hz, each a new picture
        s.add_camera_frame(CameraFrameSample(0.2 * k, "nadir", k, 12.0))
    s.add_fault(FaultSample(10.0, 0, 10.0, "camera_nadir", "stuck", result="ACCEPTED", answered_s=10.0))
    for k in range(50, 75):  # stuck: the last picture again, new stamps
        s.add_camera_frame(CameraFrameSample(0.2 * k, "nadir", 49, 12.0))
    s.add_fault(FaultSample(15.0, 0, 15.0, "camera_nadir", "ok", clear=True, result="ACCEPTED", answered_s=15.0))
    for k in range(75, 85):
        s.add_camera_frame(CameraFrameSample(0.2 * k, "nadir", k, 12.0))
    s.add_fault(FaultSample(17.0, 1, 17.0, "camera_nadir", "off", result="ACCEPTED"))
    for k in range(11):  # time goes on (the forward camera's frames), the nadir camera silent
        s.add_camera_frame(CameraFrameSample(17.0 + 0.2 * k, "forward", k, 12.0))
    m = s.summary(19.0)
    events = [e["what"] for e in m["events"]]
    assert "fault camera_nadir stuck: ACCEPTED" in events
    stuck, clear, off = m["faults"]
    assert [c["what"] for c in stuck["followed"]] == ["camera nadir: image frozen (the same picture 3 frames in a row)"]
    assert stuck["camera"]["frames"] == 24  # captured after it applied (10 s), before the clear
    assert stuck["camera"]["distinct_images"] == 1
    assert stuck["camera"]["rate_before_hz"] == pytest.approx(5.0)
    assert [c["what"] for c in clear["followed"]] == ["camera nadir: image moving again"]
    assert clear["camera"]["distinct_images"] == 9
    assert [c["what"] for c in off["followed"]] == ["camera nadir: frames stopped"]
    assert off["camera"]["frames"] == 0
    assert off["followed"][0]["after_s"] == pytest.approx(0.8)  # the last frame (16.8 s) + 1 s of silence
    # the report's faults section says it in words
    table = faults_table(m)
    assert table.count("<tr>") == 4  # the header and three commands
    assert "camera_nadir stuck" in table
    assert "+0.2 s camera nadir: image frozen (the same picture 3 frames in a row)" in table
    assert "24 frames (4.8 Hz, before 5 Hz), 1 distinct, 0 noise" in table
    assert "camera_nadir ok (end of the fault)" in table
    assert faults_table({"faults": []}) == ""
    # an autopilot fault carries no camera counts
    (gps,) = fault_summary([FaultSample(1.0, 0, 1.0, "gps", "off")], [], start_s=0.0, end_s=2.0, cameras=CameraWatch())
    assert "camera" not in gps

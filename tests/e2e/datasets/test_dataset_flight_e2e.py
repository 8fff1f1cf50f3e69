"""A sequence from a real run: uav-dataset flies a short search and rescue itself (``flight.scenario``: uav-run,
lockstep, replay recording) and labels its forward camera; then it turns the same recorded run's nadir
camera into a second sequence (``--run``).

The re-rendered frames are the run's frames: the nadir depth equals the depth the bridge published at
the same instants, and the forward sequence's labels, filtered as the bridge's detections are (100 m,
4 pixels), give exactly the instance ids and boxes of the ground-truth detections recorded in the bag,
frame by frame. Every object keeps its track id; the dataset passes every check.
"""

from __future__ import annotations

import json
import math
import shutil
import sys
from pathlib import Path

import numpy as np
import pytest
import yaml
from helpers.procs import REPO, Proc, artifacts_dir

from uav_datasets.shell.check import check_dataset
from uav_datasets.shell.folder import read_records
from uav_datasets.shell.writers import read_depth

pytestmark = pytest.mark.slow
HERE = Path(__file__).resolve().parent


def _dataset_yaml(path: Path, camera: str, flight: dict[str, object], extra: dict[str, object]) -> Path:
    data = {
        "name": f"flight_{camera}",
        "source": "flight",
        "flight": {"camera": camera, "split": "test", **flight},
        "labels": {"classes": ["person", "vehicle"], "min_visible_pixels": 4, **extra},
        "outputs": {"depth": "float32", "mot": True},
    }
    path.write_text(yaml.safe_dump(data))
    return path


def _recorded(bag: Path) -> tuple[dict[int, list[tuple[int, tuple[int, int, int, int]]]], dict[int, np.ndarray]]:
    """Forward-camera detections and nadir depth images of the bag, by header stamp (ns)."""
    import rosbag  # noqa: PLC0415

    from uav_common.ros.arrays import image_to_depth_m  # noqa: PLC0415

    dets: dict[int, list[tuple[int, tuple[int, int, int, int]]]] = {}
    depth: dict[int, np.ndarray] = {}
    with rosbag.Bag(str(bag)) as b:
        for topic, msg, _t in b.read_messages(topics=["/detections/ground_truth", "/cameras/nadir/depth/image_raw"]):
            stamp = msg.header.stamp.to_nsec()
            if topic == "/cameras/nadir/depth/image_raw":
                depth[stamp] = image_to_depth_m(msg)
            elif msg.camera == "forward":
                dets[stamp] = sorted((d.instance_id, (d.x_min, d.y_min, d.x_max, d.y_max)) for d in msg.detections)
    return dets, depth


def _generate(config: Path, out: Path, *extra: str) -> None:
    argv = [sys.executable, str(REPO / "bin" / "uav-dataset"), "generate", str(config), "--out", str(out)]
    argv += [*extra, "--workers", "2", "--cache-dir", str(artifacts_dir() / "world_cache"), "--quiet"]
    proc = Proc(f"dataset_e2e_{out.name}", argv)
    try:
        rc = proc.wait(900)
    finally:
        proc.stop()
    assert rc == 0, proc.tail()


def test_the_sequences_are_the_runs_frames() -> None:
    work = artifacts_dir() / "dataset_e2e"
    shutil.rmtree(work, ignore_errors=True)
    work.mkdir(parents=True)
    # the forward camera along a flight flown now, labels filtered as the bridge's detections are
    fwd = work / "forward"
    flight = {"scenario": str(HERE / "flight_sar.yaml"), "time_limit_s": 60.0}
    _generate(_dataset_yaml(work / "forward.yaml", "forward", flight, {"max_range_m": 100.0}), fwd)
    run_dir = fwd / "source_run"
    assert (run_dir / "run.bag").is_file()
    dets, depth = _recorded(run_dir / "run.bag")
    assert len(dets) > 150, "the bag should hold the forward camera's detections at 10 Hz"
    frames = read_records(fwd)
    assert len(frames) > 150
    compared = with_objects = 0
    for rec in frames:
        stamp = round(rec.timestamp_s * 1e9)
        if stamp not in dets:
            continue
        compared += 1
        ours = sorted(
            (lab.instance_id, (lab.bbox[0], lab.bbox[1], lab.bbox[0] + lab.bbox[2] - 1, lab.bbox[1] + lab.bbox[3] - 1))
            for lab in rec.labels
        )
        assert ours == dets[stamp], f"frame {rec.sequence_frame} at {rec.timestamp_s:.3f} s"
        with_objects += bool(ours)
    assert compared >= 0.95 * len(frames)
    assert with_objects >= 10, "too few frames with people or vehicles to compare"
    # the person of interest stands where the scenario placed it (the bridge's object_poses)
    placed = json.loads((run_dir / "metrics.json").read_text())["person"]
    seen = [lab for rec in frames for lab in rec.labels if lab.object_name == "person_0000"]
    assert seen, "the person of interest was never labelled"
    for lab in seen:
        assert math.dist(lab.box3d_position_m[:2], (placed["x_m"], placed["y_m"])) < 1e-3
    report = check_dataset(fwd)
    assert report.ok, report.text()
    tracks: dict[int, set[str]] = {}
    for rec in frames:
        for lab in rec.labels:
            tracks.setdefault(lab.track_id, set()).add(lab.object_name)
    assert all(len(names) == 1 for names in tracks.values())
    mot = (fwd / "mot").iterdir()
    assert any((p / "gt" / "gt.txt").is_file() for p in mot)
    # nadir camera: the re-rendered depth is the depth the bridge published at the same instants
    nad = work / "nadir"
    _generate(_dataset_yaml(work / "nadir.yaml", "nadir", {"run": "unused"}, {}), nad, "--run", str(run_dir))
    same = 0
    for rec in read_records(nad):
        stamp = round(rec.timestamp_s * 1e9)
        if stamp not in depth:
            continue
        ours = read_depth(nad / rec.files["depth"])
        theirs = depth[stamp]
        np.testing.assert_array_equal(np.isnan(ours), np.isnan(theirs))
        ok = ~np.isnan(ours)
        np.testing.assert_allclose(ours[ok], theirs[ok], rtol=1e-5, atol=1e-4)
        same += 1
    assert same > 150
    assert math.isfinite(float(np.nanmax(ours)))

"""A small dataset (tens of frames) generated for real (GL renders) and checked as a user would.

pycocotools loads the COCO file and scores the ground truth as detections (AP = 1.0, boxes and masks);
tight boxes equal their mask extents; YOLO and KITTI read back to the same boxes; every label agrees
with the instance-id, class-id and depth images; K workers make the same dataset as one; an
interrupted generation (in process, and a process killed with SIGKILL) leaves no annotation file and
resumes to the same dataset; a folder holding another dataset is refused.
"""

from __future__ import annotations

import filecmp
import json
import math
import os
import shutil
import signal
import subprocess
import sys
import time
from pathlib import Path

import cv2
import numpy as np
import pytest
from ds_data import small_dataset
from helpers.paths import REPO

from uav_datasets.cli.dataset import main
from uav_datasets.core.config import DatasetConfig, load_dataset_config
from uav_datasets.core.labels import box_corners
from uav_datasets.core.records import FrameRecord
from uav_datasets.errors import DatasetFolderError, IncompleteDatasetError, SamplingError
from uav_datasets.shell.check import check_dataset, coco_ap
from uav_datasets.shell.folder import read_manifest, read_records
from uav_datasets.shell.generate import GenerateResult, generate
from uav_datasets.shell.worlds import load_world, world_configs
from uav_datasets.shell.writers import read_depth, read_ids

pytestmark = pytest.mark.slow


@pytest.fixture(scope="module")
def workdir(tmp_path_factory: pytest.TempPathFactory) -> Path:
    return tmp_path_factory.mktemp("datasets")


@pytest.fixture(scope="module")
def cfg(workdir: Path) -> DatasetConfig:
    return load_dataset_config(small_dataset(workdir))


@pytest.fixture(scope="module")
def cache(workdir: Path) -> Path:
    return workdir / "world_cache"


@pytest.fixture(scope="module")
def dataset(workdir: Path, cfg: DatasetConfig, cache: Path) -> tuple[Path, GenerateResult]:
    out = workdir / "one_worker"
    return out, generate(cfg, out, workers=1, cache_dir=cache)


@pytest.fixture(scope="module")
def reference72(workdir: Path, cfg: DatasetConfig, cache: Path) -> Path:
    """The same dataset with 72 frames, made in one go: what the runs killed half-way must end up equal to
    (enough frames that a worker is still busy when the test kills it)."""
    out = workdir / "reference72"
    generate(cfg.with_overrides(frames=72), out, cache_dir=cache)
    return out


def _tree(folder: Path) -> dict[str, Path]:
    """Every file of a dataset folder (symlinks not followed), by relative path."""
    return {
        str(p.relative_to(folder)): p
        for p in sorted(folder.rglob("*"))
        if (p.is_file() or p.is_symlink()) and p.name != "preview.png"
    }


def _differ(a: dict[str, Path], b: dict[str, Path]) -> list[str]:
    out = []
    for rel, pa in a.items():
        pb = b[rel]
        if pa.is_symlink() or pb.is_symlink():
            if not (pa.is_symlink() and pb.is_symlink() and os.readlink(pa) == os.readlink(pb)):
                out.append(rel)
        elif not filecmp.cmp(pa, pb, shallow=False):
            out.append(rel)
    return out


def test_the_dataset_passes_every_check(dataset: tuple[Path, GenerateResult]) -> None:
    out, result = dataset
    assert result.frames == 24
    assert result.made == 24
    report = check_dataset(out)
    assert report.ok, report.text()
    names = [name for name, _, _ in report.results]
    for wanted in (
        "pycocotools AP (bbox)",
        "pycocotools AP (segm)",
        "tight boxes equal mask extents",
        "YOLO round trip",
        "KITTI round trip",
    ):
        assert any(n.startswith(wanted) for n in names), names
    ap, n = coco_ap(out / "annotations" / "instances.json", "bbox")
    assert ap == 1.0
    assert n > 30, "too few labelled instances to mean anything"
    for split in ("train", "test"):
        doc = json.loads((out / "annotations" / f"instances_{split}.json").read_text())
        assert {img["split"] for img in doc["images"]} == {split}
    manifest = read_manifest(out)
    assert manifest["complete"] is True
    assert manifest["stats"]["per_class"]["person"]["instances"] > 0
    assert manifest["stats"]["per_class"]["vehicle"]["instances"] > 0
    assert not (out / ".progress").exists()
    assert (out / "kitti" / "train" / "image_2").resolve() == (out / "images" / "train").resolve()


def test_splits_hold_out_worlds(dataset: tuple[Path, GenerateResult]) -> None:
    out, _ = dataset
    frames = read_records(out)
    by_split: dict[str, set[tuple[int, str]]] = {}
    for rec in frames:
        by_split.setdefault(rec.split, set()).add((rec.world_seed, rec.world_hash))
    assert {s for s, _ in by_split["train"]} == {21, 22}
    assert {s for s, _ in by_split["test"]} == {23}
    assert not {h for _, h in by_split["train"]} & {h for _, h in by_split["test"]}
    assert len({h for _, h in by_split["train"]}) == 2  # different seeds, different worlds


def test_every_label_agrees_with_the_images_and_the_geometry(
    dataset: tuple[Path, GenerateResult], cfg: DatasetConfig, cache: Path
) -> None:
    out, _ = dataset
    frames = read_records(out)
    worlds = {seed: load_world(wc, cache) for seed, wc in world_configs(cfg).items()}
    n = 0
    sizes = []
    for rec in frames:
        world = worlds[rec.world_seed]
        t = np.array(rec.t_map_camera)
        eye = t[:3, 3]
        assert 12.0 - 1e-6 <= rec.altitude_agl_m <= 60.0 + 1e-6
        assert rec.altitude_agl_m == pytest.approx(eye[2] - float(world.height_at(eye[0], eye[1])), abs=1e-3)
        assert 25.0 - 1e-6 <= rec.pitch_deg <= 90.0 + 1e-6
        ids = read_ids(out / rec.files["instance_mask"])
        classes = read_ids(out / rec.files["class_mask"])
        depth = read_depth(out / rec.files["depth"])
        image = cv2.imread(str(out / rec.files["image"]))
        assert image.shape == (240, 320, 3)
        np.testing.assert_array_equal(classes, world.instance_class[ids])
        for lab in rec.labels:
            n += 1
            sizes.append(lab.size_px)
            mask = ids == lab.instance_id
            assert int(mask.sum()) == lab.area
            rows, cols = np.nonzero(mask)
            assert lab.bbox == (cols.min(), rows.min(), cols.max() - cols.min() + 1, rows.max() - rows.min() + 1)
            assert (classes[mask] == lab.class_id).all()
            obj = world.object(lab.instance_id)
            assert lab.class_name == obj.object_class.label
            assert lab.box3d_position_m == pytest.approx(obj.pose.position_m, abs=1e-3)
            # the loose box (projected 3D box) contains the visible pixels (half a pixel: centres vs edges)
            lx, ly, lw, lh = lab.bbox_loose
            x, y, w, h = lab.bbox
            assert lx - 0.5 <= x, lab
            assert ly - 0.5 <= y, lab
            assert x + w <= lx + lw + 0.5, lab
            assert y + h <= ly + lh + 0.5, lab
            assert 0.0 < lab.visible_fraction <= 1.0
            assert lab.unoccluded_pixels >= lab.area
            # every visible pixel's depth lies within the object's 3D box range from the camera
            corners = box_corners(obj)
            dist = np.linalg.norm(corners - eye, axis=1)
            z = depth[mask]
            ray = np.linalg.norm(
                np.stack([(cols - rec.cx) / rec.fx, (rows - rec.cy) / rec.fy, np.ones_like(z)]), axis=0
            )
            near = z < 65.5  # the uint16 millimetre PNG saturates at 65.535 m
            r = (z * ray)[near]
            assert (r >= dist.min() - 1.0).all()
            assert (r <= dist.max() + 1.0).all()
            assert lab.range_m == pytest.approx(float(np.linalg.norm(obj.center_m - eye)), abs=1e-3)
    assert n > 30
    assert min(sizes) < 20 < max(sizes)  # small and large objects both present


def test_workers_make_the_same_dataset(
    dataset: tuple[Path, GenerateResult], workdir: Path, cfg: DatasetConfig, cache: Path
) -> None:
    one, _ = dataset
    out = workdir / "two_workers"
    result = generate(cfg, out, workers=2, cache_dir=cache)
    assert result.made == 24
    a, b = _tree(one), _tree(out)
    assert sorted(a) == sorted(b)
    differ = _differ(a, b)
    assert not differ, f"files differ between 1 and 2 workers: {differ[:10]}"


def test_an_interrupted_generation_resumes_to_the_same_dataset(
    dataset: tuple[Path, GenerateResult], workdir: Path, cfg: DatasetConfig, cache: Path
) -> None:
    one, _ = dataset
    out = workdir / "interrupted"

    def stop_after_7(done: int, _total: int) -> None:
        if done >= 7:
            raise KeyboardInterrupt

    with pytest.raises(KeyboardInterrupt):
        generate(cfg, out, workers=1, cache_dir=cache, progress=stop_after_7)
    assert not (out / "annotations").exists()
    assert not (out / "data.yaml").exists()
    assert read_manifest(out)["complete"] is False
    with pytest.raises(IncompleteDatasetError, match="resume"):
        read_records(out)
    assert main(["check", str(out)]) != 0
    result = generate(cfg, out, workers=1, cache_dir=cache)
    assert result.resumed >= 7
    assert result.made == 24 - result.resumed
    a, b = _tree(one), _tree(out)
    assert sorted(a) == sorted(b)
    assert _differ(a, b) == []
    again = generate(cfg, out, workers=1, cache_dir=cache)
    assert again.already_complete
    assert again.made == 0


def test_a_killed_generation_leaves_no_annotation_file_and_resumes(
    reference72: Path, workdir: Path, cache: Path
) -> None:
    one = reference72
    out = workdir / "killed"
    config = workdir / "dataset.yaml"
    argv = [sys.executable, str(REPO / "bin" / "uav-dataset"), "generate", str(config), "--out", str(out)]
    argv += ["--frames", "72", "--workers", "2", "--cache-dir", str(cache), "--quiet"]
    proc = subprocess.Popen(argv, start_new_session=True, stdout=subprocess.DEVNULL, stderr=subprocess.PIPE)
    try:
        deadline = time.monotonic() + 90
        while time.monotonic() < deadline and proc.poll() is None:
            lines = (
                sum(len(p.read_text().splitlines()) for p in (out / ".progress").glob("*.jsonl"))
                if (out / ".progress").is_dir()
                else 0
            )
            if lines >= 2:
                break
            time.sleep(0.02)
        assert proc.poll() is None, f"finished before it could be killed: {proc.stderr.read() if proc.stderr else ''}"
        os.killpg(proc.pid, signal.SIGKILL)
    finally:
        if proc.poll() is None:
            os.killpg(proc.pid, signal.SIGKILL)
        proc.wait(10)
    assert not (out / "annotations" / "instances.json").exists()
    assert read_manifest(out)["complete"] is False
    for path in out.rglob("*.png"):  # whatever is under a final name is whole
        if not path.name.startswith("."):
            assert cv2.imread(str(path), cv2.IMREAD_UNCHANGED) is not None, path
    resume = ["generate", str(config), "--out", str(out), "--frames", "72", "--cache-dir", str(cache), "--quiet"]
    assert main(resume) == 0
    a, b = _tree(one), _tree(out)
    assert sorted(a) == sorted(b)
    assert _differ(a, b) == []


def test_a_folder_holding_something_else_is_refused(
    dataset: tuple[Path, GenerateResult],
    workdir: Path,
    cfg: DatasetConfig,
    cache: Path,
    capsys: pytest.CaptureFixture[str],
) -> None:
    one, _ = dataset
    other = cfg.with_overrides(seed=5)
    with pytest.raises(DatasetFolderError) as info:
        generate(other, one, cache_dir=cache)
    text = str(info.value)
    assert str(one) in text
    assert "config.seed: 4 -> 5" in text
    assert "another --out" in text
    stranger = workdir / "stranger"
    stranger.mkdir()
    (stranger / "notes.txt").write_text("mine")
    with pytest.raises(DatasetFolderError, match="not a dataset folder"):
        generate(cfg, stranger, cache_dir=cache)
    assert (stranger / "notes.txt").read_text() == "mine"
    code = main(
        ["generate", str(workdir / "dataset.yaml"), "--out", str(one), "--seed", "5", "--cache-dir", str(cache)]
    )
    assert code == 2
    assert "different dataset" in capsys.readouterr().err


def test_stats_and_preview(
    dataset: tuple[Path, GenerateResult], artifacts: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    out, _ = dataset
    assert main(["stats", str(out)]) == 0
    text = capsys.readouterr().out
    for word in (
        "Splits (held-out worlds)",
        "| person |",
        "1-8",
        ">32",
        "Camera altitude",
        "Camera pitch",
        "Visible fraction",
    ):
        assert word in text
    card = (out / "README.md").read_text()
    assert "CC-BY-4.0" in card
    assert "| train | 21" in card
    png = artifacts / "preview.png"
    assert main(["preview", str(out), "--out", str(png), "--count", "8"]) == 0
    sheet = cv2.imread(str(png))
    assert sheet is not None
    assert sheet.shape[1] > 1500
    assert main(["stats", str(out / "nowhere")]) == 2


def test_sampling_rejects_cameras_inside_objects(cfg: DatasetConfig, cache: Path) -> None:
    from dataclasses import replace  # noqa: PLC0415

    from uav_datasets.core.config import PositionMode  # noqa: PLC0415
    from uav_datasets.core.sampling import ViewpointSampler, frame_rng  # noqa: PLC0415

    world = load_world(world_configs(cfg)[21], cache)
    cam = cfg.camera.model()
    inside = replace(
        cfg.viewpoints,
        positions=(PositionMode("near_objects", classes=("building",), max_offset_m=0.0),),
        altitude_agl_m=(1.0, 2.0),
        pitch_deg=(90.0, 90.0),
        max_attempts=50,
    )
    sampler = ViewpointSampler(world, inside, cam, cfg.labels.class_list, where="world seed 21")
    with pytest.raises(SamplingError, match="no valid viewpoint in 50 draws in world seed 21"):
        sampler.sample(frame_rng(0, 21, 0))
    low = replace(
        cfg.viewpoints,
        altitude_agl_m=(1.0, 8.0),
        positions=(PositionMode("near_objects", classes=("building",), max_offset_m=15.0),),
    )
    sampler = ViewpointSampler(world, low, cam, cfg.labels.class_list)
    rejected = 0
    for k in range(40):
        vp = sampler.sample(frame_rng(1, 21, k))
        rejected += vp.attempts - 1
        eye = vp.t_map_optical.translation_m
        for obj in world.objects:
            if obj.object_class.label in ("terrain", "road"):
                continue
            local = obj.pose.to_local(eye[None, :])[0]
            assert not (
                abs(local[0]) <= obj.size_m[0] / 2
                and abs(local[1]) <= obj.size_m[1] / 2
                and 0 <= local[2] <= obj.size_m[2]
            ), obj.name
        assert eye[2] - float(world.height_at(eye[0], eye[1])) >= 1.0 - 1e-9
    assert rejected > 0  # low cameras among the houses do get rejected
    # same seeds, same viewpoint; another sampling seed, another one
    a = sampler.sample(frame_rng(1, 21, 3)).t_map_optical
    b = sampler.sample(frame_rng(1, 21, 3)).t_map_optical
    c = sampler.sample(frame_rng(2, 21, 3)).t_map_optical
    assert np.array_equal(a.matrix(), b.matrix())
    assert not np.array_equal(a.matrix(), c.matrix())
    assert math.isfinite(float(c.translation_m[2]))


def test_frame_records_round_trip(dataset: tuple[Path, GenerateResult]) -> None:
    out, _ = dataset
    for rec in read_records(out)[:3]:
        assert FrameRecord.from_json(rec.to_json()) == rec


def _children(pid: int) -> list[int]:
    out = []
    for stat in Path("/proc").glob("[0-9]*/stat"):
        try:
            fields = stat.read_text().rsplit(")", 1)[1].split()
        except OSError:
            continue
        if int(fields[1]) == pid:
            out.append(int(stat.parent.name))
    return out


@pytest.mark.parametrize("case", [(2, "worker", "died"), (1, "encoder helper", "the encoder process died")])
def test_a_dead_worker_is_reported_and_the_run_resumes(
    reference72: Path, workdir: Path, cache: Path, case: tuple[int, str, str]
) -> None:
    """SIGKILL a shard worker (two workers), or the helper process that encodes and writes a worker's images (one
    worker, in the command's own process): the command stops with a message saying what died and to resume, and
    the same command finishes the same dataset."""
    workers, victim, said = case
    one = reference72
    out = workdir / f"dead_{victim.replace(' ', '_')}"
    config = workdir / "dataset.yaml"
    argv = [sys.executable, str(REPO / "bin" / "uav-dataset"), "generate", str(config), "--out", str(out)]
    argv += ["--frames", "72", "--workers", str(workers), "--cache-dir", str(cache), "--quiet"]
    proc = subprocess.Popen(argv, start_new_session=True, stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True)
    try:
        pid = None
        deadline = time.monotonic() + 90
        while pid is None and time.monotonic() < deadline and proc.poll() is None:
            journals = list((out / ".progress").glob("*.jsonl")) if (out / ".progress").is_dir() else []
            if any(p.read_text().count("\n") >= 1 for p in journals):
                # spawned children: the workers, or with one worker its encoder helper (not the resource tracker)
                spawned = [c for c in _children(proc.pid) if b"spawn_main" in Path(f"/proc/{c}/cmdline").read_bytes()]
                pid = max(spawned, default=None)
            time.sleep(0.02)
        assert pid is not None, f"no {victim} to kill"
        os.kill(pid, signal.SIGKILL)
        _, err = proc.communicate(timeout=120)
    finally:
        if proc.poll() is None:
            os.killpg(proc.pid, signal.SIGKILL)
            proc.wait(10)
    assert proc.returncode == 3, err
    assert said in err
    assert "resume" in err
    assert not (out / "annotations").exists()
    resume = ["generate", str(config), "--out", str(out), "--frames", "72", "--cache-dir", str(cache), "--quiet"]
    assert main(resume) == 0
    a, b = _tree(one), _tree(out)
    assert sorted(a) == sorted(b)
    assert _differ(a, b) == []


def test_check_catches_a_damaged_dataset(dataset: tuple[Path, GenerateResult], workdir: Path) -> None:
    one, _ = dataset
    bad = workdir / "damaged"
    shutil.copytree(one, bad, symlinks=True)
    coco = bad / "annotations" / "instances.json"
    doc = json.loads(coco.read_text())
    doc["annotations"][3]["bbox"][2] += 1  # one box a pixel too wide
    coco.write_text(json.dumps(doc))
    rec = next(r for r in read_records(bad) if r.labels)
    yolo = bad / rec.files["yolo"]
    yolo.write_text(yolo.read_text().replace(" 0.", " 0.0", 1))  # one YOLO coordinate off by a factor of 10
    report = check_dataset(bad)
    failed = {name for name, ok, _ in report.results if not ok}
    assert failed == {
        "COCO annotations match the frames' labels",
        "tight boxes equal mask extents",
        "YOLO round trip",
    }, report.text()
    assert main(["check", str(bad)]) == 1

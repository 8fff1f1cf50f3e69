"""``uav-train-detector``: train the range's baseline detector on a data engine dataset, export ONNX, score it.

    uav-train-detector DATASET --out DIR [--steps N] [--batch-size B] [--crop-px P] [--width W] [--seed S]
                       [--threads T] [--eval-split test] [--quiet]

``DATASET`` is a folder made by ``uav-dataset generate`` (``config/datasets/detector_train.yaml``); its ``train``
split trains, ``--eval-split`` (held-out worlds) scores. ``DIR`` receives ``model.onnx`` (the ``detector`` node's
format), ``weights.pt``, ``hyperparameters.json``, ``data.json`` (the dataset's config, fingerprint and world seeds
per split), ``curve.jsonl`` and ``curve.png`` (the training loss), ``eval.json`` (COCO AP/AP50 by class and
TinyPerson size bin on the held-out worlds) and ``command.txt``. Needs the training dependencies: ``make
train-detector`` installs them (requirements-train.txt). Exit codes: 0 done, 2 bad arguments or dataset, 3 torch
missing, 1 a failure.
"""

from __future__ import annotations

import argparse
import json
import shlex
import sys
import time
from collections.abc import Callable
from dataclasses import replace
from pathlib import Path
from typing import Any

from uav_common.exit_codes import ExitCode

__all__ = ["main"]


def _say(text: str) -> None:
    sys.stdout.write(text + "\n")
    sys.stdout.flush()


def _fail(text: str, code: ExitCode) -> int:
    sys.stderr.write(f"uav-train-detector: {text}\n")
    return int(code)


def _parser() -> argparse.ArgumentParser:
    p = argparse.ArgumentParser(prog="uav-train-detector", description=(__doc__ or "").split("\n\n")[0])
    p.add_argument("dataset", type=Path, help="a uav-dataset folder (with a train split)")
    p.add_argument("--out", type=Path, required=True, help="the output folder (model.onnx, curve, eval, ...)")
    p.add_argument("--steps", type=int, default=None, help="training steps (default: TrainConfig's)")
    p.add_argument("--batch-size", type=int, default=None)
    p.add_argument("--crop-px", type=int, default=None, help="square training crops, a multiple of 16")
    p.add_argument("--width", type=int, default=None, help="channels of the first block (model size)")
    p.add_argument("--seed", type=int, default=0)
    p.add_argument("--threads", type=int, default=2, help="torch threads for training")
    p.add_argument("--eval-split", default="test", help="the held-out split to score ('' = none)")
    p.add_argument("--quiet", action="store_true")
    return p


def main(argv: list[str] | None = None) -> int:
    args = _parser().parse_args(argv)
    try:
        import torch  # noqa: PLC0415, F401
    except ImportError:
        return _fail("torch is not installed; run `make train-detector` (requirements-train.txt)", ExitCode.RESOURCE)
    from uav_perception.errors import PerceptionError  # noqa: PLC0415
    from uav_perception.training.data import TrainDataError, load_split  # noqa: PLC0415
    from uav_perception.training.train import TrainConfig, train  # noqa: PLC0415

    say = (lambda _t: None) if args.quiet else _say
    over = {"steps": args.steps, "batch_size": args.batch_size, "crop_px": args.crop_px, "width": args.width}
    try:
        cfg = replace(TrainConfig(seed=args.seed, threads=args.threads), **{k: v for k, v in over.items() if v})
    except ValueError as err:
        return _fail(str(err), ExitCode.CONFIG)
    try:
        data = load_split(args.dataset, "train")
        held = load_split(args.dataset, args.eval_split) if args.eval_split else None
    except TrainDataError as err:
        return _fail(str(err), ExitCode.CONFIG)
    if held is not None and set(held.world_seeds) & set(data.world_seeds):
        shared = sorted(set(held.world_seeds) & set(data.world_seeds))
        return _fail(f"split {args.eval_split!r} shares worlds {shared} with train: not held out", ExitCode.CONFIG)
    out: Path = args.out
    out.mkdir(parents=True, exist_ok=True)
    given = argv if argv is not None else sys.argv[1:]
    (out / "command.txt").write_text("uav-train-detector " + " ".join(shlex.quote(a) for a in given) + "\n")
    meta = json.loads((Path(args.dataset) / "dataset.json").read_text())
    record = {
        "dataset": str(args.dataset),
        "fingerprint": data.fingerprint,
        "config": meta.get("identity", {}).get("config"),
        "train_world_seeds": list(data.world_seeds),
        "train_frames": len(data.frames),
        "train_boxes": int(sum(len(f.boxes) for f in data.frames)),
        "eval_split": args.eval_split,
        "eval_world_seeds": list(held.world_seeds) if held else [],
        "eval_frames": len(held.frames) if held else 0,
    }
    (out / "data.json").write_text(json.dumps(record, indent=2))
    (out / "hyperparameters.json").write_text(json.dumps(cfg.as_dict(), indent=2))
    try:
        say(
            f"loading {len(data.frames)} training frames ({record['train_boxes']} boxes, "
            f"worlds {record['train_world_seeds']})"
        )
        images = [data.image(f) for f in data.frames]
        with (out / "curve.jsonl").open("w") as curve_file:

            def progress(point: dict[str, float]) -> None:
                curve_file.write(json.dumps(point) + "\n")
                curve_file.flush()
                losses = ", ".join(f"{k} {point[k]:.3f}" for k in ("heat", "offset", "size"))
                say(
                    f"step {int(point['step'])}/{cfg.steps} loss {point['loss']:.3f} ({losses}) "
                    f"{point['seconds']:.0f} s"
                )

            result = train(data, images, cfg, progress)
        del images
        _finish(out, data, held, cfg, result, say)
    except PerceptionError as err:
        return _fail(str(err), ExitCode.CONFIG)
    return int(ExitCode.OK)


def _finish(out: Path, data: Any, held: Any, cfg: Any, result: Any, say: Callable[[str], None]) -> None:  # noqa: PLR0917
    import torch  # noqa: PLC0415

    from uav_perception.shell.onnx_detector import OnnxDetector  # noqa: PLC0415
    from uav_perception.training.evaluate import coco_scores, detect_split  # noqa: PLC0415
    from uav_perception.training.model import export_onnx  # noqa: PLC0415
    from uav_perception.training.plot import plot_curve  # noqa: PLC0415

    torch.save(result.net.state_dict(), out / "weights.pt")
    meta = {
        "uav_model": "TinyCenterNet (uav-train-detector)",
        "uav_hyperparameters": json.dumps(cfg.as_dict()),
        "uav_train_worlds": json.dumps(list(data.world_seeds)),
        "uav_dataset_fingerprint": data.fingerprint,
    }
    model_path = out / "model.onnx"
    export_onnx(
        result.net,
        model_path,
        classes=data.classes,
        height=data.frames[0].height,
        width=data.frames[0].width,
        meta=meta,
    )
    plot_curve(out / "curve.jsonl", out / "curve.png")
    size_mb = model_path.stat().st_size / 1e6
    say(
        f"trained {cfg.steps} steps ({result.samples} crops) in {result.seconds:.0f} s; {model_path} ({size_mb:.2f} MB)"
    )
    summary: dict[str, object] = {"train_seconds": result.seconds, "final_loss": result.curve[-1]["loss"]}
    if held is not None:
        t0 = time.perf_counter()
        model = OnnxDetector(model_path, threads=1)
        dets, per_frame = detect_split(model, held)
        scores = coco_scores(held, dets)
        summary.update(
            {
                "eval_split": held.split,
                "eval_worlds": list(held.world_seeds),
                "eval_frames": len(held.frames),
                "seconds_per_frame_1thread": per_frame,
                "scores": scores,
                "eval_seconds": time.perf_counter() - t0,
            }
        )
        for cls, bins in scores.items():
            say(f"{cls:8s} " + "  ".join(f"{b} AP50 {v['AP50']:.3f} (n={int(v['gt'])})" for b, v in bins.items()))
    (out / "eval.json").write_text(json.dumps(summary, indent=2))

"""``uav-dataset``: labelled aerial datasets from the simulated world (a thin shell over ``uav_datasets.shell``).

    uav-dataset generate CONFIG.yaml --out DIR [--frames N] [--seed S] [--workers K] [--run RUN] [--cache-dir D]
    uav-dataset stats DIR                  # the dataset card's tables
    uav-dataset preview DIR [--out PNG]    # contact sheet with masks and boxes (default DIR/preview.png)
    uav-dataset check DIR                  # pycocotools AP of the ground truth, mask extents, round trips

CONFIG is a file under config/datasets/ (or its name). An interrupted generation resumes when the
same command runs again. Exit codes: 0 done, 1 a failed check or runtime failure, 2 bad config,
argument or output folder, 3 no GL/EGL or a worker died, 130 interrupted.
"""

from __future__ import annotations

import argparse
import sys
import time
from pathlib import Path

from uav_common.errors import ConfigError, ResourceError
from uav_common.exit_codes import ExitCode, exit_code_for
from uav_common.paths import config_dir
from uav_datasets.core.config import load_dataset_config
from uav_datasets.core.stats import dataset_stats, stats_markdown
from uav_datasets.errors import DatasetError
from uav_datasets.shell.worlds import DEFAULT_CACHE_DIR

__all__ = ["main"]


def _out(text: str) -> None:
    sys.stdout.write(text + "\n")
    sys.stdout.flush()


def _parser() -> argparse.ArgumentParser:
    p = argparse.ArgumentParser(
        prog="uav-dataset", description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter
    )
    sub = p.add_subparsers(dest="command", required=True)
    g = sub.add_parser("generate", help="generate (or resume) a dataset")
    g.add_argument("config", help="dataset config: a YAML path or a name under config/datasets")
    g.add_argument("--out", type=Path, required=True, help="dataset folder (new, empty, or this dataset's to resume)")
    g.add_argument("--frames", type=int, default=None, help="frames to generate (overrides the config's frames)")
    g.add_argument("--seed", type=int, default=None, help="sampling seed (overrides the config's seed)")
    g.add_argument("--workers", type=int, default=1, help="processes rendering in parallel (default 1)")
    g.add_argument(
        "--run", type=Path, default=None, help="flights: the recorded run folder or bag (overrides flight.run)"
    )
    g.add_argument("--cache-dir", type=Path, default=DEFAULT_CACHE_DIR, help="world cache folder")
    g.add_argument("--quiet", action="store_true", help="no progress line")
    s = sub.add_parser("stats", help="print the dataset card's tables")
    s.add_argument("dir", type=Path)
    v = sub.add_parser("preview", help="write a contact sheet PNG with masks and boxes")
    v.add_argument("dir", type=Path)
    v.add_argument("--out", type=Path, default=None, help="PNG path (default DIR/preview.png)")
    v.add_argument("--count", type=int, default=16, help="frames on the sheet (default 16)")
    v.add_argument("--columns", type=int, default=4)
    c = sub.add_parser("check", help="verify a dataset: COCO AP of the ground truth, mask extents, round trips")
    c.add_argument("dir", type=Path)
    return p


def _config_path(text: str) -> Path:
    path = Path(text)
    if path.suffix in (".yaml", ".yml") or path.exists():
        return path
    return config_dir() / "datasets" / f"{text}.yaml"


class _Progress:
    def __init__(self, quiet: bool) -> None:
        self.quiet = quiet
        self.t0 = time.monotonic()
        self.first: int | None = None
        self.last = 0.0

    def __call__(self, done: int, total: int) -> None:
        if self.first is None:
            self.first = done
        now = time.monotonic()
        if self.quiet or (now - self.last < 1.0 and done < total):
            return
        self.last = now
        made = done - self.first
        rate = made / (now - self.t0) if now > self.t0 else 0.0
        eta = (total - done) / rate if rate > 0 else float("nan")
        sys.stderr.write(
            f"\rframes {done}/{total} ({100.0 * done / max(total, 1):.0f} %), {rate:.1f} frames/s, eta {eta:.0f} s   "
        )
        if done >= total:
            sys.stderr.write("\n")
        sys.stderr.flush()


def _generate(args: argparse.Namespace) -> int:
    from uav_datasets.shell.generate import generate  # noqa: PLC0415

    cfg = load_dataset_config(_config_path(args.config)).with_overrides(frames=args.frames, seed=args.seed)
    result = generate(
        cfg,
        args.out,
        workers=args.workers,
        cache_dir=args.cache_dir,
        run=args.run,
        progress=_Progress(args.quiet),
    )
    m = result.manifest
    if result.already_complete:
        _out(f"{args.out}: dataset {cfg.name} is already complete ({m.get('frames')} frames); nothing to do")
        return 0
    stats = m.get("stats", {})
    resumed = f", {result.resumed} kept from an earlier run" if result.resumed else ""
    _out(
        f"{args.out}: {result.frames} frames ({result.made} made in {result.seconds:.1f} s, "
        f"{result.frames_per_s:.1f} frames/s{resumed}), {stats.get('instances', 0)} labelled instances"
    )
    _out(f"card: {args.out / 'README.md'}")
    return 0


def _stats(args: argparse.Namespace) -> int:
    from uav_datasets.shell.folder import read_manifest, read_records  # noqa: PLC0415

    records = read_records(args.dir)
    cfg = read_manifest(args.dir)["identity"]["config"]
    card = cfg.get("card", {})
    st = dataset_stats(
        records,
        cfg["labels"]["classes"],
        card.get("altitude_bands_m", (0.0, 30.0, 60.0, 90.0, 120.0)),
        card.get("pitch_bands_deg", (0.0, 30.0, 60.0, 80.0)),
    )
    _out(f"# {cfg['name']} ({args.dir})\n")
    _out(stats_markdown(st))
    return 0


def _preview(args: argparse.Namespace) -> int:
    from uav_datasets.shell.preview import write_preview  # noqa: PLC0415

    _out(str(write_preview(args.dir, args.out, count=args.count, columns=args.columns)))
    return 0


def _check(args: argparse.Namespace) -> int:
    from uav_datasets.shell.check import check_dataset  # noqa: PLC0415

    report = check_dataset(args.dir)
    _out(report.text())
    _out("all checks passed" if report.ok else "some checks FAILED")
    return 0 if report.ok else int(ExitCode.FAILURE)


_COMMANDS = {"generate": _generate, "stats": _stats, "preview": _preview, "check": _check}


def main(argv: list[str] | None = None) -> int:
    args = _parser().parse_args(argv)
    try:
        return _COMMANDS[args.command](args)
    except KeyboardInterrupt:
        sys.stderr.write(
            "\nuav-dataset: interrupted; the frames made so far are kept: run the same command to resume\n"
        )
        return 130
    except (ConfigError, ResourceError, DatasetError) as err:
        sys.stderr.write(f"uav-dataset: {err}\n")
        return int(exit_code_for(err))

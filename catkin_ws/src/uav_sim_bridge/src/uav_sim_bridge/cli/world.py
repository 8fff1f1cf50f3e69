"""``uav-world``: generate, inspect, export and render the simulated world from a shell.

    uav-world generate [WORLD] [--out DIR]      # mesh (PLY + glTF), objects.json, summary, hash
    uav-world info [WORLD]                      # counts, bounds, hash
    uav-world hash [WORLD]                      # just the hash (same seed -> same hash)
    uav-world voxels [WORLD] --resolution 0.5 --out keys.npy
    uav-world render [WORLD] --x 0 --y 0 --alt 50 [--yaw 0] [--camera nadir|forward] [--environment PRESET] --out DIR
    uav-world render [WORLD] --sheet docs/images/world_contact_sheet.png   # every preset, every pose and vehicle
    uav-world overview [WORLD] --out overview.png

WORLD is a name under config/worlds (default: ``default``) or a path to a world YAML.
``--seed N`` overrides the world's seed.  Generated worlds are cached in
``--cache-dir`` (default ~/.cache/uav_test_range/worlds).
"""

from __future__ import annotations

import argparse
import json
import sys
import time
from collections import Counter
from dataclasses import replace
from pathlib import Path

import numpy as np

from uav_common.config import ConfigError, from_mapping
from uav_common.exit_codes import ExitCode, exit_code_for
from uav_sim_bridge.config import default_cameras, resolve_environment, resolve_world_path
from uav_sim_bridge.core import visualize
from uav_sim_bridge.core.camera import CameraModel, look_at
from uav_sim_bridge.core.camera_effects import CameraEffects, camera_rng
from uav_sim_bridge.core.environment import EnvironmentConfig
from uav_sim_bridge.core.lighting import lighting_for
from uav_sim_bridge.core.transforms import RigidTransform
from uav_sim_bridge.core.world import World
from uav_sim_bridge.core.world_config import load_world_config
from uav_sim_bridge.errors import SimBridgeError
from uav_sim_bridge.shell.world_io import export_mesh, export_objects_json
from uav_sim_bridge.shell.world_store import load_or_generate

__all__ = ["main"]

DEFAULT_CACHE = Path("~/.cache/uav_test_range/worlds").expanduser()


def _out(text: str) -> None:
    sys.stdout.write(text + "\n")


def _parser() -> argparse.ArgumentParser:
    p = argparse.ArgumentParser(
        prog="uav-world", description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter
    )
    sub = p.add_subparsers(dest="command", required=True)

    def common(sp: argparse.ArgumentParser) -> None:
        sp.add_argument("world", nargs="?", default="default", help="world name or YAML path (default: default)")
        sp.add_argument("--seed", type=int, default=None, help="override the world's seed")
        sp.add_argument("--cache-dir", type=Path, default=DEFAULT_CACHE, help="world cache folder")

    g = sub.add_parser("generate", help="generate and export mesh + objects")
    common(g)
    g.add_argument("--out", type=Path, default=Path("world_export"), help="output folder")
    for name in ("info", "hash"):
        common(sub.add_parser(name, help=f"print the world's {name}"))
    v = sub.add_parser("voxels", help="ground-truth surface voxel keys (int64 N x 3, floor(p / res))")
    common(v)
    v.add_argument("--resolution", type=float, required=True, help="voxel size in metres")
    v.add_argument("--out", type=Path, required=True, help=".npy file")
    r = sub.add_parser("render", help="color/depth/class PNGs of a default camera on a vehicle pose")
    common(r)
    r.add_argument("--x", type=float, default=0.0)
    r.add_argument("--y", type=float, default=0.0)
    r.add_argument("--alt", type=float, default=50.0, help="height above the ground under (x, y)")
    r.add_argument("--yaw", type=float, default=0.0, help="vehicle heading, degrees counter-clockwise from east")
    r.add_argument("--camera", choices=sorted(default_cameras()), default="nadir")
    r.add_argument("--environment", default="clean", help="environment preset (config/environments), default clean")
    r.add_argument(
        "--sheet",
        type=Path,
        metavar="PNG",
        help="instead: the contact sheet (one view under every preset; each person pose and vehicle type "
        "from 30, 60 and 100 m) into this PNG",
    )
    r.add_argument("--out", type=Path, default=Path("."))
    o = sub.add_parser("overview", help="a bird's-eye PNG of the whole world")
    common(o)
    o.add_argument("--out", type=Path, default=Path("overview.png"))
    return p


def _load(args: argparse.Namespace) -> World:
    cfg = load_world_config(resolve_world_path(args.world))
    if args.seed is not None:
        cfg = replace(cfg, seed=args.seed)
    return load_or_generate(cfg, args.cache_dir)


def _summary(world: World) -> dict[str, object]:
    counts = Counter(o.object_class.label for o in world.objects)
    return {
        "name": world.config.name,
        "seed": world.config.seed,
        "hash": world.hash,
        "bounds_m": list(world.terrain.bounds_m),
        "terrain_height_range_m": [float(world.terrain.heights_m.min()), float(world.terrain.heights_m.max())],
        "objects": dict(sorted(counts.items())),
        "villages": len(world.roads.villages_m),
        "triangles": len(world.mesh.faces),
    }


def _save_png(path: Path, array: np.ndarray) -> None:
    from PIL import Image  # noqa: PLC0415

    path.parent.mkdir(parents=True, exist_ok=True)
    Image.fromarray(array).save(path)


def _render(args: argparse.Namespace, world: World) -> list[Path]:
    from uav_sim_bridge.render import RenderedFrame, Renderer  # noqa: PLC0415

    if args.sheet is not None:
        from uav_sim_bridge.cli.contact_sheet import contact_sheet  # noqa: PLC0415

        return [contact_sheet(world, args.sheet)]
    env = from_mapping(EnvironmentConfig, resolve_environment({"preset": args.environment}), source=args.environment)
    cam = CameraModel.from_config(args.camera, default_cameras()[args.camera])
    ground = float(world.height_at(args.x, args.y))
    base = RigidTransform.from_rpy([args.x, args.y, ground + args.alt], yaw_rad=np.radians(args.yaw))
    renderer = Renderer(world, lighting=lighting_for(env, world.config.latitude_deg))
    try:
        frame = renderer.render(cam, cam.optical_pose(base))
        fx = env.effects_for(args.camera)
        if fx.changes_pixels:
            effects = CameraEffects(
                fx, cam.width, cam.height, cam.fx, cam.fy, cam.cx, cam.cy, camera_rng(env.seed, args.camera)
            )
            frame = RenderedFrame(
                effects.apply(frame.color_rgb, frame.depth_m, 0.0).color_rgb, frame.depth_m, frame.instance_id
            )
    finally:
        renderer.close()
    stem = args.out / f"{args.camera}_{args.x:g}_{args.y:g}_{args.alt:g}"
    paths = [Path(f"{stem}_color.png"), Path(f"{stem}_depth.png"), Path(f"{stem}_class.png")]
    _save_png(paths[0], frame.color_rgb)
    _save_png(paths[1], visualize.depth_image(frame.depth_m))
    _save_png(paths[2], visualize.class_image(frame.instance_id, world.instance_class))
    return paths


def _overview(args: argparse.Namespace, world: World) -> Path:
    from uav_sim_bridge.render import Renderer  # noqa: PLC0415

    x0, y0, x1, y1 = world.terrain.bounds_m
    size = max(x1 - x0, y1 - y0)
    centre = np.array([(x0 + x1) / 2, (y0 + y1) / 2, 0.0])
    cam = CameraModel(name="overview", width=1280, height=960, fx=1100.0, fy=1100.0, cx=639.5, cy=479.5, far_m=6 * size)
    renderer = Renderer(world)
    try:
        frame = renderer.render(cam, look_at(centre + np.array([0.0, -1.05 * size, 0.85 * size]), centre))
    finally:
        renderer.close()
    _save_png(args.out, frame.color_rgb)
    return Path(args.out)


def main(argv: list[str] | None = None) -> int:
    args = _parser().parse_args(argv)
    try:
        t0 = time.monotonic()
        world = _load(args)
        if args.command == "hash":
            _out(world.hash)
        elif args.command == "info":
            _out(json.dumps(_summary(world), indent=1))
        elif args.command == "generate":
            args.out.mkdir(parents=True, exist_ok=True)
            export_mesh(world, args.out / "world.ply")
            export_mesh(world, args.out / "world.glb")
            export_objects_json(world, args.out / "objects.json")
            (args.out / "summary.json").write_text(json.dumps(_summary(world), indent=1))
            _out(f"world {world.config.name} seed {world.config.seed} hash {world.hash}")
            _out(f"wrote {args.out}/world.ply, world.glb, objects.json, summary.json in {time.monotonic() - t0:.1f} s")
        elif args.command == "voxels":
            keys = world.surface_voxels(args.resolution)
            args.out.parent.mkdir(parents=True, exist_ok=True)
            np.save(args.out, keys)
            _out(f"{len(keys)} surface voxels at {args.resolution} m -> {args.out}")
        elif args.command == "render":
            for p in _render(args, world):
                _out(str(p))
        elif args.command == "overview":
            _out(str(_overview(args, world)))
    except (ConfigError, SimBridgeError, ValueError) as err:
        sys.stderr.write(f"uav-world: {err}\n")
        # 2 for a bad config or argument, 3 for no GL/EGL (RenderError), 1 otherwise (docs/architecture.md)
        return int(ExitCode.CONFIG if isinstance(err, ValueError) else exit_code_for(err))
    return 0

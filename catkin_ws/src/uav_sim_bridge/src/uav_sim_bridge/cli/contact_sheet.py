"""The world's contact sheet (``uav-world render --sheet``): how it looks under each environment preset, and
what a camera sees of each person pose and vehicle type from 30, 60 and 100 m.

* Top: one oblique view (the forward camera, 45 m above the ground, looking across a village) under every
  preset in ``config/environments/``, each with the preset's camera effects (the camera flying at 12 m/s and
  turning, so motion blur shows where the preset has it).
* Bottom: close-ups. Each person pose (standing, walking, sitting, lying) and each vehicle type (car, van,
  truck) is put on open ground and seen by the 640x480, 90 degree camera from 12 (detail), 30, 60 and 100 m
  (slant range, 45 degrees down) in the ``clear_noon`` preset at 9:30 (shadows show); each tile is the
  camera's own pixels around the object, enlarged without smoothing, so the tile shows exactly what a
  detector gets at that range.
"""

from __future__ import annotations

import math
from pathlib import Path

import numpy as np
import numpy.typing as npt

from uav_common.config import from_mapping
from uav_sim_bridge.config import default_cameras, environment_presets, resolve_environment
from uav_sim_bridge.core import figures
from uav_sim_bridge.core.camera import CameraModel, look_at
from uav_sim_bridge.core.camera_effects import CameraEffects, CameraMotion, camera_rng
from uav_sim_bridge.core.environment import EnvironmentConfig
from uav_sim_bridge.core.figures import PersonPose, VehicleType
from uav_sim_bridge.core.lighting import lighting_for
from uav_sim_bridge.core.objects import ObjectPose, WorldObject
from uav_sim_bridge.core.transforms import RigidTransform
from uav_sim_bridge.core.world import World
from uav_sim_bridge.core.world_config import ObjectClass
from uav_sim_bridge.render import Renderer

__all__ = ["contact_sheet"]

U8 = npt.NDArray[np.uint8]
_TILE_W, _TILE_H = 400, 300
_TILE = 192  # close-up tile side, screen pixels
#: Slant ranges of the close-ups and the camera pixels around the subject each tile shows (enlarged without
#: smoothing to the tile): 12 m to see the shapes, then the 30, 60 and 100 m a detector has to cope with.
_RANGES_M = {12.0: 96, 30.0: 64, 60.0: 48, 100.0: 32}
_BG = (24, 28, 34)


def _environment(preset: str) -> EnvironmentConfig:
    return from_mapping(EnvironmentConfig, resolve_environment({"preset": preset}), source=preset)


def _effects(env: EnvironmentConfig, cam: CameraModel) -> CameraEffects | None:
    cfg = env.effects_for(cam.name)
    if not cfg.changes_pixels:
        return None
    return CameraEffects(cfg, cam.width, cam.height, cam.fx, cam.fy, cam.cx, cam.cy, camera_rng(env.seed, cam.name))


def _label(img: U8, lines: list[str]) -> U8:
    from PIL import Image, ImageDraw  # noqa: PLC0415

    pil = Image.fromarray(img)
    draw = ImageDraw.Draw(pil)
    y = 4
    for line in lines:
        w = int(draw.textlength(line)) + 8
        draw.rectangle([2, y - 2, 2 + w, y + 12], fill=(0, 0, 0))
        draw.text((6, y), line, fill=(255, 255, 255))
        y += 15
    return np.asarray(pil)


def _resize(img: U8, w: int, h: int, *, nearest: bool = False) -> U8:
    from PIL import Image  # noqa: PLC0415

    method = Image.Resampling.NEAREST if nearest else Image.Resampling.LANCZOS
    return np.asarray(Image.fromarray(img).resize((w, h), method))


def _overview_viewpoint(world: World) -> RigidTransform:
    """45 m above the ground, 150 m south-west of the first village, looking at it."""
    vx, vy = (float(v) for v in world.roads.villages_m[0]) if len(world.roads.villages_m) else (150.0, 150.0)
    x, y = vx - 110.0, vy - 110.0
    z = float(world.height_at(x, y)) + 45.0
    return RigidTransform.from_rpy([x, y, z], yaw_rad=math.atan2(vy - y, vx - x))


def _preset_tiles(world: World, renderer: Renderer, presets: list[str]) -> list[U8]:
    cam = CameraModel.from_config("forward", default_cameras()["forward"])
    base = _overview_viewpoint(world)
    motion = CameraMotion((0.0, 0.0, 12.0), (0.0, 0.35, 0.0))  # forward at 12 m/s, yawing (optical frame)
    tiles = []
    for preset in presets:
        env = _environment(preset)
        light = lighting_for(env, world.config.latitude_deg)
        renderer.set_lighting(light)
        frame = renderer.render(cam, cam.optical_pose(base))
        color = frame.color_rgb
        effects = _effects(env, cam)
        if effects is not None:
            color = effects.apply(color, frame.depth_m, 0.0, motion).color_rgb
        tile = _resize(color, _TILE_W, _TILE_H)
        text = [f"{preset}", f"sun {light.elevation_deg:.0f} deg up, az {light.azimuth_deg:.0f}"]
        if env.visibility_m is not None:
            text.append(f"visibility {env.visibility_m:.0f} m, overcast {env.overcast:.1f}")
        tiles.append(_label(tile, text))
    return tiles


def _stage(world: World) -> tuple[float, float]:
    """Open, flat-ish ground away from home for the close-ups: the flattest clear spot on a coarse grid."""
    x0, y0, x1, y1 = world.terrain.bounds_m
    best, best_cost = (x0 + 60.0, y0 + 60.0), math.inf
    obstacles = np.array([o.pose.position_m[:2] for o in world.objects if o.object_class is not ObjectClass.TERRAIN])
    for x in np.linspace(x0 + 80, x1 - 80, 24):
        for y in np.linspace(y0 + 80, y1 - 80, 24):
            if math.hypot(x, y) < 60.0:
                continue
            ring = np.array([[x + dx, y + dy] for dx in (-20, 0, 20) for dy in (-20, 0, 20)])
            slope = float(np.ptp(world.height_at(ring[:, 0], ring[:, 1])))
            near = int(np.sum(np.hypot(obstacles[:, 0] - x, obstacles[:, 1] - y) < 25.0)) if len(obstacles) else 0
            cost = slope + 3.0 * near
            if cost < best_cost:
                best, best_cost = (float(x), float(y)), cost
    return best


def _subjects(world: World) -> list[tuple[str, WorldObject, PersonPose | None]]:
    people = world.objects_of_class(ObjectClass.PERSON)
    out: list[tuple[str, WorldObject, PersonPose | None]] = []
    for k, pose in enumerate(PersonPose):
        if k < len(people):
            out.append((f"person, {pose.label}", people[k], pose))
    for vtype in VehicleType:
        v = next((o for o in world.objects_of_class(ObjectClass.VEHICLE) if o.kind == vtype.label), None)
        if v is not None:
            out.append((vtype.label, v, None))
    return out


def _reshape(renderer: Renderer, obj: WorldObject, pose: PersonPose) -> float:
    """Give a person a pose in the renderer; returns the box height."""
    height, build = obj.shape if len(obj.shape) == 2 else (1.75, 1.0)
    verts = figures.person_vertices([height], [build], [int(pose)], [0.3])
    faces, _ = figures.person_faces()
    renderer.set_object_shape(obj.instance_id, verts[0][faces].reshape(-1, 3))
    return float(figures.person_boxes([height], [build], [int(pose)])[0][2])


#: The close-ups' light: the clear_noon preset's sky and camera in mid-morning, so the shadows show.
_CLOSEUP_ENV = {"preset": "clear_noon", "time_of_day_h": 9.5}


def _closeup_tiles(world: World, renderer: Renderer) -> tuple[list[list[U8]], list[str]]:
    env = from_mapping(EnvironmentConfig, resolve_environment(_CLOSEUP_ENV), source="contact sheet")
    renderer.set_lighting(lighting_for(env, world.config.latitude_deg))
    cam = CameraModel.from_config("closeup", default_cameras()["forward"])
    sx, sy = _stage(world)
    rows: list[list[U8]] = []
    names: list[str] = []
    park = [(sx + 400.0 * (i + 1), sy + 400.0) for i in range(8)]
    subjects = _subjects(world)
    for i, (_label_text, obj, _pose) in enumerate(subjects):  # everyone off stage first
        renderer.set_object_pose(obj.instance_id, ObjectPose((*park[i % len(park)], -1000.0), 0.0))
    for i, (label, obj, pose) in enumerate(subjects):
        ground = float(world.height_at(sx, sy))
        height = _reshape(renderer, obj, pose) if pose is not None else obj.size_m[2]
        yaw = 0.6
        renderer.set_object_pose(obj.instance_id, ObjectPose((sx, sy, ground), yaw))
        target = np.array([sx, sy, ground + 0.4 * height])
        row = []
        for rng_m, crop_px in _RANGES_M.items():
            az = math.radians(200.0)  # camera south-south-west of the subject, sun from the south
            el = math.radians(45.0)
            eye = target + rng_m * np.array([math.cos(el) * math.sin(az), math.cos(el) * math.cos(az), math.sin(el)])
            pose_cam = look_at(eye, target)
            frame = renderer.render(cam, pose_cam)
            effects = _effects(env, cam)
            color = effects.apply(frame.color_rgb, frame.depth_m, 0.0).color_rgb if effects else frame.color_rgb
            uv, _ = cam.project(pose_cam.inverse().apply(target[None]))
            cu, cv = round(float(uv[0, 0])), round(float(uv[0, 1]))
            half = (crop_px if pose is not None else round(1.6 * crop_px)) // 2  # vehicles: a wider view
            cu = min(max(cu, half), cam.width - half)
            cv = min(max(cv, half), cam.height - half)
            crop = color[cv - half : cv + half, cu - half : cu + half]
            pixels = int(np.count_nonzero(frame.instance_id == obj.instance_id))
            tile = _resize(np.ascontiguousarray(crop), _TILE, _TILE, nearest=True)
            row.append(_label(tile, [f"{label}", f"{rng_m:.0f} m: {pixels} px"]))
        renderer.set_object_pose(obj.instance_id, ObjectPose((*park[i % len(park)], -1000.0), 0.0))
        rows.append(row)
        names.append(label)
    for _, obj, _pose in subjects:  # back where the world has them
        renderer.set_object_pose(obj.instance_id, obj.pose)
        if obj.kind in {p.label for p in PersonPose}:
            _reshape(renderer, obj, PersonPose.from_label(obj.kind))
    return rows, names


def _grid(tiles: list[U8], cols: int, gap: int = 6) -> U8:
    h, w = tiles[0].shape[:2]
    rows = math.ceil(len(tiles) / cols)
    out = np.full((rows * h + (rows + 1) * gap, cols * w + (cols + 1) * gap, 3), _BG, dtype=np.uint8)
    for k, t in enumerate(tiles):
        r, c = divmod(k, cols)
        y, x = gap + r * (h + gap), gap + c * (w + gap)
        out[y : y + h, x : x + w] = t
    return out


def _banner(text: str, width: int) -> U8:
    bar = np.full((26, width, 3), _BG, dtype=np.uint8)
    return _label(bar, [text])


def contact_sheet(world: World, out: Path, presets: list[str] | None = None) -> Path:
    """Render the contact sheet of ``world`` into ``out`` (PNG); returns the path."""
    from PIL import Image  # noqa: PLC0415

    names = presets or environment_presets()
    renderer = Renderer(world)
    try:
        top = _grid(_preset_tiles(world, renderer, names), cols=4)
        rows, _ = _closeup_tiles(world, renderer)
    finally:
        renderer.close()
    # close-ups: one column per subject, one row per range
    by_range = [rows[s][r] for r in range(len(_RANGES_M)) for s in range(len(rows))]
    bottom = _grid(by_range, cols=len(rows))
    width = max(top.shape[1], bottom.shape[1])

    def pad(img: U8) -> U8:
        canvas = np.full((img.shape[0], width, 3), _BG, dtype=np.uint8)
        canvas[:, : img.shape[1]] = img
        return canvas

    title = f"world {world.config.name} (seed {world.config.seed}): one view under each environment preset"
    closeups = (
        "what the 640x480, 90 deg camera sees of each pose and vehicle at 12 (detail), 30, 60 and 100 m "
        "(clear_noon's camera at 9:30 solar time; camera pixels enlarged)"
    )
    sheet = np.concatenate([pad(_banner(title, width)), pad(top), pad(_banner(closeups, width)), pad(bottom)])
    out.parent.mkdir(parents=True, exist_ok=True)
    Image.fromarray(sheet).save(out)
    return out

"""Per-frame labelling from a rendered instance-id image and the objects' geometry (pure numpy).

Two steps, because the second needs the renderer in between:

1. :func:`visible_instances`: every instance of a labelled class with at least ``min_visible_pixels``
   pixels in the instance-id image, with its pixels (rows, columns) and tight box;
2. the caller asks the renderer how many pixels each would cover with nothing in front of it
   (``Renderer.unoccluded_pixel_counts``), then :func:`label_instances` computes every attribute and
   applies the remaining filters.

Nothing here knows how an object is shaped: an object is its instance id in the image, its class,
and its 3D box (base centre, size, yaw) at the frame's instant, so new geometry and moving objects
label the same way.
"""

from __future__ import annotations

import math
from collections.abc import Callable, Mapping
from dataclasses import dataclass
from typing import Any

import numpy as np
import numpy.typing as npt

from uav_datasets.core import rle
from uav_datasets.core.config import LabelSpec
from uav_datasets.core.records import InstanceLabel
from uav_sim_bridge.core.camera import CameraModel
from uav_sim_bridge.core.objects import WorldObject
from uav_sim_bridge.core.transforms import RigidTransform

__all__ = [
    "BOX_EDGES",
    "Candidate",
    "FrameGeometry",
    "box_corners",
    "frame_geometry",
    "label_instances",
    "project_box",
    "visible_instances",
]

FloatArray = npt.NDArray[np.float64]

#: The 12 edges of a box whose corners are ordered as :func:`box_corners` returns them.
BOX_EDGES = ((0, 1), (1, 2), (2, 3), (3, 0), (4, 5), (5, 6), (6, 7), (7, 4), (0, 4), (1, 5), (2, 6), (3, 7))


@dataclass(frozen=True)
class FrameGeometry:
    """Where a frame's camera is: height above the terrain, pitch and yaw of its view (see ``docs/datasets.md``)."""

    altitude_agl_m: float
    pitch_deg: float
    yaw_deg: float


def frame_geometry(t_map_optical: RigidTransform, terrain_z_m: float) -> FrameGeometry:
    """The camera's height above ``terrain_z_m`` (the terrain under it), its pitch and its yaw.

    Pitch is the depression of the optical axis below the horizon (90 = nadir, 0 = level, negative =
    looking up). Yaw is the heading of the optical axis projected on the ground, counter-clockwise from
    east in [0, 360); for a nadir view (no horizontal component) it is the heading of the image's up
    direction.
    """
    rot = t_map_optical.rotation
    axis = rot[:, 2]
    pitch = math.degrees(math.atan2(-float(axis[2]), float(np.hypot(axis[0], axis[1]))))
    horizontal = axis[:2] if float(np.hypot(axis[0], axis[1])) > 1e-6 else -rot[:2, 1]
    yaw = math.degrees(math.atan2(float(horizontal[1]), float(horizontal[0]))) % 360.0
    return FrameGeometry(float(t_map_optical.translation_m[2]) - terrain_z_m, pitch, yaw)


@dataclass(frozen=True)
class Candidate:
    """An instance seen in a frame: its visible pixels and their tight box (inclusive pixel indices)."""

    instance_id: int
    rows: npt.NDArray[np.int64]
    cols: npt.NDArray[np.int64]
    x_min: int
    y_min: int
    x_max: int
    y_max: int

    @property
    def visible_pixels(self) -> int:
        return int(self.rows.size)


def visible_instances(
    instance_id: npt.NDArray[np.integer[Any]], labelled: npt.NDArray[np.bool_], min_pixels: int
) -> dict[int, Candidate]:
    """Instances with ``labelled[iid]`` true and at least ``min_pixels`` pixels in ``instance_id``.

    Args:
        instance_id: ``(H, W)`` world instance ids (0 = sky).
        labelled: lookup table over instance ids: whether the id's class is labelled. Ids beyond it are not.
        min_pixels: smallest visible pixel count kept.
    """
    ids = np.asarray(instance_id)
    lut = np.zeros(max(int(ids.max(initial=0)) + 1, len(labelled)), dtype=bool)
    lut[: len(labelled)] = labelled
    flat = ids.ravel()
    where = np.flatnonzero(np.take(lut, flat))  # ~10x faster than np.nonzero of the 2-D mask
    if not len(where):
        return {}
    hit = flat[where].astype(np.int64)
    order = np.argsort(hit, kind="stable")
    hit, where = hit[order], where[order]
    rows, cols = np.divmod(where, ids.shape[1])
    uniq, first, counts = np.unique(hit, return_index=True, return_counts=True)
    out: dict[int, Candidate] = {}
    for iid, a, n in zip(uniq.tolist(), first.tolist(), counts.tolist(), strict=True):
        if n < min_pixels:
            continue
        r = rows[a : a + n]
        c = cols[a : a + n]
        out[int(iid)] = Candidate(int(iid), r, c, int(c.min()), int(r.min()), int(c.max()), int(r.max()))
    return out


def box_corners(obj: WorldObject) -> FloatArray:
    """``(8, 3)`` corners of an object's 3D box in ``map``: bottom face, then top face."""
    length, width, height = obj.size_m
    local = np.array(
        [[sx * length / 2, sy * width / 2, z] for z in (0.0, height) for sx, sy in ((-1, -1), (1, -1), (1, 1), (-1, 1))]
    )
    return obj.pose.to_world(local)


def project_box(
    corners_map: FloatArray, camera: CameraModel, t_optical_map: RigidTransform
) -> tuple[float, float, float, float] | None:
    """Pixel-edge extent ``(x0, y0, x1, y1)`` of a 3D box's projection, the box clipped at the near plane.

    Pixel column ``c`` spans ``[c, c + 1)``, so a projected point ``(u, v)`` (OpenCV: pixel centres at
    integers) is at ``(u + 0.5, v + 0.5)``. Returns None when the whole box is nearer than ``near_m``
    (behind the camera included).
    """
    p = t_optical_map.apply(corners_map)
    near = camera.near_m
    pts = [p[i] for i in range(8) if p[i, 2] >= near]
    for a, b in BOX_EDGES:
        za, zb = p[a, 2], p[b, 2]
        if (za - near) * (zb - near) < 0:
            t = (near - za) / (zb - za)
            pts.append(p[a] + t * (p[b] - p[a]))
    if not pts:
        return None
    q = np.asarray(pts)
    u = camera.fx * q[:, 0] / q[:, 2] + camera.cx + 0.5
    v = camera.fy * q[:, 1] / q[:, 2] + camera.cy + 0.5
    return float(u.min()), float(v.min()), float(u.max()), float(v.max())


def _wrap(angle: float) -> float:
    return (angle + math.pi) % (2 * math.pi) - math.pi


def label_instances(
    candidates: Mapping[int, Candidate],
    *,
    objects: Mapping[int, WorldObject],
    unoccluded_pixels: Mapping[int, int],
    camera: CameraModel,
    t_map_optical: RigidTransform,
    terrain_height: Callable[[float, float], float],
    spec: LabelSpec,
) -> list[InstanceLabel]:
    """Labels of the candidates that pass ``spec``'s filters, sorted by instance id.

    Args:
        candidates: from :func:`visible_instances` (already at least ``spec.min_visible_pixels``).
        objects: every candidate's object at the frame's instant (pose and size).
        unoccluded_pixels: pixels each candidate would cover in this frame with nothing in front of it.
        camera, t_map_optical: the frame's camera and its pose.
        terrain_height: terrain height at ``(x, y)`` in ``map``.
        spec: class list and filters.
    """
    h, w = camera.height, camera.width
    t_optical_map = t_map_optical.inverse()
    eye = t_map_optical.translation_m
    classes = {c.label: c for c in spec.class_list}
    out: list[InstanceLabel] = []
    for iid in sorted(candidates):
        cand = candidates[iid]
        obj = objects[iid]
        if obj.object_class.label not in classes:
            continue
        visible = cand.visible_pixels
        alone = int(unoccluded_pixels.get(iid, visible))
        # The renderer draws the object alone; rasterisation is the same, so alone >= visible. Guard anyway.
        fraction = min(1.0, visible / alone) if alone > 0 else 1.0
        if fraction < spec.min_visible_fraction:
            continue
        centre = obj.center_m
        range_m = float(np.linalg.norm(centre - eye))
        if spec.max_range_m is not None and range_m > spec.max_range_m:
            continue
        corners = box_corners(obj)
        extent = project_box(corners, camera, t_optical_map)
        if extent is None:  # cannot be visible; guard against a box that does not enclose its mesh
            extent = (float(cand.x_min), float(cand.y_min), float(cand.x_max + 1), float(cand.y_max + 1))
        x0, y0, x1, y1 = extent
        full_area = max(0.0, x1 - x0) * max(0.0, y1 - y0)
        cx0, cy0, cx1, cy1 = max(0.0, x0), max(0.0, y0), min(float(w), x1), min(float(h), y1)
        inside = max(0.0, cx1 - cx0) * max(0.0, cy1 - cy0)
        truncation = 1.0 - inside / full_area if full_area > 0 else 0.0
        base = np.asarray(obj.pose.position_m, dtype=np.float64)
        ground = float(terrain_height(float(base[0]), float(base[1])))
        horizontal = float(np.hypot(eye[0] - centre[0], eye[1] - centre[1]))
        view_angle = math.degrees(math.atan2(float(eye[2] - centre[2]), horizontal))
        loc = t_optical_map.apply(base)
        heading = t_optical_map.rotation @ np.array([math.cos(obj.pose.yaw_rad), math.sin(obj.pose.yaw_rad), 0.0])
        rot_y = math.atan2(-float(heading[2]), float(heading[0]))
        alpha = _wrap(rot_y - math.atan2(float(loc[0]), float(loc[2])))
        out.append(
            InstanceLabel(
                instance_id=iid,
                track_id=iid,
                class_name=obj.object_class.label,
                class_id=int(obj.object_class),
                object_name=obj.name,
                bbox=(cand.x_min, cand.y_min, cand.x_max - cand.x_min + 1, cand.y_max - cand.y_min + 1),
                bbox_loose=(cx0, cy0, max(0.0, cx1 - cx0), max(0.0, cy1 - cy0)),
                segmentation=rle.encode_pixels(cand.rows, cand.cols, h, w),
                area=visible,
                unoccluded_pixels=alone,
                visible_fraction=fraction,
                truncation=truncation,
                range_m=range_m,
                height_above_ground_m=float(base[2]) - ground,
                camera_height_m=float(eye[2] - base[2]),
                view_angle_deg=view_angle,
                box3d_position_m=(float(base[0]), float(base[1]), float(base[2])),
                box3d_size_m=(float(obj.size_m[0]), float(obj.size_m[1]), float(obj.size_m[2])),
                box3d_yaw_rad=float(obj.pose.yaw_rad),
                location_camera_m=(float(loc[0]), float(loc[1]), float(loc[2])),
                rotation_y_rad=rot_y,
                alpha_rad=alpha,
            )
        )
    return out

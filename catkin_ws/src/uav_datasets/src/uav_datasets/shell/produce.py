"""Making one frame: pose, render, labels and files (the renderer and the writers around the pure core).

A :class:`FrameProducer` owns one world's renderer (an EGL context bound to the creating thread: make
it in the thread, and the process, that uses it). For each :class:`~uav_datasets.core.plan.FramePlan`
it draws the viewpoint (or takes the flight's pose), moves the objects that are not at their
generated poses, renders colour, depth and instance ids once, labels the instances and returns the
images and label texts for a writer (``shell.encoder``), which encodes and writes them while the next
frame renders.
"""

from __future__ import annotations

from pathlib import Path

import numpy as np

from uav_datasets.core.config import DatasetConfig
from uav_datasets.core.formats import kitti_calib, kitti_lines, yolo_lines
from uav_datasets.core.labels import frame_geometry, label_instances, visible_instances
from uav_datasets.core.plan import FramePlan
from uav_datasets.core.records import FrameRecord
from uav_datasets.core.sampling import ViewpointSampler, frame_rng
from uav_datasets.shell.encoder import FramePayload
from uav_sim_bridge.core.camera import CameraModel
from uav_sim_bridge.core.objects import ObjectPose, WorldObject
from uav_sim_bridge.core.world import World
from uav_sim_bridge.render import Renderer

__all__ = ["FrameProducer", "frame_files"]


def frame_files(cfg: DatasetConfig, split: str, name: str) -> dict[str, str]:
    """Relative paths of a frame's files, by kind (only the kinds the config writes)."""
    out = cfg.outputs
    files: dict[str, str] = {}
    if out.images != "none":
        files["image"] = f"images/{split}/{name}.{out.images}"
    if out.depth != "none":
        files["depth"] = f"depth/{split}/{name}.{'tiff' if out.depth == 'float32' else 'png'}"
    if out.instance_masks:
        files["instance_mask"] = f"masks/instance/{split}/{name}.png"
    if out.class_masks:
        files["class_mask"] = f"masks/class/{split}/{name}.png"
    if out.yolo:
        files["yolo"] = f"labels/{split}/{name}.txt"
    if out.kitti:
        files["kitti"] = f"kitti/{split}/label_2/{name}.txt"
        files["calib"] = f"kitti/{split}/calib/{name}.txt"
    return files


class FrameProducer:
    """Frames of one world (see the module docstring).

    Args:
        world: the world; ``world_seed`` is the seed it was generated with.
        cfg: the dataset config.
        camera: the camera every frame is rendered with.
        out_dir: the dataset folder.
    """

    def __init__(
        self,
        world: World,
        world_seed: int,
        cfg: DatasetConfig,
        camera: CameraModel,
        out_dir: Path,
    ) -> None:
        self.world = world
        self.world_seed = world_seed
        self.cfg = cfg
        self.camera = camera
        self.out_dir = out_dir
        classes = set(cfg.labels.class_list)
        lut = np.zeros(len(world.objects) + 1, dtype=bool)
        for obj in world.objects:
            lut[obj.instance_id] = obj.object_class in classes
        self.labelled = lut
        self.class_lut = np.asarray(world.instance_class, dtype=np.uint16)
        self.class_index = {c: k for k, c in enumerate(cfg.labels.classes)}
        self.sampler = (
            ViewpointSampler(
                world,
                cfg.viewpoints,
                camera,
                cfg.labels.class_list,
                max_range_m=cfg.labels.max_range_m,
                where=f"world seed {world_seed} ({world.config.name})",
            )
            if cfg.source == "viewpoints"
            else None
        )
        self.renderer = Renderer(world)
        self._moved: dict[int, WorldObject] = {}

    def close(self) -> None:
        self.renderer.close()

    def _place_objects(self, poses: tuple[tuple[int, ObjectPose], ...]) -> None:
        wanted = dict(poses)
        for iid in [i for i in self._moved if i not in wanted]:  # back to where the world put it
            self.renderer.set_object_pose(iid, self.world.object(iid).pose)
            del self._moved[iid]
        for iid, pose in wanted.items():
            current = self._moved.get(iid)
            if current is None or current.pose != pose:
                self.renderer.set_object_pose(iid, pose)
                o = self.world.object(iid)
                self._moved[iid] = WorldObject(o.instance_id, o.object_class, o.name, pose, o.size_m)

    def _object(self, iid: int) -> WorldObject:
        return self._moved.get(iid) or self.world.object(iid)

    def make(self, plan: FramePlan) -> tuple[FrameRecord, FramePayload]:
        """Render and label one frame; returns its record and its files to write (images and label texts)."""
        cfg = self.cfg
        cam = self.camera
        attempts, mode = 1, "flight"
        if plan.t_map_optical is not None:
            pose = plan.t_map_optical
        else:
            assert self.sampler is not None  # a plan without a pose is a sampled viewpoint
            vp = self.sampler.sample(frame_rng(cfg.seed, plan.world_seed, plan.index))
            pose, attempts, mode = vp.t_map_optical, vp.attempts, vp.mode
        self._place_objects(plan.object_poses)
        frame = self.renderer.render(cam, pose)
        cands = visible_instances(frame.instance_id, self.labelled, cfg.labels.min_visible_pixels)
        alone = self.renderer.unoccluded_pixel_counts(cam, pose, sorted(cands)) if cands else {}
        labels = label_instances(
            cands,
            objects={iid: self._object(iid) for iid in cands},
            unoccluded_pixels=alone,
            camera=cam,
            t_map_optical=pose,
            terrain_height=lambda x, y: float(self.world.height_at(x, y)),
            spec=cfg.labels,
        )
        eye = pose.translation_m
        geo = frame_geometry(pose, float(self.world.height_at(float(eye[0]), float(eye[1]))))
        files = frame_files(cfg, plan.split, plan.name)
        rec = FrameRecord(
            index=plan.index,
            name=plan.name,
            split=plan.split,
            world_seed=self.world_seed,
            world_name=self.world.config.name,
            world_hash=self.world.hash,
            sequence=plan.sequence,
            sequence_frame=plan.sequence_frame,
            timestamp_s=plan.timestamp_s,
            width=cam.width,
            height=cam.height,
            fx=cam.fx,
            fy=cam.fy,
            cx=cam.cx,
            cy=cam.cy,
            t_map_camera=tuple(tuple(float(v) for v in row) for row in pose.matrix()),
            altitude_agl_m=geo.altitude_agl_m,
            pitch_deg=geo.pitch_deg,
            yaw_deg=geo.yaw_deg,
            files=files,
            labels=tuple(labels),
            attempts=attempts,
            position_mode=mode,
        )
        out = cfg.outputs
        texts: list[tuple[str, str]] = []
        if "yolo" in files:
            texts.append((files["yolo"], yolo_lines(labels, self.class_index, cam.width, cam.height)))
        if "kitti" in files:
            texts.append((files["kitti"], kitti_lines(labels)))
            texts.append((files["calib"], kitti_calib(rec)))
        payload = FramePayload(
            key=plan.index,
            color=frame.color_rgb,
            depth=frame.depth_m,
            ids=frame.instance_id,
            image=files.get("image", ""),
            depth_file=files.get("depth", ""),
            instance_file=files.get("instance_mask", ""),
            class_file=files.get("class_mask", ""),
            image_format=out.images,
            jpeg_quality=out.jpeg_quality,
            depth_format=out.depth,
            lut_key=self.world_seed,
            texts=tuple(texts),
            png_level=0 if out.png_compression == "none" else 1,
        )
        return rec, payload

"""Headless OpenGL renderer (moderngl + EGL): color, z-depth and instance ids in one pass.

Usage (no ROS needed)::

    from uav_sim_bridge.render import Renderer
    from uav_sim_bridge.core.camera import CameraModel, look_at

    renderer = Renderer(world)                       # creates an EGL context in *this* thread
    cam = CameraModel.simple(640, 480, 90.0)
    frame = renderer.render(cam, look_at([0, 0, 50], [0, 0, 0]))
    frame.color_rgb, frame.depth_m, frame.instance_id

Threading and processes: the GL context belongs to the thread that created the
renderer; calling it from another thread raises :class:`RenderError`.  Never
``fork`` a process that has created a renderer (use the ``spawn`` start method).

Speed: static triangles are sorted into square tiles; each frame a vectorised
frustum test picks the tiles to draw and tiles beyond ``lod_distance_m`` draw the
low-detail tree crowns instead of the full ones (indirect draw calls, front to back).
Only the tiles that touch the landing pad use the shader variant that paints it, and
the sky pass runs only when some pixel has no surface (a nadir camera rarely sees sky).
People and vehicles live in a small dynamic buffer so they can be moved.
"""

from __future__ import annotations

import itertools
import math
import threading
from dataclasses import dataclass
from typing import Any

import numpy as np
import numpy.typing as npt

from uav_sim_bridge.core.camera import CameraModel
from uav_sim_bridge.core.generator import TERRAIN_INSTANCE_ID
from uav_sim_bridge.core.mesh import LOD_ALWAYS, LOD_FAR, LOD_NEAR
from uav_sim_bridge.core.objects import ObjectPose
from uav_sim_bridge.core.render_settings import RenderSettings
from uav_sim_bridge.core.transforms import RigidTransform
from uav_sim_bridge.core.world import World
from uav_sim_bridge.errors import RenderError
from uav_sim_bridge.render import shaders

__all__ = ["RenderSettings", "RenderedFrame", "Renderer", "gl_projection", "gl_view"]


@dataclass(frozen=True)
class RenderedFrame:
    """One camera image set; all arrays are ``(H, W, ...)`` with row 0 at the top.

    Attributes:
        color_rgb: uint8 RGB.
        depth_m: float32 z-depth along the optical axis in metres, NaN where nothing was hit.
        instance_id: uint16 world instance id, 0 for the sky.
    """

    color_rgb: npt.NDArray[np.uint8]
    depth_m: npt.NDArray[np.float32]
    instance_id: npt.NDArray[np.uint16]


def gl_projection(camera: CameraModel) -> npt.NDArray[np.float64]:
    """OpenGL projection matrix reproducing the OpenCV intrinsics (pixel centres at integers)."""
    w, h = camera.width, camera.height
    near, far = camera.near_m, camera.far_m
    p = np.zeros((4, 4))
    p[0, 0] = 2.0 * camera.fx / w
    p[0, 2] = 1.0 - 2.0 * (camera.cx + 0.5) / w
    p[1, 1] = 2.0 * camera.fy / h
    p[1, 2] = 2.0 * (camera.cy + 0.5) / h - 1.0
    p[2, 2] = -(far + near) / (far - near)
    p[2, 3] = -2.0 * far * near / (far - near)
    p[3, 2] = -1.0
    return p


def gl_view(t_map_optical: RigidTransform) -> npt.NDArray[np.float64]:
    """OpenGL view matrix (eye: x right, y up, z back) of an optical-frame pose in ``map``."""
    r = np.diag([1.0, -1.0, -1.0]) @ t_map_optical.rotation.T
    v = np.eye(4)
    v[:3, :3] = r
    v[:3, 3] = -r @ t_map_optical.translation_m
    return v


class _Target:
    """Framebuffer and readback buffers of one image size."""

    def __init__(self, ctx: Any, width: int, height: int) -> None:
        self.color = ctx.renderbuffer((width, height), 4, dtype="f1")
        self.depth = ctx.renderbuffer((width, height), 1, dtype="f4")
        self.inst = ctx.renderbuffer((width, height), 1, dtype="u4")
        self.zbuf = ctx.depth_renderbuffer((width, height))
        self.fbo = ctx.framebuffer([self.color, self.depth, self.inst], self.zbuf)
        self.fbo_inst = ctx.framebuffer([self.inst], self.zbuf)  # instance-only pass
        self.buf_color = np.empty((height, width, 3), np.uint8)
        self.buf_depth = np.empty((height, width), np.float32)
        self.buf_inst = np.empty((height, width), np.uint32)

    def release(self) -> None:
        for obj in (self.fbo, self.fbo_inst, self.color, self.depth, self.inst, self.zbuf):
            obj.release()


class Renderer:
    """Renders :class:`RenderedFrame` s of a :class:`World` (see module docstring).

    Args:
        world: the world to draw.
        settings: look and speed knobs.

    Raises:
        RenderError: no usable EGL/OpenGL 3.3 context.
    """

    def __init__(self, world: World, settings: RenderSettings | None = None) -> None:
        import moderngl  # noqa: PLC0415  (GL is optional for the pure core)

        self._mgl: Any = moderngl  # moderngl's stubs are partial; GL objects are handled as Any
        self.world = world
        self.settings = settings or RenderSettings()
        self._thread = threading.get_ident()
        try:
            self.ctx: Any = self._mgl.create_context(standalone=True, backend="egl")
        except Exception as err:  # glcontext raises bare Exceptions
            msg = (
                f"cannot create a headless EGL OpenGL context: {err}. Install libegl1 and libgl1 "
                "(Mesa), and check GLCONTEXT_DEVICE_INDEX on machines with several GPUs."
            )
            raise RenderError(msg) from err
        self.gl_renderer = str(self.ctx.info.get("GL_RENDERER", "unknown"))
        self._targets: dict[tuple[int, int], _Target] = {}
        self._queries: list[Any] = []  # occlusion queries of unoccluded_pixel_counts, reused
        self._static_alone_vao: Any = None  # static objects drawn alone (unoccluded_pixel_counts), built lazily
        self._static_alone_ranges: dict[int, tuple[int, int]] = {}
        self._build_programs()
        self._upload_static()
        self._upload_dynamic()
        self.last_triangles = 0

    # ------------------------------------------------------------------ setup
    def _build_programs(self) -> None:
        ctx = self.ctx
        s = self.settings
        self.prog: Any = ctx.program(vertex_shader=shaders.MAIN_VS, fragment_shader=shaders.MAIN_FS)
        pad_fs = shaders.with_defines(shaders.MAIN_FS, "PAD")
        self.prog_pad: Any = ctx.program(vertex_shader=shaders.MAIN_VS, fragment_shader=pad_fs)
        self.sky: Any = ctx.program(vertex_shader=shaders.SKY_VS, fragment_shader=shaders.SKY_FS)
        sun = s.sun_direction
        haze = (0.74, 0.80, 0.88)
        for prog in (self.prog, self.prog_pad):
            prog["u_sun"].value = sun
            prog["u_texture_gain"].value = s.texture_gain
            prog["u_haze_m"].value = s.haze_distance_m
            prog["u_haze_color"].value = haze
        self.prog_pad["u_pad_half_m"].value = s.pad_half_size_m
        self.prog_pad["u_pad_instance"].value = TERRAIN_INSTANCE_ID
        self.sky["u_sun"].value = sun
        self.sky["u_haze_color"].value = haze
        tri = ctx.buffer(np.array([-1, -1, 3, -1, -1, 3], dtype="f4").tobytes())
        self.sky_vao = ctx.vertex_array(self.sky, [(tri, "2f", "in_xy")])
        self.iprog: Any = ctx.program(vertex_shader=shaders.INSTANCE_VS, fragment_shader=shaders.INSTANCE_FS)

    def _vertex_bytes(self, verts: npt.NDArray[np.float32], normals: npt.NDArray[np.float32],
                      colors: npt.NDArray[np.float32], inst: npt.NDArray[np.uint32]) -> bytes:  # fmt: skip
        rec = np.empty(len(verts), dtype=[("p", "<f4", 3), ("n", "<f4", 3), ("c", "<f4", 3), ("i", "<u4")])
        rec["p"], rec["n"], rec["c"], rec["i"] = verts, normals, colors, inst
        return rec.tobytes()

    def _shaded_vao(self, prog: Any, vbo: Any, ibo: Any) -> Any:
        return self.ctx.vertex_array(prog, [(vbo, "3f 3f 3f 1u", "in_pos", "in_nrm", "in_col", "in_inst")], ibo)

    def _make_vaos(self, vbo: Any, ibo: Any) -> tuple[Any, Any]:
        """(shaded, instance-only) vertex arrays over one vertex buffer."""
        instance = self.ctx.vertex_array(self.iprog, [(vbo, "3f 24x 1u", "in_pos", "in_inst")], ibo)
        return self._shaded_vao(self.prog, vbo, ibo), instance

    def _upload_static(self) -> None:
        w = self.world
        m = w.mesh
        cls = w.instance_class[w.face_instance]
        dynamic = np.isin(cls, [5, 6])  # person, vehicle
        faces = m.faces[~dynamic]
        lod = m.face_lod[~dynamic]
        tris = m.vertices_m[faces]  # (F, 3, 3)
        centroid = tris.mean(axis=1)
        x_min, y_min, x_max, y_max = w.terrain.bounds_m
        ts = self.settings.tile_size_m
        nx = max(1, math.ceil((x_max - x_min) / ts))
        ny = max(1, math.ceil((y_max - y_min) / ts))
        tx = np.clip(((centroid[:, 0] - x_min) / ts).astype(np.int64), 0, nx - 1)
        ty = np.clip(((centroid[:, 1] - y_min) / ts).astype(np.int64), 0, ny - 1)
        tile = ty * nx + tx
        # Within a tile: NEAR, ALWAYS, FAR, so near = [NEAR+ALWAYS] and far = [ALWAYS+FAR] are contiguous.
        rank = np.select([lod == LOD_NEAR, lod == LOD_ALWAYS, lod == LOD_FAR], [0, 1, 2])
        order = np.lexsort((rank, tile))
        faces, tile, rank, tris = faces[order], tile[order], rank[order], tris[order]
        n_tiles = nx * ny
        key = tile * 3 + rank
        bounds = np.searchsorted(key, np.arange(n_tiles * 3 + 1))
        starts = bounds[:-1].reshape(n_tiles, 3)
        ends = bounds[1:].reshape(n_tiles, 3)
        self._near_first = starts[:, 0] * 3
        self._near_count = (ends[:, 1] - starts[:, 0]) * 3
        self._far_first = starts[:, 1] * 3
        self._far_count = (ends[:, 2] - starts[:, 1]) * 3
        lo = np.full((n_tiles, 3), np.inf)
        hi = np.full((n_tiles, 3), -np.inf)
        flat = tris.reshape(-1, 3)
        tile_v = np.repeat(tile, 3)
        np.minimum.at(lo, tile_v, flat)
        np.maximum.at(hi, tile_v, flat)
        empty = ~np.isfinite(lo[:, 0])
        lo[empty] = 0.0
        hi[empty] = 0.0
        self._tile_center = (lo + hi) / 2.0
        self._tile_extent = (hi - lo) / 2.0
        self._tile_nonempty = ~empty
        # Tiles whose box reaches into the landing pad's square around home (drawn with the PAD shader).
        half = self.settings.pad_half_size_m
        self._tile_pad = np.all(np.abs(self._tile_center[:, :2]) - self._tile_extent[:, :2] <= half, axis=1)
        self.static_triangles = len(faces)
        ctx = self.ctx
        self._static_vbo = ctx.buffer(self._vertex_bytes(m.vertices_m, m.normals, m.colors, m.vertex_instance))
        self._static_ibo = ctx.buffer(faces.astype("<u4").tobytes())
        self._static_vao, self._static_ivao = self._make_vaos(self._static_vbo, self._static_ibo)
        self._static_pad_vao = self._shaded_vao(self.prog_pad, self._static_vbo, self._static_ibo)
        self._indirect = ctx.buffer(reserve=max(1, n_tiles) * 20, dynamic=True)

    def _upload_dynamic(self) -> None:
        """People and vehicles: their own vertex buffer, re-posed by :meth:`set_object_pose`."""
        w = self.world
        m = w.mesh
        cls = w.instance_class[w.face_instance]
        dyn_mask = np.isin(cls, [5, 6])
        order = np.argsort(w.face_instance[dyn_mask], kind="stable")
        dyn_faces = m.faces[dyn_mask][order]
        dyn_face_ids = w.face_instance[dyn_mask][order]
        used, inverse = np.unique(dyn_faces, return_inverse=True)
        ids_sorted, first = np.unique(dyn_face_ids, return_index=True)
        counts = np.diff(np.append(first, len(dyn_face_ids)))
        # index range (first index, index count) of each person/vehicle in the dynamic IBO
        self._dyn_ranges = {int(i): (int(f) * 3, int(c) * 3) for i, f, c in zip(ids_sorted, first, counts, strict=True)}
        self._dyn_inst = m.vertex_instance[used]
        self._dyn_normals_local = np.zeros((len(used), 3), np.float32)
        self._dyn_local = np.zeros((len(used), 3), np.float64)
        self._dyn_world = m.vertices_m[used].astype(np.float32)
        self._dyn_normals = m.normals[used].astype(np.float32)
        self._dyn_colors = m.colors[used]
        self._poses: dict[int, ObjectPose] = {}
        self._dyn_slices: dict[int, npt.NDArray[np.int64]] = {}
        for iid in np.unique(self._dyn_inst):
            obj = w.object(int(iid))
            sel = np.flatnonzero(self._dyn_inst == iid)
            self._dyn_slices[int(iid)] = sel
            self._poses[int(iid)] = obj.pose
            self._dyn_local[sel] = obj.pose.to_local(self._dyn_world[sel])
            self._dyn_normals_local[sel] = self._dyn_normals[sel] @ obj.pose.rotation()
        self.dynamic_triangles = len(dyn_faces)
        ctx = self.ctx
        data = self._vertex_bytes(self._dyn_world, self._dyn_normals, self._dyn_colors, self._dyn_inst)
        self._dyn_vbo = ctx.buffer(data if data else b"\0" * 40, dynamic=True)
        ibo = inverse.reshape(-1).astype("<u4").tobytes()
        self._dyn_ibo = ctx.buffer(ibo if ibo else b"\0" * 12)
        self._dyn_vao, self._dyn_ivao = self._make_vaos(self._dyn_vbo, self._dyn_ibo)
        self._dyn_dirty = False

    # ------------------------------------------------------------------ dynamic objects
    def object_pose(self, instance_id: int) -> ObjectPose:
        """Current pose of a person or vehicle."""
        return self._poses[instance_id]

    def set_object_pose(self, instance_id: int, pose: ObjectPose) -> None:
        """Move a person or vehicle (takes effect at the next render).

        Raises:
            KeyError: the instance is not a person or vehicle of this world.
        """
        if instance_id not in self._dyn_slices:
            msg = f"instance {instance_id} is not a movable object (person or vehicle) of this world"
            raise KeyError(msg)
        sel = self._dyn_slices[instance_id]
        self._dyn_world[sel] = pose.to_world(self._dyn_local[sel]).astype(np.float32)
        self._dyn_normals[sel] = (self._dyn_normals_local[sel] @ pose.rotation().T).astype(np.float32)
        self._poses[instance_id] = pose
        self._dyn_dirty = True

    # ------------------------------------------------------------------ rendering
    def _check_thread(self) -> None:
        if threading.get_ident() != self._thread:
            msg = "the renderer was created in another thread; GL contexts are bound to their thread"
            raise RenderError(msg)

    def _target(self, width: int, height: int) -> _Target:
        key = (width, height)
        if key not in self._targets:
            self._targets[key] = _Target(self.ctx, width, height)
        return self._targets[key]

    def visible_tiles(self, camera: CameraModel, t_map_optical: RigidTransform) -> npt.NDArray[np.bool_]:
        """Tiles whose bounding box intersects the view frustum, far plane (z-depth ``far_m``) included."""
        # The far plane is a plane, not a sphere: a tile farther than far_m from the eye can still hold points
        # whose z-depth is within it (off the optical axis), and they are drawn.
        planes = camera.frustum_planes_optical()
        rot = t_map_optical.rotation
        eye = t_map_optical.translation_m
        normals_w = planes[:, :3] @ rot.T
        d_w = planes[:, 3] - normals_w @ eye
        # the most-inside corner of each box must be on the inner side of every plane
        dist = self._tile_center @ normals_w.T + d_w + self._tile_extent @ np.abs(normals_w).T
        inside = np.all(dist >= 0.0, axis=1)
        return np.asarray(inside & self._tile_nonempty, dtype=np.bool_)

    def _draw_commands(
        self, camera: CameraModel, t_map_optical: RigidTransform
    ) -> tuple[npt.NDArray[np.uint32], npt.NDArray[np.bool_]]:
        """Indirect draw commands of the visible tiles, front to back, and whether each tile touches the pad."""
        if self.settings.frustum_culling:
            vis = np.flatnonzero(self.visible_tiles(camera, t_map_optical))
        else:
            vis = np.flatnonzero(self._tile_nonempty)
        eye = t_map_optical.translation_m
        gap = np.maximum(np.abs(self._tile_center[vis] - eye) - self._tile_extent[vis], 0.0)
        far = np.linalg.norm(gap, axis=1) > self.settings.lod_distance_m
        order = np.argsort(np.linalg.norm(gap, axis=1), kind="stable")  # front to back: early-z
        vis, far = vis[order], far[order]
        first = np.where(far, self._far_first[vis], self._near_first[vis])
        count = np.where(far, self._far_count[vis], self._near_count[vis])
        keep = count > 0
        cmds = np.zeros((int(keep.sum()), 5), dtype=np.uint32)
        cmds[:, 0] = count[keep]
        cmds[:, 1] = 1
        cmds[:, 2] = first[keep]
        return cmds, self._tile_pad[vis[keep]]

    def _setup_camera(self, camera: CameraModel, t_map_optical: RigidTransform, *, shaded: bool) -> _Target:
        target = self._target(camera.width, camera.height)
        proj = gl_projection(camera)
        view = gl_view(t_map_optical)
        mvp = (proj @ view).T.astype("f4").tobytes()
        if shaded:
            view_bytes = view.T.astype("f4").tobytes()
            eye = tuple(float(v) for v in t_map_optical.translation_m)
            for prog in (self.prog, self.prog_pad):
                prog["u_mvp"].write(mvp)
                prog["u_view"].write(view_bytes)
                prog["u_eye"].value = eye
                prog["u_focal_px"].value = float(camera.fx)
        else:
            self.iprog["u_mvp"].write(mvp)
        fbo = target.fbo if shaded else target.fbo_inst
        fbo.use()
        self.ctx.enable(self._mgl.DEPTH_TEST | self._mgl.CULL_FACE)
        self.ctx.depth_func = "<"
        fbo.clear(0.0, 0.0, 0.0, 0.0, depth=1.0)
        if self._dyn_dirty:
            self._dyn_vbo.write(
                self._vertex_bytes(self._dyn_world, self._dyn_normals, self._dyn_colors, self._dyn_inst)
            )
            self._dyn_dirty = False
        return target

    def render(self, camera: CameraModel, t_map_optical: RigidTransform) -> RenderedFrame:
        """Render one camera at ``T_map_optical``.

        Raises:
            RenderError: called from a thread other than the creating one.
        """
        self._check_thread()
        with self.ctx:  # make this renderer's context current (several renderers may share a thread)
            return self._render(camera, t_map_optical)

    def _draw_scene(self, camera: CameraModel, t_map_optical: RigidTransform, *, shaded: bool) -> None:
        cmds, pad = self._draw_commands(camera, t_map_optical)
        if len(cmds):
            self._indirect.orphan(len(cmds) * 20)
            self._indirect.write(cmds.tobytes())
            if not shaded:
                self._static_ivao.render_indirect(self._indirect, mode=self._mgl.TRIANGLES, count=len(cmds))
            else:
                # Runs of tiles with and without the pad, in the front-to-back order (same result as one call).
                cuts = [0, *(np.flatnonzero(pad[1:] != pad[:-1]) + 1).tolist(), len(cmds)]
                for a, b in itertools.pairwise(cuts):
                    vao = self._static_pad_vao if pad[a] else self._static_vao
                    vao.render_indirect(self._indirect, mode=self._mgl.TRIANGLES, count=b - a, first=a)
        if self.dynamic_triangles:
            (self._dyn_vao if shaded else self._dyn_ivao).render(self._mgl.TRIANGLES)
        self.last_triangles = int(cmds[:, 0].sum() // 3) + self.dynamic_triangles if len(cmds) else 0

    def _render(self, camera: CameraModel, t_map_optical: RigidTransform) -> RenderedFrame:
        target = self._setup_camera(camera, t_map_optical, shaded=True)
        self._draw_scene(camera, t_map_optical, shaded=True)
        self.ctx.depth_func = "<="
        self.ctx.disable(self._mgl.CULL_FACE)
        self.sky["u_r_map_optical"].write(t_map_optical.rotation.T.astype("f4").tobytes())
        self.sky["u_k"].value = (camera.fx, camera.fy, camera.cx, camera.cy)
        self.sky["u_height"].value = float(camera.height)
        fbo = target.fbo
        fbo.read_into(target.buf_depth, attachment=1, components=1, dtype="f4", alignment=1)
        # A surface's z-depth is >= near_m > 0: the clear value 0 marks the pixels left for the sky. Most nadir
        # frames have none, and the full-screen sky pass would cost more than this check.
        if not target.buf_depth.all():
            self.sky_vao.render(self._mgl.TRIANGLES)
            fbo.read_into(target.buf_depth, attachment=1, components=1, dtype="f4", alignment=1)
        fbo.read_into(target.buf_color, attachment=0, components=3, dtype="f1", alignment=1)
        fbo.read_into(target.buf_inst, attachment=2, components=1, dtype="u4", alignment=1)
        return RenderedFrame(
            color_rgb=np.ascontiguousarray(target.buf_color[::-1]),
            depth_m=np.ascontiguousarray(target.buf_depth[::-1]),
            instance_id=target.buf_inst[::-1].astype(np.uint16),
        )

    def render_instances(self, camera: CameraModel, t_map_optical: RigidTransform) -> npt.NDArray[np.uint16]:
        """Only the instance-id image of :meth:`render` (0 where nothing was hit), unshaded.

        Several times cheaper than :meth:`render` when nothing else is consumed (ground-truth
        detections).  Pass a camera with a short ``far_m`` (e.g. the detection range plus the
        largest object) to skip the distant scene: nothing beyond it can hide what is nearer.

        Raises:
            RenderError: called from a thread other than the creating one.
        """
        self._check_thread()
        with self.ctx:
            target = self._setup_camera(camera, t_map_optical, shaded=False)
            # Where nothing is drawn the id stays the clear value, 0: Mesa clears an integer attachment with the
            # bit pattern of the float clear colour, and 0.0f is 0 (a full-screen pass did the same, ~1 ms more).
            self._draw_scene(camera, t_map_optical, shaded=False)
            target.fbo_inst.read_into(target.buf_inst, attachment=0, components=1, dtype="u4", alignment=1)
            return target.buf_inst[::-1].astype(np.uint16)

    def unoccluded_pixel_counts(
        self, camera: CameraModel, t_map_optical: RigidTransform, instance_ids: list[int]
    ) -> dict[int, int]:
        """Pixels each object would cover in the frame with nothing else drawn.

        Each object is drawn alone into a cleared depth buffer, twice: the first pass keeps its nearest
        surface at each pixel, the second counts (occlusion query) the fragments that are that surface, so
        each pixel counts once however many of the object's own faces overlap there (a person's head over
        its torso seen from above). Objects hidden by other people or vehicles count too. Comparing with
        the pixels visible in :meth:`render` gives visible fractions. People and vehicles are drawn at
        their current poses; static objects (buildings, trees, roads, custom objects) at full detail.

        Raises:
            KeyError: an id is not an object of this world (or is the terrain).
        """
        self._check_thread()
        with self.ctx:
            return self._unoccluded(camera, t_map_optical, instance_ids)

    def _static_alone(self) -> tuple[Any, dict[int, tuple[int, int]]]:
        """An instance-only vertex array of the static objects' full-detail faces sorted by instance, and each
        instance's (first index, index count) in it; built on first use (most runs never need it)."""
        if self._static_alone_vao is None:
            w = self.world
            cls = w.instance_class[w.face_instance]
            keep = ~np.isin(cls, [1, 5, 6]) & (w.mesh.face_lod != LOD_FAR)  # not terrain, person, vehicle
            ids = w.face_instance[keep]
            order = np.argsort(ids, kind="stable")
            ids = ids[order]
            uniq, first, counts = np.unique(ids, return_index=True, return_counts=True)
            self._static_alone_ranges = {
                int(i): (int(f) * 3, int(c) * 3) for i, f, c in zip(uniq, first, counts, strict=True)
            }
            faces = w.mesh.faces[keep][order].astype("<u4").tobytes()
            ibo = self.ctx.buffer(faces if faces else b"\0" * 12)
            self._static_alone_vao = self.ctx.vertex_array(
                self.iprog, [(self._static_vbo, "3f 24x 1u", "in_pos", "in_inst")], ibo
            )
        return self._static_alone_vao, self._static_alone_ranges

    def _unoccluded(
        self, camera: CameraModel, t_map_optical: RigidTransform, instance_ids: list[int]
    ) -> dict[int, int]:
        target = self._setup_camera(camera, t_map_optical, shaded=False)
        draws = []
        for iid in instance_ids:
            if iid in self._dyn_ranges:
                draws.append((self._dyn_ivao, *self._dyn_ranges[iid]))
                continue
            vao, ranges = self._static_alone()
            if iid not in ranges:
                msg = f"instance {iid} is not an object of this world that can be drawn alone"
                raise KeyError(msg)
            draws.append((vao, *ranges[iid]))
        # moderngl cannot release query objects: keep a pool and reuse it every frame.
        while len(self._queries) < len(instance_ids):
            self._queries.append(self.ctx.query(samples=True))
        for (vao, first, count), query in zip(draws, self._queries, strict=False):
            target.fbo_inst.clear(depth=1.0)
            self.ctx.depth_func = "<"
            vao.render(self._mgl.TRIANGLES, vertices=count, first=first)  # depth pre-pass: the nearest surface
            self.ctx.depth_func = "=="
            with query:
                vao.render(self._mgl.TRIANGLES, vertices=count, first=first)
        self.ctx.depth_func = "<"
        # Read the results only after every query was issued: each read waits for the GPU (llvmpipe) to finish.
        return {iid: int(q.samples) for iid, q in zip(instance_ids, self._queries, strict=False)}

    def close(self) -> None:
        """Release every GL object and the context."""
        with self.ctx:
            for t in self._targets.values():
                t.release()
            self._targets.clear()
        self.ctx.release()

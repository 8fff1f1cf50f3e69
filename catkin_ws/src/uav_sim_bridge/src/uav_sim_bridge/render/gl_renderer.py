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

import dataclasses
import itertools
import math
import threading
from collections.abc import Callable
from typing import Any

import numpy as np
import numpy.typing as npt

from uav_sim_bridge.core.camera import CameraModel
from uav_sim_bridge.core.generator import TERRAIN_INSTANCE_ID
from uav_sim_bridge.core.lighting import Lighting
from uav_sim_bridge.core.mesh import LOD_ALWAYS, LOD_FAR, LOD_NEAR
from uav_sim_bridge.core.objects import ObjectPose
from uav_sim_bridge.core.render_settings import RenderSettings
from uav_sim_bridge.core.shading import UnshadedColor
from uav_sim_bridge.core.transforms import RigidTransform
from uav_sim_bridge.core.world import World
from uav_sim_bridge.errors import RenderError
from uav_sim_bridge.render import shaders

__all__ = ["RenderSettings", "RenderedFrame", "Renderer", "gl_projection", "gl_view"]


class RenderedFrame:
    """One camera image set; all arrays are ``(H, W, ...)`` with row 0 at the top.

    Attributes:
        color_rgb: uint8 RGB. With shadows it is finished on first access (:class:`UnshadedColor`: the sun's share
            taken away where the shadow pass found shade, ~0.5 ms of OpenCV), so whoever reads it first does that
            work; the bridge has its camera-effects process do it (:attr:`unshaded`), beside the next render.
        depth_m: float32 z-depth along the optical axis in metres, NaN where nothing was hit.
        instance_id: uint16 world instance id, 0 for the sky.
    """

    __slots__ = ("_color", "_lock", "_shade", "_unshaded", "depth_m", "instance_id")

    def __init__(
        self,
        color_rgb: npt.NDArray[np.uint8] | None,
        depth_m: npt.NDArray[np.float32],
        instance_id: npt.NDArray[np.uint16],
        *,
        unshaded: UnshadedColor | None = None,
        shade: Callable[[], npt.NDArray[np.uint8]] | None = None,
    ) -> None:
        if color_rgb is None and unshaded is None and shade is None:
            msg = "a rendered frame needs its colour, its unshaded colour or the function that finishes it"
            raise ValueError(msg)
        self._color = color_rgb
        self._unshaded = unshaded if color_rgb is None else None
        self._shade = shade if color_rgb is None and unshaded is None else None
        self._lock = threading.Lock()
        self.depth_m = depth_m
        self.instance_id = instance_id

    @property
    def unshaded(self) -> UnshadedColor | None:
        """The colour before its shadows, while it is not finished yet (None once it is, or without shadows)."""
        return self._unshaded if self._color is None else None

    @property
    def color_rgb(self) -> npt.NDArray[np.uint8]:
        if self._color is None:
            with self._lock:
                if self._color is None:
                    if self._unshaded is not None:
                        self._color = self._unshaded.finish()
                    else:
                        assert self._shade is not None
                        self._color = self._shade()
                    self._unshaded = None
                    self._shade = None
        return self._color


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


def _set(prog: Any, name: str, value: Any) -> None:
    """Set a uniform if the program has it (the GLSL compiler drops unused ones)."""
    u = prog.get(name, None)
    if u is None:
        return
    if isinstance(value, bytes):
        u.write(value)
    else:
        u.value = value


class _Target:
    """Framebuffer and readback buffers of one image size."""

    def __init__(self, ctx: Any, width: int, height: int) -> None:
        self.color = ctx.renderbuffer((width, height), 4, dtype="f1")
        self.depth = ctx.texture((width, height), 1, dtype="f4")  # a texture: the shadow pass reads it
        self.depth.filter = (0x2600, 0x2600)  # GL_NEAREST
        self.inst = ctx.renderbuffer((width, height), 1, dtype="u4")
        self.zbuf = ctx.depth_renderbuffer((width, height))
        self.fbo = ctx.framebuffer([self.color, self.depth, self.inst], self.zbuf)
        self.fbo_inst = ctx.framebuffer([self.inst], self.zbuf)  # instance-only pass
        self.buf_color = np.empty((height, width, 3), np.uint8)
        self.buf_depth = np.empty((height, width), np.float32)
        self.buf_inst = np.empty((height, width), np.uint32)
        self.buf_alpha = np.empty((height, width, 4), np.uint8)

    def shadow_buffers(self, ctx: Any, step: int) -> None:
        """The lit-fraction buffer of the shadow pass: one pixel per ``step`` x ``step`` block."""
        if getattr(self, "shadow_step", None) == step:
            return
        width, height = self.buf_color.shape[1], self.buf_color.shape[0]
        hw, hh = (width + step - 1) // step, (height + step - 1) // step
        self.shadow_step = step
        self.lit = ctx.renderbuffer((hw, hh), 1, dtype="f1")
        self.fbo_lit = ctx.framebuffer([self.lit])
        self.buf_lit = np.empty((hh, hw), np.uint8)

    def release(self) -> None:
        for obj in (self.fbo, self.fbo_inst, self.color, self.depth, self.inst, self.zbuf):
            obj.release()
        if getattr(self, "shadow_step", None) is not None:
            self.fbo_lit.release()
            self.lit.release()


class Renderer:
    """Renders :class:`RenderedFrame` s of a :class:`World` (see module docstring).

    Args:
        world: the world to draw.
        settings: look and speed knobs.

    Raises:
        RenderError: no usable EGL/OpenGL 3.3 context.
    """

    def __init__(self, world: World, settings: RenderSettings | None = None, lighting: Lighting | None = None) -> None:
        import moderngl  # noqa: PLC0415  (GL is optional for the pure core)

        self._mgl: Any = moderngl  # moderngl's stubs are partial; GL objects are handled as Any
        self.world = world
        self.settings = settings or RenderSettings()
        s = self.settings
        self.lighting = lighting or Lighting.clean(s.sun_azimuth_deg, s.sun_elevation_deg, s.haze_distance_m)
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
        self._shadow_static: Any = None  # (texture, framebuffer) of the static shadow map, made on demand
        self._shadow_static_key: tuple[float, ...] | None = None  # the sun it was rendered for
        self._static_depth = np.zeros((1, 1), np.float32)  # host copy of the static shadow map
        self._stamps: dict[int, tuple[int, int, int, int]] = {}  # texel rectangles the movers were drawn into
        self._stamps_dirty = True
        self._stamp_moved: set[int] = set()  # people and vehicles moved since they were last drawn into it
        self._shadow_texel = (1.0, 1.0)
        self._shadow_bias = 0.0
        self.object_shadow_stamps = 0  # how often people and vehicles were drawn into the shadow map
        self._dyn_dirty = False
        self._light0 = np.eye(4)
        self._light_depth = (0.0, 1.0)
        self.static_shadow_renders = 0  # how often the static shadow map was rendered (once per sun)
        self._static_alone_vao: Any = None  # static objects drawn alone (unoccluded_pixel_counts), built lazily
        self._static_alone_ranges: dict[int, tuple[int, int]] = {}
        self._build_programs()
        self._upload_static()
        self._upload_dynamic()
        self.last_triangles = 0
        self.set_lighting(self.lighting)

    # ------------------------------------------------------------------ setup
    def _build_programs(self) -> None:
        ctx = self.ctx
        s = self.settings
        # One shaded program per (landing pad, shadow mode): 0 no shadows, 1 shadows.
        self._progs: dict[tuple[bool, int], Any] = {}
        for pad in (False, True):
            for mode in (0, 1, 2):
                defines = (
                    (["PAD"] if pad else []) + (["SHADOWS"] if mode else []) + (["DYN_SHADOWS"] if mode == 2 else [])
                )
                vs = shaders.with_defines(shaders.MAIN_VS, *defines)
                fs = shaders.with_defines(shaders.MAIN_FS, *defines)
                prog = ctx.program(vertex_shader=vs, fragment_shader=fs)
                prog["u_texture_gain"].value = s.texture_gain
                if pad:
                    prog["u_pad_half_m"].value = s.pad_half_size_m
                    prog["u_pad_instance"].value = TERRAIN_INSTANCE_ID
                if prog.get("u_shadow0", None) is not None:
                    prog["u_shadow0"].value = 0
                self._progs[(pad, mode)] = prog
        self.prog: Any = self._progs[(False, 0)]
        self.prog_pad: Any = self._progs[(True, 0)]
        self.sky: Any = ctx.program(vertex_shader=shaders.SKY_VS, fragment_shader=shaders.SKY_FS)
        tri = ctx.buffer(np.array([-1, -1, 3, -1, -1, 3], dtype="f4").tobytes())
        self.sky_vao = ctx.vertex_array(self.sky, [(tri, "2f", "in_xy")])
        self.iprog: Any = ctx.program(vertex_shader=shaders.INSTANCE_VS, fragment_shader=shaders.INSTANCE_FS)
        self.dprog: Any = ctx.program(vertex_shader=shaders.DEPTH_VS, fragment_shader=shaders.DEPTH_FS)
        self.sprog: Any = ctx.program(vertex_shader=shaders.SHADOW_VS, fragment_shader=shaders.SHADOW_FS)
        self.sprog["u_shadow"].value = 0
        self.sprog["u_depth"].value = 1
        self.shadow_vao = ctx.vertex_array(self.sprog, [(tri, "2f", "in_xy")])

    # ------------------------------------------------------------------ light
    def set_lighting(self, lighting: Lighting) -> None:
        """Use this light from the next frame on (the static shadow map follows the sun, once per change)."""
        self.lighting = lighting
        lt = lighting
        with self.ctx:
            for prog in self._progs.values():
                prog["u_sun"].value = lt.sun_dir
                prog["u_sun_rgb"].value = lt.sun_rgb
                prog["u_sky_rgb"].value = lt.sky_rgb
                prog["u_ambient_rgb"].value = lt.ambient_rgb
                prog["u_haze_color"].value = lt.haze_rgb
                prog["u_haze_per_m"].value = lt.haze_per_m
                prog["u_haze_max"].value = lt.haze_max
            self.sky["u_sun"].value = lt.sun_dir
            self.sky["u_zenith"].value = lt.zenith_rgb
            self.sky["u_horizon"].value = lt.horizon_rgb
            self.sky["u_glow"].value = lt.glow_rgb
            self.sky["u_sun_disc"].value = lt.sun_disc

    @staticmethod
    def _vertex_records(verts: npt.NDArray[np.float32], normals: npt.NDArray[np.float32],
                        colors: npt.NDArray[np.float32], inst: npt.NDArray[np.uint32]) -> npt.NDArray[Any]:  # fmt: skip
        rec = np.empty(len(verts), dtype=[("p", "<f4", 3), ("n", "<f4", 3), ("c", "<f4", 3), ("i", "<u4")])
        rec["p"], rec["n"], rec["c"], rec["i"] = verts, normals, colors, inst
        return rec

    def _vertex_bytes(self, verts: npt.NDArray[np.float32], normals: npt.NDArray[np.float32],
                      colors: npt.NDArray[np.float32], inst: npt.NDArray[np.uint32]) -> bytes:  # fmt: skip
        return bytes(self._vertex_records(verts, normals, colors, inst).tobytes())

    def _upload_dynamic_changes(self) -> None:
        """Write the vertex runs of the people and vehicles moved since the last upload."""
        if not self._dyn_dirty:
            return
        for iid in self._dyn_changed:
            a, b = self._dyn_span[iid]
            self._dyn_rec["p"][a:b] = self._dyn_world[a:b]
            self._dyn_rec["n"][a:b] = self._dyn_normals[a:b]
            self._dyn_vbo.write(self._dyn_rec[a:b].tobytes(), offset=a * self._dyn_rec.itemsize)
        self._dyn_changed.clear()
        self._dyn_dirty = False

    def _shaded_vao(self, prog: Any, vbo: Any, ibo: Any) -> Any:
        return self.ctx.vertex_array(prog, [(vbo, "3f 3f 3f 1u", "in_pos", "in_nrm", "in_col", "in_inst")], ibo)

    def _make_vaos(self, vbo: Any, ibo: Any) -> tuple[Any, Any]:
        """(shaded, instance-only) vertex arrays over one vertex buffer."""
        instance = self.ctx.vertex_array(self.iprog, [(vbo, "3f 24x 1u", "in_pos", "in_inst")], ibo)
        return self._shaded_vao(self.prog, vbo, ibo), instance

    def _upload_static(self) -> None:  # noqa: PLR0915 - one pass over the static mesh
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
        faces, tile, rank, tris, lod = faces[order], tile[order], rank[order], tris[order], lod[order]
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
        self._static_vaos = {
            key: self._shaded_vao(prog, self._static_vbo, self._static_ibo) for key, prog in self._progs.items()
        }
        self._static_vao = self._static_vaos[(False, 0)]
        self._static_pad_vao = self._static_vaos[(True, 0)]
        self._indirect = ctx.buffer(reserve=max(1, n_tiles) * 20, dynamic=True)
        # What casts static shadows: everything but the far-LOD tree crowns (the near ones stand in for them).
        caster = faces[lod != LOD_FAR] if len(faces) else faces
        self._shadow_ibo = ctx.buffer(caster.astype("<u4").tobytes() if len(caster) else b"\0" * 12)
        self._shadow_vao = ctx.vertex_array(self.dprog, [(self._static_vbo, "3f 28x", "in_pos")], self._shadow_ibo)
        self._shadow_caster_count = len(caster) * 3
        lo_w = np.min(tris.reshape(-1, 3), axis=0) if len(tris) else np.zeros(3)
        hi_w = np.max(tris.reshape(-1, 3), axis=0) if len(tris) else np.ones(3)
        self._world_box = (lo_w, hi_w)

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
            if len(sel) and sel[-1] - sel[0] + 1 != len(sel):
                msg = f"the vertices of object {int(iid)} are not one run of the world mesh"
                raise RenderError(msg)
            self._dyn_slices[int(iid)] = sel
            self._poses[int(iid)] = obj.pose
            self._dyn_local[sel] = obj.pose.to_local(self._dyn_world[sel])
            self._dyn_normals_local[sel] = self._dyn_normals[sel] @ obj.pose.rotation()
        self.dynamic_triangles = len(dyn_faces)
        ctx = self.ctx
        self._dyn_rec = self._vertex_records(self._dyn_world, self._dyn_normals, self._dyn_colors, self._dyn_inst)
        data = self._dyn_rec.tobytes()
        self._dyn_vbo = ctx.buffer(data if data else b"\0" * 40, dynamic=True)
        # each object's vertices are one run of the buffer: only the runs of moved objects are uploaded
        self._dyn_span = {iid: (int(sel[0]), int(sel[-1]) + 1) for iid, sel in self._dyn_slices.items() if len(sel)}
        self._dyn_changed: set[int] = set()
        ibo = inverse.reshape(-1).astype("<u4").tobytes()
        self._dyn_ibo = ctx.buffer(ibo if ibo else b"\0" * 12)
        self._dyn_vao, self._dyn_ivao = self._make_vaos(self._dyn_vbo, self._dyn_ibo)
        self._dyn_vaos = {
            mode: self._shaded_vao(self._progs[(False, mode)], self._dyn_vbo, self._dyn_ibo) for mode in (0, 1, 2)
        }
        self._dyn_shadow_vao = self.ctx.vertex_array(self.dprog, [(self._dyn_vbo, "3f 28x", "in_pos")], self._dyn_ibo)
        self._dyn_radius = {
            iid: float(np.max(np.linalg.norm(self._dyn_local[sel], axis=1))) if len(sel) else 0.0
            for iid, sel in self._dyn_slices.items()
        }
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
        a, b = self._dyn_span[instance_id]  # the object's vertices are this run of the buffer
        rot = pose.rotation()
        self._dyn_world[a:b] = self._dyn_local[a:b] @ rot.T + np.asarray(pose.position_m)
        self._dyn_normals[a:b] = self._dyn_normals_local[a:b] @ rot.T
        self._poses[instance_id] = pose
        self._dyn_changed.add(instance_id)
        self._dyn_dirty = True
        self._stamp_moved.add(instance_id)
        self._stamps_dirty = True

    def set_object_shape(self, instance_id: int, local_vertices_m: npt.ArrayLike) -> None:
        """Re-shape a person (a new pose or gait phase): its triangle-soup vertices in its local frame, in the order
        the world mesh has them (``figures.person_vertices(...)[faces].reshape(-1, 3)``); the pose is kept.

        Raises:
            KeyError: the instance is not a person or vehicle of this world.
            ValueError: the vertex count differs from the object's.
        """
        if instance_id not in self._dyn_slices:
            msg = f"instance {instance_id} is not a movable object (person or vehicle) of this world"
            raise KeyError(msg)
        sel = self._dyn_slices[instance_id]
        local = np.asarray(local_vertices_m, dtype=np.float64).reshape(-1, 3)
        if len(local) != len(sel):
            msg = f"instance {instance_id} has {len(sel)} vertices, got {len(local)}"
            raise ValueError(msg)
        self.set_object_shapes([instance_id], local[None])
        self.set_object_pose(instance_id, self._poses[instance_id])

    def set_object_shapes(
        self, instance_ids: list[int], local_vertices_m: npt.ArrayLike, normals: npt.ArrayLike | None = None
    ) -> None:
        """:meth:`set_object_shape` of several people with the same vertex count (``(K, V, 3)``), without
        re-posing them: call :meth:`set_object_pose` for each afterwards (walkers move every frame anyway).

        Raises:
            KeyError: an instance is not a person or vehicle of this world.
            ValueError: a vertex count differs from the object's.
        """
        local = np.asarray(local_vertices_m)
        if not len(instance_ids):
            return
        if normals is None:  # flat shading: each triangle's own normal on its three vertices
            tri = local.reshape(len(instance_ids), -1, 3, 3)
            nrm = np.cross(tri[:, :, 1] - tri[:, :, 0], tri[:, :, 2] - tri[:, :, 0])
            nrm /= np.linalg.norm(nrm, axis=-1, keepdims=True) + 1e-12
            normals = np.repeat(nrm, 3, axis=1)
        normals = np.asarray(normals)
        radius = np.max(np.abs(local).sum(axis=-1), axis=1)  # >= the largest norm: a safe bound
        for k, iid in enumerate(instance_ids):
            if iid not in self._dyn_span:
                msg = f"instance {iid} is not a movable object (person or vehicle) of this world"
                raise KeyError(msg)
            a, b = self._dyn_span[iid]
            if b - a != local.shape[1]:
                msg = f"instance {iid} has {b - a} vertices, got {local.shape[1]}"
                raise ValueError(msg)
            self._dyn_local[a:b] = local[k]
            self._dyn_normals_local[a:b] = normals[k]
            self._dyn_radius[iid] = float(radius[k])

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
            mode = self._shadow_mode
            for pad in (False, True):
                prog = self._progs[(pad, mode)]
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
        self._upload_dynamic_changes()
        return target

    def render(self, camera: CameraModel, t_map_optical: RigidTransform) -> RenderedFrame:
        """Render one camera at ``T_map_optical``.

        Raises:
            RenderError: called from a thread other than the creating one.
        """
        self._check_thread()
        with self.ctx:  # make this renderer's context current (several renderers may share a thread)
            try:
                return self._render(camera, t_map_optical)
            finally:
                self._shadow_mode = 0

    def _draw_scene(
        self, camera: CameraModel, t_map_optical: RigidTransform, *, shaded: bool, cull: CameraModel | None = None
    ) -> None:
        """Draw the static tiles in ``cull``'s frustum (default: the camera's) and every dynamic object."""
        cmds, pad = self._draw_commands(cull or camera, t_map_optical)
        if len(cmds):
            self._indirect.orphan(len(cmds) * 20)
            self._indirect.write(cmds.tobytes())
            if not shaded:
                self._static_ivao.render_indirect(self._indirect, mode=self._mgl.TRIANGLES, count=len(cmds))
            else:
                # Runs of tiles with and without the pad, in the front-to-back order (same result as one call).
                cuts = [0, *(np.flatnonzero(pad[1:] != pad[:-1]) + 1).tolist(), len(cmds)]
                for a, b in itertools.pairwise(cuts):
                    vao = self._static_vaos[(bool(pad[a]), self._shadow_mode)]
                    vao.render_indirect(self._indirect, mode=self._mgl.TRIANGLES, count=b - a, first=a)
        if self.dynamic_triangles:
            (self._dyn_vaos[self._shadow_mode] if shaded else self._dyn_ivao).render(self._mgl.TRIANGLES)
        self.last_triangles = int(cmds[:, 0].sum() // 3) + self.dynamic_triangles if len(cmds) else 0

    def _render(self, camera: CameraModel, t_map_optical: RigidTransform) -> RenderedFrame:
        self._prepare_shadows(camera, t_map_optical)
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
        unshaded = self._shadow_pass(camera, t_map_optical, target) if self._shadow_mode else None
        if unshaded is None:
            fbo.read_into(target.buf_color, attachment=0, components=3, dtype="f1", alignment=1)
        fbo.read_into(target.buf_inst, attachment=2, components=1, dtype="u4", alignment=1)
        return RenderedFrame(
            None if unshaded is not None else np.ascontiguousarray(target.buf_color[::-1]),
            np.ascontiguousarray(target.buf_depth[::-1]),
            target.buf_inst[::-1].astype(np.uint16),
            unshaded=unshaded,
        )

    # ------------------------------------------------------------------ shadows
    _shadow_mode = 0

    def _shadow_pass(self, camera: CameraModel, t_map_optical: RigidTransform, target: _Target) -> UnshadedColor:
        """The lit fraction of every ``shadow_step`` x ``shadow_step`` block (GL, now), with the lit colour and the
        sun's share: the colour is finished on the CPU (:class:`UnshadedColor`), wherever it is first needed."""
        step = self.settings.shadow_step
        target.shadow_buffers(self.ctx, step)
        sp = self.sprog
        sp["u_step"].value = step
        sp["u_r_map_optical"].write(t_map_optical.rotation.T.astype("f4").tobytes())
        sp["u_eye"].value = tuple(float(v) for v in t_map_optical.translation_m)
        sp["u_k"].value = (camera.fx, camera.fy, camera.cx, camera.cy)
        sp["u_height"].value = float(camera.height)
        sp["u_light"].write(self._light0.T.astype("f4").tobytes())
        sp["u_bias"].value = self._shadow_bias
        target.depth.use(location=1)
        self.ctx.disable(self._mgl.DEPTH_TEST | self._mgl.CULL_FACE)
        target.fbo_lit.use()
        self.shadow_vao.render(self._mgl.TRIANGLES)
        target.fbo_lit.read_into(target.buf_lit, components=1, dtype="f1", alignment=1)
        target.fbo.read_into(target.buf_alpha, attachment=0, components=4, dtype="f1", alignment=1)
        # top row first, and copies: the target's buffers are reused next frame
        return UnshadedColor(target.buf_alpha[::-1].copy(), target.buf_lit[::-1].copy())

    def _light_basis(self) -> tuple[npt.NDArray[np.float64], npt.NDArray[np.float64], npt.NDArray[np.float64]]:
        w = np.asarray(self.lighting.sun_dir, dtype=np.float64)
        up = np.array([0.0, 0.0, 1.0]) if abs(w[2]) < 0.999 else np.array([0.0, 1.0, 0.0])
        u = np.cross(up, w)
        u /= np.linalg.norm(u)
        return u, np.cross(w, u), w

    @staticmethod
    def _ortho(
        axes: tuple[npt.NDArray[np.float64], npt.NDArray[np.float64], npt.NDArray[np.float64]],
        centre: tuple[float, float],
        half: tuple[float, float],
        depth: tuple[float, float],
    ) -> npt.NDArray[np.float64]:
        """``map`` -> ``[0, 1]^3`` of an orthographic view along ``-w`` (depth 0 nearest the sun): axes ``(u, v, w)``,
        the view's centre and half sizes along ``u`` and ``v``, and its depth range along ``w``."""
        u, v, w = axes
        (cu, cv), (hu, hv), (w_lo, w_hi) = centre, half, depth
        m = np.zeros((4, 4))
        m[0, :3], m[0, 3] = u / (2 * hu), 0.5 - cu / (2 * hu)
        m[1, :3], m[1, 3] = v / (2 * hv), 0.5 - cv / (2 * hv)
        m[2, :3], m[2, 3] = -w / (w_hi - w_lo), w_hi / (w_hi - w_lo)
        m[3, 3] = 1.0
        return m

    @staticmethod
    def _clip_from_unit(m: npt.NDArray[np.float64]) -> npt.NDArray[np.float64]:
        """The same projection into GL clip space ``[-1, 1]^3`` (for drawing the map)."""
        to_clip = np.diag([2.0, 2.0, 2.0, 1.0])
        to_clip[:3, 3] = -1.0
        return to_clip @ m

    def _shadow_target(self, size: int) -> tuple[Any, Any]:
        tex = self.ctx.depth_texture((size, size))
        tex.compare_func = "<="
        tex.filter = (self._mgl.LINEAR, self._mgl.LINEAR)
        tex.repeat_x = False
        tex.repeat_y = False
        return tex, self.ctx.framebuffer(depth_attachment=tex)

    def _draw_depth(
        self,
        fbo: Any,
        light: npt.NDArray[np.float64],
        vao: Any,
        vertices: int | None = None,
        *,
        first: int = 0,
        clear: bool,
    ) -> None:
        fbo.use()
        if clear:
            fbo.clear(depth=1.0)
        self.ctx.enable(self._mgl.DEPTH_TEST)
        self.ctx.disable(self._mgl.CULL_FACE)
        self.ctx.depth_func = "<"
        self.ctx.polygon_offset = (1.6, 4.0)
        self.dprog["u_light"].write(self._clip_from_unit(light).T.astype("f4").tobytes())
        if vertices is None:
            vao.render(self._mgl.TRIANGLES)
        else:
            vao.render(self._mgl.TRIANGLES, vertices=vertices, first=first)
        self.ctx.polygon_offset = (0.0, 0.0)

    def _render_static_shadows(self) -> None:
        """The static world seen from the sun, once per sun position: terrain, roads, buildings, trees.

        A copy stays in memory: the people and vehicles are drawn into the same map where they stand
        (:meth:`_stamp_object_shadows`), and the static depth is written back where they stood.
        """
        u, v, w = self._light_basis()
        lo, hi = self._world_box
        corners = np.array([[x, y, z] for x in (lo[0], hi[0]) for y in (lo[1], hi[1]) for z in (lo[2], hi[2])])
        pu, pv, pw = corners @ u, corners @ v, corners @ w
        pad = 2.0
        hu, hv = (pu.max() - pu.min()) / 2 + pad, (pv.max() - pv.min()) / 2 + pad
        self._light_depth = (float(pw.min()) - 20.0, float(pw.max()) + 20.0)
        self._light0 = self._ortho((u, v, w), (float(pu.mean()), float(pv.mean())), (hu, hv), self._light_depth)
        size = self.settings.shadow_map_px
        if self._shadow_static is None:
            self._shadow_static = self._shadow_target(size)
        tex, fbo = self._shadow_static
        self._shadow_texel = (2.0 * hu / size, 2.0 * hv / size)
        # a receiver is lit unless something is more than ~1.5 texels (in depth) nearer the sun
        self._shadow_bias = 1.5 * max(self._shadow_texel) / (self._light_depth[1] - self._light_depth[0])
        self._draw_depth(fbo, self._light0, self._shadow_vao, self._shadow_caster_count, clear=True)
        self._static_depth = np.frombuffer(tex.read(), dtype=np.float32).reshape(size, size).copy()
        self._stamps = {}
        self._stamps_dirty = True
        self._shadow_static_key = tuple(self.lighting.sun_dir)
        self.static_shadow_renders += 1

    def _stamp_object_shadows(self) -> None:
        """Put the people and vehicles into the shadow map where they are now (once per move, for every camera).

        Only what changed is redrawn: the static depth is written back where each moved object stood, then the
        moved objects are drawn where they stand, with any other object whose texels that write-back touched.
        After a new static map (``self._stamps`` empty) every object is drawn."""
        if not self.dynamic_triangles:
            return
        tex, fbo = self._shadow_static
        size = self.settings.shadow_map_px
        moved = set(self._dyn_ranges) if not self._stamps else self._stamp_moved & set(self._dyn_ranges)
        restored = [self._stamps.pop(iid) for iid in moved if iid in self._stamps]
        for x0, y0, x1, y1 in restored:
            tex.write(
                np.ascontiguousarray(self._static_depth[y0:y1, x0:x1]).tobytes(), viewport=(x0, y0, x1 - x0, y1 - y0)
            )
        redraw = set(moved)
        for iid, (x0, y0, x1, y1) in self._stamps.items():  # unmoved objects the write-back reached
            if any(x0 < b[2] and b[0] < x1 and y0 < b[3] and b[1] < y1 for b in restored):
                redraw.add(iid)
        for iid in moved:
            c = self._light0 @ np.array([*self._poses[iid].position_m, 1.0])
            r = self._dyn_radius.get(iid, 0.0)
            rx, ry = r / self._shadow_texel[0] + 2.0, r / self._shadow_texel[1] + 2.0
            x0, x1 = int(max(0, math.floor(c[0] * size - rx))), int(min(size, math.ceil(c[0] * size + rx)))
            y0, y1 = int(max(0, math.floor(c[1] * size - ry))), int(min(size, math.ceil(c[1] * size + ry)))
            if x1 > x0 and y1 > y0:
                self._stamps[iid] = (x0, y0, x1, y1)
        self._upload_dynamic_changes()
        # one draw per run of consecutive index ranges (a draw costs ~0.15 ms on llvmpipe, an object ~0.015 ms)
        runs: list[list[int]] = []
        for first, count in sorted(self._dyn_ranges[iid] for iid in redraw):
            if runs and runs[-1][0] + runs[-1][1] == first:
                runs[-1][1] += count
            else:
                runs.append([first, count])
        for first, count in runs:
            self._draw_depth(fbo, self._light0, self._dyn_shadow_vao, count, first=first, clear=False)
        self._stamp_moved.clear()
        self._stamps_dirty = False
        self.object_shadow_stamps += 1

    def _prepare_shadows(self, camera: CameraModel, t_map_optical: RigidTransform) -> None:
        """Pick the shadow mode of this frame and bring the shadow map up to date before the camera pass."""
        self._shadow_mode = 0
        if not self.lighting.shadows:
            return
        if self._shadow_static_key != tuple(self.lighting.sun_dir):
            self._render_static_shadows()
        if self._stamps_dirty:
            self._stamp_object_shadows()
        self._shadow_mode = 1
        tex0, _ = self._shadow_static
        tex0.use(location=0)

    def render_instances(
        self, camera: CameraModel, t_map_optical: RigidTransform, *, draw_within_m: float | None = None
    ) -> npt.NDArray[np.uint16]:
        """Only the instance-id image of :meth:`render` (0 where nothing was hit), unshaded.

        Several times cheaper than :meth:`render` when nothing else is consumed (ground-truth
        detections).  ``draw_within_m`` (e.g. the detection range plus the largest object) skips the
        distant scene: the terrain and object tiles wholly beyond that z-depth are not drawn, since nothing
        there can hide what is nearer. The projection stays the camera's (same near and far planes), so every
        surface drawn gets the depth it gets in :meth:`render`, and the ids within ``draw_within_m`` are
        exactly the full render's, down to which of two nearly coincident surfaces wins a pixel (a vehicle
        sunk into a slope). A shorter far plane would change the depth buffer's precision and with it,
        now and then, an edge pixel.

        Raises:
            RenderError: called from a thread other than the creating one.
            ValueError: ``draw_within_m`` is not positive.
        """
        self._check_thread()
        cull = None
        if draw_within_m is not None:
            if not draw_within_m > 0.0:
                msg = f"draw_within_m must be > 0, got {draw_within_m}"
                raise ValueError(msg)
            far = min(camera.far_m, max(draw_within_m, 2.0 * camera.near_m))
            cull = dataclasses.replace(camera, far_m=far)
        with self.ctx:
            target = self._setup_camera(camera, t_map_optical, shaded=False)
            # Where nothing is drawn the id stays the clear value, 0: Mesa clears an integer attachment with the
            # bit pattern of the float clear colour, and 0.0f is 0 (a full-screen pass did the same, ~1 ms more).
            self._draw_scene(camera, t_map_optical, shaded=False, cull=cull)
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
            # An articulated figure overlaps itself (an arm in front of the chest): lay down its depth first,
            # then count only the front-most fragment of each pixel, so every pixel counts once.
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
            if self._shadow_static is not None:
                self._shadow_static[1].release()
                self._shadow_static[0].release()
        self.ctx.release()

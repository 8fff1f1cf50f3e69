"""Low-poly people and vehicles: articulated humans in poses and gaits, car / van / truck bodies (pure numpy).

People are articulated figures: head, neck, chest, hips, upper arms, forearms, hands, thighs,
shins and feet, each a tapered box (the head an icosahedron) placed by forward kinematics from
joint angles. Every pose (:class:`PersonPose`) and every phase of the walking gait uses the same
triangles in the same order, only the vertices move, so the renderer re-shapes a walking person
in place. Body size (height, build) and clothing colours are per person.

Vehicles are rigid: a side-profile body (bonnet, boot), a cabin with glass windscreen, rear and
side windows, wheels, lights and bumpers, in three types (:class:`VehicleType`).

Frames: an object's local frame has x forward, y left, z up; its origin is the centre of the
footprint of its bounding box with z = 0 on the ground, so the world's 3D box of an object is
its pose plus ``size_m`` (``WorldObject``). A walking person's box is the union over the gait
cycle. Faces are counter-clockwise seen from outside.

Colours come from *roles* (skin, shirt, paint, glass...): a template gives each face a role and
each instance a colour per role (:func:`face_colors`).
"""

from __future__ import annotations

import enum
import math
from dataclasses import dataclass
from functools import cache

import numpy as np
import numpy.typing as npt

from uav_sim_bridge.core.mesh import icosahedron

__all__ = [
    "PERSON_ROLES",
    "VEHICLE_ROLES",
    "VEHICLE_SIZE_M",
    "PersonPose",
    "VehicleType",
    "face_colors",
    "gait_phase",
    "person_box_centres",
    "person_boxes",
    "person_faces",
    "person_vertices",
    "random_person_colors",
    "random_vehicle_colors",
    "vehicle_template",
]

FloatArray = npt.NDArray[np.float64]
IntArray = npt.NDArray[np.int64]


class PersonPose(enum.IntEnum):
    """How a person is posed; the value is stored in object records (``WorldObject.kind``)."""

    STANDING = 0
    WALKING = 1
    SITTING = 2
    LYING = 3

    @property
    def label(self) -> str:
        return self.name.lower()

    @staticmethod
    def from_label(label: str) -> PersonPose:
        try:
            return PersonPose[label.upper()]
        except KeyError as err:
            msg = f"unknown person pose {label!r}; known: {', '.join(p.label for p in PersonPose)}"
            raise ValueError(msg) from err


class VehicleType(enum.IntEnum):
    CAR = 0
    VAN = 1
    TRUCK = 2

    @property
    def label(self) -> str:
        return self.name.lower()

    @staticmethod
    def from_label(label: str) -> VehicleType:
        try:
            return VehicleType[label.upper()]
        except KeyError as err:
            msg = f"unknown vehicle type {label!r}; known: {', '.join(v.label for v in VehicleType)}"
            raise ValueError(msg) from err


# ---------------------------------------------------------------------------------------------------- colours
#: Colour roles of a person's faces.
PERSON_ROLES = ("skin", "shirt", "trousers", "shoes", "hair", "sleeves", "shins")
_SKIN, _SHIRT, _TROUSERS, _SHOES, _HAIR, _SLEEVES, _SHINS = range(len(PERSON_ROLES))
#: Colour roles of a vehicle's faces.
VEHICLE_ROLES = ("paint", "glass", "tyre", "trim", "light", "tail_light", "cargo")
_PAINT, _GLASS, _TYRE, _TRIM, _LIGHT, _TAIL, _CARGO = range(len(VEHICLE_ROLES))

_SKINS = np.array([[0.93, 0.76, 0.62], [0.85, 0.65, 0.50], [0.72, 0.53, 0.38], [0.55, 0.38, 0.26], [0.38, 0.26, 0.18]])
_SHIRTS = np.array(
    [[0.85, 0.15, 0.12], [0.12, 0.35, 0.85], [0.95, 0.75, 0.10], [0.20, 0.62, 0.25], [0.95, 0.45, 0.05],
     [0.55, 0.20, 0.60], [0.92, 0.92, 0.92], [0.15, 0.15, 0.17], [0.45, 0.55, 0.65], [0.70, 0.10, 0.35],
     [0.35, 0.42, 0.22], [0.98, 0.60, 0.70]]
)  # fmt: skip
_TROUSERS_C = np.array(
    [[0.15, 0.18, 0.30], [0.25, 0.22, 0.20], [0.10, 0.10, 0.12], [0.42, 0.38, 0.30], [0.30, 0.34, 0.42],
     [0.55, 0.50, 0.40], [0.20, 0.26, 0.18]]
)  # fmt: skip
_HAIRS = np.array([[0.10, 0.07, 0.05], [0.30, 0.18, 0.09], [0.55, 0.40, 0.20], [0.80, 0.70, 0.45], [0.55, 0.55, 0.55]])
_SHOES_C = np.array([[0.08, 0.08, 0.08], [0.30, 0.20, 0.12], [0.85, 0.85, 0.85], [0.20, 0.22, 0.30]])
_PAINTS = np.array(
    [[0.75, 0.08, 0.08], [0.10, 0.22, 0.65], [0.92, 0.92, 0.92], [0.12, 0.12, 0.13], [0.88, 0.70, 0.10],
     [0.50, 0.52, 0.55], [0.15, 0.40, 0.20], [0.70, 0.72, 0.74], [0.35, 0.18, 0.10], [0.20, 0.45, 0.70]]
)  # fmt: skip
_CARGO_C = np.array([[0.90, 0.90, 0.88], [0.80, 0.80, 0.78], [0.25, 0.35, 0.60], [0.70, 0.20, 0.15]])


def random_person_colors(n: int, rng: np.random.Generator) -> FloatArray:
    """``(n, len(PERSON_ROLES), 3)`` clothing, skin and hair colours, each slightly varied."""
    out = np.empty((n, len(PERSON_ROLES), 3))
    out[:, _SKIN] = _SKINS[rng.integers(len(_SKINS), size=n)]
    out[:, _SHIRT] = _SHIRTS[rng.integers(len(_SHIRTS), size=n)]
    out[:, _TROUSERS] = _TROUSERS_C[rng.integers(len(_TROUSERS_C), size=n)]
    out[:, _SHOES] = _SHOES_C[rng.integers(len(_SHOES_C), size=n)]
    out[:, _HAIR] = _HAIRS[rng.integers(len(_HAIRS), size=n)]
    short_sleeves = rng.random(n) < 0.4
    out[:, _SLEEVES] = np.where(short_sleeves[:, None], out[:, _SKIN], out[:, _SHIRT])
    shorts = rng.random(n) < 0.15
    out[:, _SHINS] = np.where(shorts[:, None], out[:, _SKIN], out[:, _TROUSERS])
    out *= rng.uniform(0.9, 1.08, (n, len(PERSON_ROLES), 1))
    return np.clip(out, 0.0, 1.0)


def random_vehicle_colors(n: int, rng: np.random.Generator) -> FloatArray:
    """``(n, len(VEHICLE_ROLES), 3)`` paint, glass, tyres, trim, lights and cargo-box colours."""
    out = np.empty((n, len(VEHICLE_ROLES), 3))
    out[:, _PAINT] = _PAINTS[rng.integers(len(_PAINTS), size=n)] * rng.uniform(0.92, 1.05, (n, 1))
    out[:, _GLASS] = [0.10, 0.13, 0.17]
    out[:, _TYRE] = [0.05, 0.05, 0.05]
    out[:, _TRIM] = [0.16, 0.16, 0.17]
    out[:, _LIGHT] = [0.95, 0.93, 0.85]
    out[:, _TAIL] = [0.70, 0.06, 0.05]
    out[:, _CARGO] = _CARGO_C[rng.integers(len(_CARGO_C), size=n)]
    return np.clip(out, 0.0, 1.0)


def face_colors(face_roles: IntArray, role_colors: FloatArray) -> FloatArray:
    """``(K, F, 3)`` per-face colours of ``K`` instances from their ``(K, R, 3)`` role colours."""
    return np.asarray(role_colors[:, face_roles, :], dtype=np.float64)


# ---------------------------------------------------------------------------------------------------- primitives
# A box between two joints: vertices 0-3 around the start, 4-7 around the end, in the (side, thickness) plane.
_SEG_CORNERS = np.array([[-1, -1], [1, -1], [1, 1], [-1, 1]], dtype=np.float64) * 0.5
_SEG_FACES = np.array(
    [[0, 2, 1], [0, 3, 2],  # start cap
     [4, 5, 6], [4, 6, 7],  # end cap
     [0, 1, 5], [0, 5, 4], [1, 2, 6], [1, 6, 5], [2, 3, 7], [2, 7, 6], [3, 0, 4], [3, 4, 7]],
    dtype=np.int64,
)  # fmt: skip


def _unit(v: FloatArray) -> FloatArray:
    return np.asarray(v / (np.linalg.norm(v, axis=-1, keepdims=True) + 1e-12), dtype=np.float64)


def _segment(  # noqa: PLR0917 - a segment is its two ends, its side axis and its two cross-sections
    p0: FloatArray, p1: FloatArray, side: FloatArray, w0: FloatArray, t0: FloatArray, w1: FloatArray, t1: FloatArray
) -> FloatArray:
    """``(K, 8, 3)`` tapered boxes from ``p0`` to ``p1`` (``(K, 3)``): width along ``side`` (made orthogonal to
    the axis), thickness across both, ``w0, t0`` at the start and ``w1, t1`` at the end (``(K,)``)."""
    u = _unit(p1 - p0)
    s = _unit(side - np.sum(side * u, axis=-1, keepdims=True) * u)
    t = np.cross(u, s)  # (s, t, u) is right-handed: faces stay counter-clockwise from outside
    out = np.empty((len(p0), 8, 3))
    for k, (a, b) in enumerate(_SEG_CORNERS):
        out[:, k] = p0 + s * (a * w0)[:, None] + t * (b * t0)[:, None]
        out[:, k + 4] = p1 + s * (a * w1)[:, None] + t * (b * t1)[:, None]
    return out


def _icosahedron() -> tuple[FloatArray, IntArray]:
    """:func:`mesh.icosahedron` turned so that two vertices lie on the z axis."""
    v, f = icosahedron()
    # rotate so that two vertices lie on the z axis (a crown and a chin), the rest in two rings
    axis = v[5] / np.linalg.norm(v[5])
    z = np.array([0.0, 0.0, 1.0])
    c = float(axis @ z)
    k = np.cross(axis, z)
    s = float(np.linalg.norm(k))
    k = k / s
    kx = np.array([[0, -k[2], k[1]], [k[2], 0, -k[0]], [-k[1], k[0], 0]])
    rot = np.eye(3) + s * kx + (1 - c) * kx @ kx
    return v @ rot.T, f


_ICO_V, _ICO_F = _icosahedron()

# ---------------------------------------------------------------------------------------------------- people
# Segments in vertex order; each is (name, colour role of its side faces, role of its end caps).
_PERSON_SEGMENTS = (
    ("hips", _TROUSERS),
    ("chest", _SHIRT),
    ("neck", _SKIN),
    ("upper_arm_l", _SHIRT),
    ("upper_arm_r", _SHIRT),
    ("forearm_l", _SLEEVES),
    ("forearm_r", _SLEEVES),
    ("hand_l", _SKIN),
    ("hand_r", _SKIN),
    ("thigh_l", _TROUSERS),
    ("thigh_r", _TROUSERS),
    ("shin_l", _SHINS),
    ("shin_r", _SHINS),
    ("foot_l", _SHOES),
    ("foot_r", _SHOES),
)
_N_SEG = len(_PERSON_SEGMENTS)
_PERSON_VERTS = _N_SEG * 8 + len(_ICO_V)

# Template body of 1.75 m (metres); lengths scale with height, widths also with build.
_HIP_Z = 0.93
_THIGH = 0.44
_SHIN = 0.42
_ANKLE_Z = 0.07
_WAIST_Z = 1.06
_SHOULDER_Z = 1.44
_NECK_TOP_Z = 1.53
_HEAD_C_Z = 1.635
_HEAD_R = (0.098, 0.082, 0.115)
_HIP_Y = 0.09
_SHOULDER_Y = 0.195
_UPPER_ARM = 0.30
_FOREARM = 0.25
_HAND = 0.09
_STRIDE_M = 1.45  # two steps at a brisk 1.4 m/s walk


@cache
def person_faces() -> tuple[IntArray, IntArray]:
    """The shared person template: ``(F, 3)`` faces over :func:`person_vertices` and ``(F,)`` colour roles.

    The head's upper faces are hair, its lower ones skin.
    """
    faces = []
    roles = []
    for k, (_, role) in enumerate(_PERSON_SEGMENTS):
        faces.append(_SEG_FACES + 8 * k)
        roles.append(np.full(len(_SEG_FACES), role, dtype=np.int64))
    head_faces = _ICO_F + 8 * _N_SEG
    faces.append(head_faces)
    centroid_z = _ICO_V[_ICO_F].mean(axis=1)[:, 2]
    centroid_x = _ICO_V[_ICO_F].mean(axis=1)[:, 0]
    hair = (centroid_z > 0.25) | ((centroid_z > -0.1) & (centroid_x < -0.2))  # crown and the back of the head
    roles.append(np.where(hair, _HAIR, _SKIN).astype(np.int64))
    out_f = np.concatenate(faces)
    out_r = np.concatenate(roles)
    out_f.setflags(write=False)
    out_r.setflags(write=False)
    return out_f, out_r


def gait_phase(distance_m: npt.ArrayLike, height_m: npt.ArrayLike) -> FloatArray:
    """Phase in [0, 1) of the walking cycle after walking ``distance_m`` (stride scales with height)."""
    stride = _STRIDE_M * np.asarray(height_m, dtype=np.float64) / 1.75
    return np.asarray(np.mod(np.asarray(distance_m, dtype=np.float64) / stride, 1.0), dtype=np.float64)


@dataclass(frozen=True)
class _Joints:
    """Joint angles in radians, one per person (``(K,)`` each); flexion swings a limb forward."""

    hip_l: FloatArray
    hip_r: FloatArray
    knee_l: FloatArray
    knee_r: FloatArray
    shoulder_l: FloatArray
    shoulder_r: FloatArray
    elbow_l: FloatArray
    elbow_r: FloatArray
    abduct_arm: FloatArray
    abduct_leg: FloatArray
    lean: FloatArray  # torso pitch forward


def _joints(pose: IntArray, phase: FloatArray) -> _Joints:
    k = len(pose)
    z = np.zeros(k)
    d = math.radians
    w = 2.0 * math.pi * phase
    walking = pose == PersonPose.WALKING
    sitting = pose == PersonPose.SITTING
    lying = pose == PersonPose.LYING
    swing = np.sin(w)
    knee_l = d(6.0) + d(55.0) * np.maximum(0.0, np.cos(w)) ** 1.5
    knee_r = d(6.0) + d(55.0) * np.maximum(0.0, -np.cos(w)) ** 1.5

    def by_pose(standing: float, walk: FloatArray | float, sit: float, lie: float) -> FloatArray:
        out = np.full(k, standing) + z
        out = np.where(walking, walk, out)
        out = np.where(sitting, sit, out)
        return np.where(lying, lie, out)

    return _Joints(
        hip_l=by_pose(0.0, d(24.0) * swing, d(84.0), d(4.0)),
        hip_r=by_pose(0.0, -d(24.0) * swing, d(80.0), d(28.0)),
        knee_l=by_pose(d(3.0), knee_l, d(40.0), d(8.0)),
        knee_r=by_pose(d(3.0), knee_r, d(20.0), d(55.0)),
        shoulder_l=by_pose(d(2.0), -d(22.0) * swing, d(38.0), d(0.0)),
        shoulder_r=by_pose(d(2.0), d(22.0) * swing, d(30.0), d(0.0)),
        elbow_l=by_pose(d(10.0), d(18.0) - d(10.0) * swing, d(25.0), d(4.0)),
        elbow_r=by_pose(d(10.0), d(18.0) + d(10.0) * swing, d(30.0), d(4.0)),
        abduct_arm=by_pose(d(6.0), d(5.0), d(14.0), d(28.0)),
        abduct_leg=by_pose(d(2.0), d(1.5), d(8.0), d(9.0)),
        lean=by_pose(0.0, d(4.0), d(-12.0), 0.0),
    )


def _limb_dir(flex: FloatArray, abduct: FloatArray, side: float) -> FloatArray:
    """Unit direction of a limb hanging down, swung forward by ``flex`` and outward by ``abduct``."""
    ca = np.cos(abduct)
    return np.stack([np.sin(flex) * ca, side * np.sin(abduct), -np.cos(flex) * ca], axis=-1)


def _person_body(  # noqa: PLR0915 - one segment after the other, head to feet
    height_m: FloatArray, build: FloatArray, pose: IntArray, phase: FloatArray
) -> FloatArray:
    """``(K, V, 3)`` vertices in the body frame (pelvis over the origin, before lying down and grounding)."""
    k = len(height_m)
    s = (height_m / 1.75)[:, None]  # length scale
    b = build * (height_m / 1.75)  # width scale
    j = _joints(pose, phase)
    up = np.array([0.0, 0.0, 1.0])
    lat = np.tile([0.0, 1.0, 0.0], (k, 1))
    fwd = np.tile([1.0, 0.0, 0.0], (k, 1))
    # the torso leans about the hip joint
    lean_dir = np.stack([np.sin(j.lean), np.zeros(k), np.cos(j.lean)], axis=-1)
    hip_c = np.zeros((k, 3)) + up * (_HIP_Z * s)
    waist = hip_c + lean_dir * ((_WAIST_Z - _HIP_Z) * s)
    shoulder_c = hip_c + lean_dir * ((_SHOULDER_Z - _HIP_Z) * s)
    neck_top = hip_c + lean_dir * ((_NECK_TOP_Z - _HIP_Z) * s)
    head_c = hip_c + lean_dir * ((_HEAD_C_Z - _HIP_Z) * s)
    segs = []
    one = np.ones(k)
    hips_bottom = hip_c - lean_dir * (0.07 * s)
    segs.append(_segment(hips_bottom, waist, lat, 0.34 * b, 0.21 * b, 0.31 * b, 0.19 * b))
    segs.append(_segment(waist, shoulder_c, lat, 0.31 * b, 0.19 * b, 0.40 * b, 0.22 * b))
    segs.append(_segment(shoulder_c - lean_dir * (0.02 * s), neck_top, lat, 0.10 * b, 0.10 * b, 0.09 * b, 0.09 * b))
    joints_l = {}
    for side, name in ((1.0, "l"), (-1.0, "r")):
        shoulder = shoulder_c + lat * (side * _SHOULDER_Y * b)[:, None] - lean_dir * (0.03 * s)
        flex = getattr(j, f"shoulder_{name}") + j.lean
        upper = _limb_dir(flex, j.abduct_arm, side)
        elbow = shoulder + upper * (_UPPER_ARM * s)
        fore = _limb_dir(flex + getattr(j, f"elbow_{name}"), j.abduct_arm * 0.6, side)
        wrist = elbow + fore * (_FOREARM * s)
        hand_end = wrist + fore * (_HAND * s)
        joints_l[name] = (shoulder, elbow, wrist, hand_end)
    for name in ("l", "r"):
        shoulder, elbow, _, _ = joints_l[name]
        segs.append(_segment(shoulder, elbow, fwd, 0.105 * b, 0.105 * b, 0.085 * b, 0.085 * b))
    for name in ("l", "r"):
        _, elbow, wrist, _ = joints_l[name]
        segs.append(_segment(elbow, wrist, fwd, 0.085 * b, 0.085 * b, 0.065 * b, 0.065 * b))
    for name in ("l", "r"):
        _, _, wrist, hand_end = joints_l[name]
        segs.append(_segment(wrist, hand_end, fwd, 0.075 * b, 0.035 * b, 0.065 * b, 0.03 * b))
    legs = {}
    for side, name in ((1.0, "l"), (-1.0, "r")):
        hip = hip_c + lat * (side * _HIP_Y * b)[:, None]
        flex = getattr(j, f"hip_{name}")
        thigh = _limb_dir(flex, j.abduct_leg, side)
        knee = hip + thigh * (_THIGH * s)
        shin_flex = flex - getattr(j, f"knee_{name}")
        shin = _limb_dir(shin_flex, j.abduct_leg, side)
        ankle = knee + shin * ((_SHIN + 0.5 * _ANKLE_Z) * s)
        # the foot points forward, perpendicular to the shin
        foot_dir = np.stack([np.cos(shin_flex), np.zeros(k), np.sin(shin_flex)], axis=-1)
        heel = ankle - foot_dir * (0.05 * s) - shin * (0.5 * _ANKLE_Z * s)
        toe = heel + foot_dir * (0.25 * s)
        legs[name] = (hip, knee, ankle, heel, toe, shin)
    for name in ("l", "r"):
        hip, knee, *_ = legs[name]
        segs.append(_segment(hip, knee, fwd, 0.165 * b, 0.17 * b, 0.115 * b, 0.12 * b))
    for name in ("l", "r"):
        _, knee, ankle, *_ = legs[name]
        segs.append(_segment(knee, ankle, fwd, 0.11 * b, 0.115 * b, 0.075 * b, 0.08 * b))
    for name in ("l", "r"):
        _, _, _, heel, toe, shin = legs[name]
        segs.append(_segment(heel, toe, lat, 0.095 * b, _ANKLE_Z * one * s[:, 0], 0.09 * b, 0.05 * s[:, 0]))
    verts = np.concatenate(segs, axis=1)
    radii = np.asarray(_HEAD_R)[None, :] * np.stack([b, b, s[:, 0]], axis=-1)
    # the head leans with the torso
    c, sn = np.cos(j.lean), np.sin(j.lean)
    rot = np.zeros((k, 3, 3))
    rot[:, 0, 0], rot[:, 0, 2], rot[:, 1, 1], rot[:, 2, 0], rot[:, 2, 2] = c, sn, 1.0, -sn, c
    head = np.einsum("kij,kvj->kvi", rot, _ICO_V[None, :, :] * radii[:, None, :]) + head_c[:, None, :]
    return np.concatenate([verts, head], axis=1)


# Lying on the back, head towards local +x: body up -> +x, body forward -> +z (a proper rotation).
_LIE = np.array([[0.0, 0.0, 1.0], [0.0, -1.0, 0.0], [1.0, 0.0, 0.0]])


def _raw_person(height_m: FloatArray, build: FloatArray, pose: IntArray, phase: FloatArray) -> FloatArray:
    verts = _person_body(height_m, build, pose, phase)
    lying = pose == PersonPose.LYING
    if lying.any():
        verts[lying] = verts[lying] @ _LIE.T
    return verts


def person_vertices(
    height_m: npt.ArrayLike,
    build: npt.ArrayLike,
    pose: npt.ArrayLike,
    phase: npt.ArrayLike | None = None,
    *,
    centre_xy: npt.ArrayLike | None = None,
) -> FloatArray:
    """``(K, V, 3)`` local vertices of ``K`` people (faces: :func:`person_faces`).

    Args:
        height_m: ``(K,)`` standing heights.
        build: ``(K,)`` girth factors (1 = average).
        pose: ``(K,)`` :class:`PersonPose` values.
        phase: ``(K,)`` gait phases in [0, 1) (walking only; default 0).
        centre_xy: ``(K, 2)`` :func:`person_box_centres` of these people and poses, if known (it costs
            16 poses of a walker to compute).

    The footprint of each pose's box (:func:`person_boxes`) is centred on the origin and the
    lowest vertex is at z = 0 (a walking person bobs as the stance foot changes).
    """
    h = np.atleast_1d(np.asarray(height_m, dtype=np.float64))
    bld = np.broadcast_to(np.asarray(build, dtype=np.float64), h.shape)
    p = np.broadcast_to(np.asarray(pose, dtype=np.int64), h.shape)
    ph = np.zeros_like(h) if phase is None else np.broadcast_to(np.asarray(phase, dtype=np.float64), h.shape)
    verts = _raw_person(h, bld, p, ph)
    centre = _box_of(h, bld, p)[0] if centre_xy is None else np.asarray(centre_xy, dtype=np.float64).reshape(-1, 2)
    verts[..., 0] -= centre[:, None, 0]
    verts[..., 1] -= centre[:, None, 1]
    verts[..., 2] -= verts[..., 2].min(axis=1, keepdims=True)
    return verts


_GAIT_SAMPLES = np.linspace(0.0, 1.0, 16, endpoint=False)


def _box_of(height_m: FloatArray, build: FloatArray, pose: IntArray) -> tuple[FloatArray, FloatArray]:
    """(footprint centre ``(K, 2)``, extents ``(K, 3)``) of each person's box in the raw frame (walking: the
    union over the gait cycle)."""
    k = len(height_m)
    lo = np.full((k, 3), np.inf)
    hi = np.full((k, 3), -np.inf)
    walking = pose == PersonPose.WALKING
    phases = _GAIT_SAMPLES if walking.any() else _GAIT_SAMPLES[:1]
    for ph in phases:
        v = _raw_person(height_m, build, pose, np.full(k, ph))
        v[..., 2] -= v[..., 2].min(axis=1, keepdims=True)
        lo = np.minimum(lo, v.min(axis=1))
        hi = np.maximum(hi, v.max(axis=1))
    centre = (lo[:, :2] + hi[:, :2]) / 2.0
    return centre, hi - np.concatenate([lo[:, :2], np.zeros((k, 1))], axis=1)


def person_box_centres(height_m: npt.ArrayLike, build: npt.ArrayLike, pose: npt.ArrayLike) -> FloatArray:
    """``(K, 2)`` footprint centres of the people's boxes in the body frame (for :func:`person_vertices`)."""
    h = np.atleast_1d(np.asarray(height_m, dtype=np.float64))
    bld = np.broadcast_to(np.asarray(build, dtype=np.float64), h.shape)
    p = np.broadcast_to(np.asarray(pose, dtype=np.int64), h.shape)
    return _box_of(h, bld, p)[0]


def person_boxes(height_m: npt.ArrayLike, build: npt.ArrayLike, pose: npt.ArrayLike) -> FloatArray:
    """``(K, 3)`` box extents (length along x, width along y, height) of people in their poses."""
    h = np.atleast_1d(np.asarray(height_m, dtype=np.float64))
    bld = np.broadcast_to(np.asarray(build, dtype=np.float64), h.shape)
    p = np.broadcast_to(np.asarray(pose, dtype=np.int64), h.shape)
    return _box_of(h, bld, p)[1]


# ---------------------------------------------------------------------------------------------------- vehicles
def _prism(profile_xz: list[tuple[float, float]], half_width: float, y0: float = 0.0) -> tuple[FloatArray, IntArray]:
    """A convex side profile (x, z; counter-clockwise seen from +y... i.e. from the left) extruded over
    ``y0 ± half_width``: ``(2n, 3)`` vertices (left side first) and faces (both sides fanned)."""
    n = len(profile_xz)
    p = np.asarray(profile_xz, dtype=np.float64)
    left = np.stack([p[:, 0], np.full(n, y0 + half_width), p[:, 1]], axis=1)
    right = np.stack([p[:, 0], np.full(n, y0 - half_width), p[:, 1]], axis=1)
    verts = np.concatenate([left, right])
    faces = []
    # Seen from +y (the left) with x to the right... x right and z up seen from +y means looking towards -y, so
    # counter-clockwise in (x, z) is clockwise from outside: flip the left fan.
    faces += [[0, i + 1, i] for i in range(1, n - 1)]
    faces += [[n, n + i, n + i + 1] for i in range(1, n - 1)]
    for i in range(n):
        j = (i + 1) % n
        faces += [[i, j, n + j], [i, n + j, n + i]]
    return verts, np.asarray(faces, dtype=np.int64)


def _part_box(centre: tuple[float, float, float], size: tuple[float, float, float]) -> tuple[FloatArray, IntArray]:
    cx, cy, cz = centre
    lx, ly, lz = size
    prof = [
        (cx - lx / 2, cz - lz / 2),
        (cx + lx / 2, cz - lz / 2),
        (cx + lx / 2, cz + lz / 2),
        (cx - lx / 2, cz + lz / 2),
    ]
    return _prism(prof, ly / 2, cy)


def _wheel(x: float, y: float, radius: float, width: float) -> tuple[FloatArray, IntArray]:
    a = np.linspace(0.0, 2.0 * math.pi, 8, endpoint=False) + math.pi / 8
    prof = [(x + radius * math.cos(t), radius + radius * math.sin(t)) for t in a]
    return _prism(prof, width / 2, y)


class _Builder:
    def __init__(self) -> None:
        self.verts: list[FloatArray] = []
        self.faces: list[IntArray] = []
        self.roles: list[IntArray] = []
        self.count = 0

    def add(self, part: tuple[FloatArray, IntArray], role: int | IntArray) -> None:
        v, f = part
        self.verts.append(v)
        self.faces.append(f + self.count)
        self.roles.append(np.broadcast_to(np.asarray(role, dtype=np.int64), (len(f),)).copy())
        self.count += len(v)

    def finish(self) -> tuple[FloatArray, IntArray, IntArray]:
        v = np.concatenate(self.verts)
        # footprint box centred on the origin, wheels on the ground
        lo, hi = v.min(axis=0), v.max(axis=0)
        v = v - np.array([(lo[0] + hi[0]) / 2, (lo[1] + hi[1]) / 2, lo[2]])
        return v, np.concatenate(self.faces), np.concatenate(self.roles)


def _cabin_roles(faces: IntArray, verts: FloatArray, roof_role: int = _PAINT) -> IntArray:
    """Glass on the windscreen, rear window and sides of a cabin prism; paint on the roof."""
    tri = verts[faces]
    n = np.cross(tri[:, 1] - tri[:, 0], tri[:, 2] - tri[:, 0])
    n /= np.linalg.norm(n, axis=1, keepdims=True) + 1e-12
    return np.where(n[:, 2] > 0.9, roof_role, np.where(n[:, 2] < -0.5, _TRIM, _GLASS)).astype(np.int64)


def _lights(b: _Builder, front_x: float, rear_x: float, z: float, half_w: float) -> None:
    for y in (half_w - 0.22, -(half_w - 0.22)):
        b.add(_part_box((front_x - 0.02, y, z), (0.06, 0.26, 0.12)), _LIGHT)
        b.add(_part_box((rear_x + 0.02, y, z), (0.06, 0.24, 0.12)), _TAIL)


@cache
def vehicle_template(vtype: VehicleType) -> tuple[FloatArray, IntArray, IntArray]:
    """``(V, 3)`` local vertices, ``(F, 3)`` faces and ``(F,)`` colour roles of one vehicle type."""
    b = _Builder()
    if vtype is VehicleType.CAR:
        hw = 0.89
        body = [(-2.2, 0.30), (2.2, 0.30), (2.22, 0.62), (2.0, 0.82), (0.85, 0.92), (-1.75, 0.94), (-2.18, 0.80)]
        b.add(_prism(body, hw), _PAINT)
        v, f = _prism([(-1.55, 0.90), (0.75, 0.90), (0.05, 1.42), (-1.2, 1.44)], hw - 0.07)
        b.add((v, f), _cabin_roles(f, v))
        b.add(_part_box((2.17, 0.0, 0.40), (0.14, 1.80, 0.20)), _TRIM)
        b.add(_part_box((-2.17, 0.0, 0.40), (0.14, 1.80, 0.20)), _TRIM)
        _lights(b, 2.2, -2.2, 0.70, hw)
        for x in (-1.35, 1.35):
            for y in (-0.78, 0.78):
                b.add(_wheel(x, y, 0.33, 0.24), _TYRE)
    elif vtype is VehicleType.VAN:
        hw = 0.98
        body = [(-2.5, 0.35), (2.5, 0.35), (2.52, 0.80), (2.2, 1.05), (-2.5, 1.05)]
        b.add(_prism(body, hw), _PAINT)
        v, f = _prism([(-2.5, 1.03), (1.95, 1.03), (1.25, 1.85), (-2.45, 2.05)], hw - 0.02)
        roles = _cabin_roles(f, v)
        # only the cab has side windows: faces behind x = 0.3 are painted panels
        behind = verts_centroid_x(v, f) < 0.3
        roles = np.where(behind & (roles == _GLASS), _PAINT, roles)
        b.add((v, f), roles)
        b.add(_part_box((2.47, 0.0, 0.45), (0.14, 1.98, 0.22)), _TRIM)
        b.add(_part_box((-2.47, 0.0, 0.45), (0.14, 1.98, 0.22)), _TRIM)
        _lights(b, 2.52, -2.5, 0.85, hw)
        for x in (-1.6, 1.65):
            for y in (-0.86, 0.86):
                b.add(_wheel(x, y, 0.36, 0.26), _TYRE)
    else:  # truck: cab in front, cargo box behind, three axles
        hw = 1.22
        b.add(_part_box((0.0, 0.0, 0.62), (7.4, 2.1, 0.34)), _TRIM)  # chassis
        cab = [(2.0, 0.75), (3.7, 0.75), (3.72, 1.55), (3.45, 2.75), (2.0, 2.85)]
        v, f = _prism(cab, hw - 0.04)
        roles = _cabin_roles(f, v)
        low = verts_centroid_z(v, f) < 1.6
        roles = np.where(low & (roles == _GLASS), _PAINT, roles)
        b.add((v, f), roles)
        b.add(_part_box((-0.85, 0.0, 2.02), (5.4, 2.44, 2.5)), _CARGO)
        b.add(_part_box((3.68, 0.0, 0.55), (0.14, 2.3, 0.30)), _TRIM)
        _lights(b, 3.72, -3.55, 0.95, hw)
        for x in (-2.6, -1.45, 2.75):
            for y in (-1.0, 1.0):
                b.add(_wheel(x, y, 0.48, 0.34), _TYRE)
    return b.finish()


def verts_centroid_x(verts: FloatArray, faces: IntArray) -> FloatArray:
    return np.asarray(verts[faces].mean(axis=1)[:, 0], dtype=np.float64)


def verts_centroid_z(verts: FloatArray, faces: IntArray) -> FloatArray:
    return np.asarray(verts[faces].mean(axis=1)[:, 2], dtype=np.float64)


#: Box extents (length, width, height) of each vehicle type's template.
VEHICLE_SIZE_M: dict[VehicleType, tuple[float, float, float]] = {}
for _t in VehicleType:
    _v = vehicle_template(_t)[0]
    _ext = _v.max(axis=0) - _v.min(axis=0)
    VEHICLE_SIZE_M[_t] = (float(_ext[0]), float(_ext[1]), float(_ext[2]))

from __future__ import annotations

import struct

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st
from hypothesis.extra.numpy import arrays

from uav_common.pointcloud import (
    FIELD_OFFSETS,
    POINT_STEP,
    DepthImagePacker,
    pack_depth_image,
    pack_rgb,
    pack_xyzrgb,
    unpack_rgb,
    unpack_xyzrgb,
)


@settings(max_examples=50, deadline=None)
@given(
    arrays(np.float32, st.tuples(st.integers(0, 40), st.just(3)), elements=st.floats(-1e4, 1e4, width=32)),
    st.integers(0, 2**31 - 1),
)
def test_pack_unpack_round_trip(points: np.ndarray, seed: int) -> None:
    colors = np.random.default_rng(seed).integers(0, 256, (len(points), 3)).astype(np.uint8)
    buf = pack_xyzrgb(points, colors)
    assert len(buf) == POINT_STEP * len(points)
    xyz, rgb = unpack_xyzrgb(buf)
    np.testing.assert_array_equal(xyz, points)
    np.testing.assert_array_equal(rgb, colors)


def test_layout_is_pcl_xyzrgb_little_endian() -> None:
    buf = pack_xyzrgb([[1.0, -2.0, 3.5]], [[0x12, 0x34, 0x56]])
    x, y, z, rgb = struct.unpack("<fffI", buf)
    assert (x, y, z) == (1.0, -2.0, 3.5)
    assert rgb == 0x00123456
    assert FIELD_OFFSETS == {"x": 0, "y": 4, "z": 8, "rgb": 12}


def test_unpack_other_layouts_ignores_extra_fields() -> None:
    # 32-byte points with rgb first and an intensity field we do not know about
    rec = np.zeros(2, dtype={"names": ["rgb", "x", "y", "z", "i"], "formats": ["<u4", "<f4", "<f4", "<f4", "<f4"],
                             "offsets": [0, 8, 12, 16, 20], "itemsize": 32})  # fmt: skip
    rec["rgb"] = [0xFF0000, 0x0000FF]
    rec["x"], rec["y"], rec["z"], rec["i"] = [1, 2], [3, 4], [5, 6], [9, 9]
    xyz, rgb = unpack_xyzrgb(rec.tobytes(), 32, {"rgb": 0, "x": 8, "y": 12, "z": 16})
    np.testing.assert_array_equal(xyz, [[1, 3, 5], [2, 4, 6]])
    np.testing.assert_array_equal(rgb, [[255, 0, 0], [0, 0, 255]])


def test_big_endian_clouds_unpack() -> None:
    buf = struct.pack(">fffI", 1.0, 2.0, 3.0, 0x00010203)
    xyz, rgb = unpack_xyzrgb(buf, big_endian=True)
    np.testing.assert_array_equal(xyz, [[1.0, 2.0, 3.0]])
    np.testing.assert_array_equal(rgb, [[1, 2, 3]])


def test_rgb_helpers_round_trip() -> None:
    c = np.array([[0, 0, 0], [255, 255, 255], [1, 2, 3]], dtype=np.uint8)
    np.testing.assert_array_equal(unpack_rgb(pack_rgb(c)), c)


@pytest.mark.parametrize(
    ("kwargs", "match"),
    [
        ({"field_offsets": {"x": 0, "y": 4, "z": 8}}, "lacks field"),
        ({"point_step": 12}, "do not fit"),
    ],
)
def test_unpack_rejects_bad_layouts(kwargs: dict, match: str) -> None:
    with pytest.raises(ValueError, match=match):
        unpack_xyzrgb(b"\0" * 16, **kwargs)


def test_unpack_rejects_partial_points() -> None:
    with pytest.raises(ValueError, match="multiple of point_step"):
        unpack_xyzrgb(b"\0" * 20)


def test_pack_rejects_bad_input() -> None:
    with pytest.raises(ValueError, match="finite"):
        pack_xyzrgb([[np.nan, 0, 0]], [[0, 0, 0]])
    with pytest.raises(ValueError, match="colors"):
        pack_xyzrgb([[0, 0, 0]], [[0, 0, 0], [1, 1, 1]])
    with pytest.raises(ValueError, match=r"\(N, 3\)"):
        pack_xyzrgb([0, 0, 0], [[0, 0, 0]])


@settings(max_examples=40, deadline=None)
@given(st.integers(1, 24), st.integers(1, 24), st.integers(1, 3), st.integers(0, 2**31 - 1))
def test_pack_depth_image_is_pack_xyzrgb_of_the_returns(h: int, w: int, stride: int, seed: int) -> None:
    rng = np.random.default_rng(seed)
    depth = (rng.random((h, w)) * 80.0).astype(np.float32)
    holes = rng.random((h, w))
    depth[holes < 0.1] = np.nan
    depth[(holes >= 0.1) & (holes < 0.15)] = np.inf
    depth[(holes >= 0.15) & (holes < 0.2)] = -1.0
    depth[(holes >= 0.2) & (holes < 0.25)] = 0.0
    color = rng.integers(0, 256, (h, w, 3)).astype(np.uint8)
    k = np.array([[0.8 * w, 0.0, (w - 1) / 2.0], [0.0, 0.8 * w, (h - 1) / 2.0], [0.0, 0.0, 1.0]])
    data, n = pack_depth_image(depth, color, k, stride)
    packer = DepthImagePacker()  # reused buffers: a bigger frame before, and again after
    packer.pack(np.ones((30, 30), np.float32), np.zeros((30, 30, 3), np.uint8), k)
    assert packer.pack(depth, color, k, stride) == (data, n)
    assert packer.pack(depth, color, k, stride) == (data, n)
    # reference: back-project every kept pixel, drop the non-returns, pack
    rows, cols = np.mgrid[0:h:stride, 0:w:stride]
    z = depth[rows, cols]
    ok = np.isfinite(z) & (z > 0)
    with np.errstate(invalid="ignore"):
        x = z * ((cols - k[0, 2]) / k[0, 0]).astype(np.float32)
        y = z * ((rows - k[1, 2]) / k[1, 1]).astype(np.float32)
    expected = pack_xyzrgb(np.stack([x[ok], y[ok], z[ok]], axis=1), color[rows, cols][ok])
    assert n == int(ok.sum())
    assert data == expected


def test_pack_depth_image_rejects_mismatched_images() -> None:
    k = np.eye(3)
    with pytest.raises(ValueError, match=r"\(H, W, 3\) color"):
        pack_depth_image(np.ones((4, 5), np.float32), np.zeros((4, 4, 3), np.uint8), k)
    with pytest.raises(ValueError, match="stride"):
        pack_depth_image(np.ones((4, 5), np.float32), np.zeros((4, 5, 3), np.uint8), k, 0)

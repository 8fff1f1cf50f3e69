"""The files' encoders: PNGs that OpenCV and Pillow read back exactly, depth in millimetres, atomic writes."""

from __future__ import annotations

import io
import os
from pathlib import Path

import cv2
import numpy as np
import pytest
from PIL import Image

from uav_datasets.shell.writers import (
    atomic_write,
    depth_to_mm,
    encode_color,
    encode_depth,
    encode_ids,
    encode_png,
    read_depth,
    read_ids,
)


def _images() -> list[np.ndarray]:
    rng = np.random.default_rng(5)
    return [
        rng.integers(0, 256, (48, 64, 3), dtype=np.uint8),
        rng.integers(0, 256, (1, 7, 3), dtype=np.uint8),
        rng.integers(0, 256, (9, 1), dtype=np.uint8),
        rng.integers(0, 65536, (31, 17), dtype=np.uint16),
        np.full((480, 640), 65535, np.uint16),
    ]


@pytest.mark.parametrize("level", [1, 9, 0])
@pytest.mark.parametrize("k", range(5))
def test_png_round_trips_through_opencv_and_pillow(k: int, level: int) -> None:
    img = _images()[k]
    data = encode_png(img, level=level)
    back = cv2.imdecode(np.frombuffer(data, np.uint8), cv2.IMREAD_UNCHANGED)
    expected = img[..., ::-1] if img.ndim == 3 else img  # OpenCV gives BGR
    np.testing.assert_array_equal(back.reshape(expected.shape), expected)
    pil = np.asarray(Image.open(io.BytesIO(data)))
    np.testing.assert_array_equal(pil.reshape(img.shape).astype(img.dtype), img)


def test_encoders_and_readers(tmp_path: Path) -> None:
    with pytest.raises(ValueError, match="encode_png takes"):
        encode_png(np.zeros((4, 4), np.float32))
    with pytest.raises(ValueError, match="level must be 0"):
        encode_png(np.zeros((4, 4), np.uint8), level=10)
    depth = np.array([[np.nan, 0.0004, 1.2345], [65.534, 65.5356, 900.0]], np.float32)
    np.testing.assert_array_equal(depth_to_mm(depth), [[0, 0, 1234], [65534, 65535, 65535]])
    data, ext = encode_depth(depth, "uint16_mm")
    assert ext == ".png"
    (tmp_path / "d.png").write_bytes(data)
    back = read_depth(tmp_path / "d.png")
    assert np.isnan(back[0, :2]).all()  # 0 mm = no return
    assert back[0, 2] == pytest.approx(1.234)
    data, ext = encode_depth(depth, "float32")
    (tmp_path / f"d{ext}").write_bytes(data)
    np.testing.assert_array_equal(read_depth(tmp_path / f"d{ext}"), depth)
    ids = np.arange(12, dtype=np.uint16).reshape(3, 4) * 5000
    (tmp_path / "i.png").write_bytes(encode_ids(ids))
    np.testing.assert_array_equal(read_ids(tmp_path / "i.png"), ids)
    (tmp_path / "c.png").write_bytes(encode_color(np.zeros((3, 4, 3), np.uint8), "png"))
    with pytest.raises(ValueError, match="16-bit"):
        read_ids(tmp_path / "c.png")
    jpg = encode_color(np.full((8, 8, 3), 200, np.uint8), "jpg", 90)
    assert jpg[:2] == b"\xff\xd8"
    target = tmp_path / "a" / "b.txt"
    atomic_write(target, "one")
    atomic_write(target, "two", sync=True)
    assert target.read_text() == "two"
    assert sorted(os.listdir(target.parent)) == ["b.txt"]  # no temporary file left behind

"""COCO run-length encoding of binary masks (pure numpy; the format ``pycocotools.mask`` reads).

A COCO RLE is ``{"size": [height, width], "counts": ...}``: the mask is read in column-major
(Fortran) order, and ``counts`` holds alternating run lengths of 0s and 1s, starting with 0s
(possibly an empty run). The compressed form (what :func:`encode` writes, as pycocotools does) stores
the counts as a string: each count after the second minus the count two places before it, in 5-bit
groups, least significant first, each group plus a continuation bit offset by 48 (ASCII).

:func:`encode_pixels` encodes a mask given only the coordinates of its pixels, without building the
full image: the labeller knows an instance's pixels from the instance-id image.
"""

from __future__ import annotations

from typing import Any

import numpy as np
import numpy.typing as npt

__all__ = ["area", "counts_from_string", "counts_to_string", "decode", "encode", "encode_pixels", "to_bbox"]


def counts_to_string(counts: list[int]) -> str:
    """COCO's compressed string of a list of run lengths (``rleToString`` in the COCO API)."""
    out: list[str] = []
    for i, count in enumerate(counts):
        x = count - counts[i - 2] if i > 2 else count
        more = True
        while more:
            c = x & 0x1F
            x >>= 5
            more = x != -1 if c & 0x10 else x != 0
            if more:
                c |= 0x20
            out.append(chr(c + 48))
    return "".join(out)


def counts_from_string(text: str) -> list[int]:
    """Run lengths of a compressed COCO string (``rleFrString``)."""
    counts: list[int] = []
    p = 0
    n = len(text)
    while p < n:
        x = 0
        k = 0
        more = True
        while more:
            c = ord(text[p]) - 48
            x |= (c & 0x1F) << (5 * k)
            more = bool(c & 0x20)
            p += 1
            k += 1
            if not more and c & 0x10:
                x |= -1 << (5 * k)
        if len(counts) > 2:
            x += counts[-2]
        counts.append(x)
    return counts


def _runs(linear: npt.NDArray[np.int64], total: int) -> list[int]:
    """Run lengths of a mask whose set pixels have the sorted column-major indices ``linear``."""
    if linear.size == 0:
        return [total]
    breaks = np.flatnonzero(np.diff(linear) != 1)
    starts = np.concatenate(([linear[0]], linear[breaks + 1]))
    ends = np.concatenate((linear[breaks] + 1, [linear[-1] + 1]))  # exclusive
    zeros = starts - np.concatenate(([0], ends[:-1]))
    ones = ends - starts
    counts = np.empty(2 * len(starts), dtype=np.int64)
    counts[0::2] = zeros
    counts[1::2] = ones
    out = counts.tolist()
    tail = total - int(ends[-1])
    if tail:
        out.append(tail)
    return [int(v) for v in out]


def encode_pixels(rows: npt.ArrayLike, cols: npt.ArrayLike, height: int, width: int) -> dict[str, Any]:
    """Compressed COCO RLE of the mask whose set pixels are ``(rows[i], cols[i])`` (any order, no repeats)."""
    r = np.asarray(rows, dtype=np.int64)
    c = np.asarray(cols, dtype=np.int64)
    linear = np.sort(c * height + r)
    return {"size": [int(height), int(width)], "counts": counts_to_string(_runs(linear, height * width))}


def encode(mask: npt.ArrayLike) -> dict[str, Any]:
    """Compressed COCO RLE of a ``(H, W)`` boolean mask."""
    m = np.asarray(mask, dtype=bool)
    h, w = m.shape
    linear = np.flatnonzero(m.ravel(order="F")).astype(np.int64)
    return {"size": [int(h), int(w)], "counts": counts_to_string(_runs(linear, h * w))}


def _counts(rle: dict[str, Any]) -> list[int]:
    counts = rle["counts"]
    if isinstance(counts, str):
        return counts_from_string(counts)
    if isinstance(counts, bytes):
        return counts_from_string(counts.decode("ascii"))
    return [int(v) for v in counts]


def decode(rle: dict[str, Any]) -> npt.NDArray[np.bool_]:
    """The ``(H, W)`` boolean mask of a COCO RLE (compressed or a list of counts)."""
    h, w = (int(v) for v in rle["size"])
    counts = _counts(rle)
    if sum(counts) != h * w:
        msg = f"RLE counts sum to {sum(counts)}, not {h} x {w} = {h * w} pixels"
        raise ValueError(msg)
    values = np.zeros(len(counts), dtype=bool)
    values[1::2] = True
    flat = np.repeat(values, counts)
    return np.asarray(flat.reshape((w, h)).T)


def area(rle: dict[str, Any]) -> int:
    """Set pixels of a COCO RLE."""
    return int(sum(_counts(rle)[1::2]))


def to_bbox(rle: dict[str, Any]) -> tuple[int, int, int, int]:
    """``[x, y, w, h]`` of the set pixels (pixel-edge coordinates, as ``pycocotools.mask.toBbox``); zeros if empty."""
    m = decode(rle)
    rows = np.flatnonzero(m.any(axis=1))
    cols = np.flatnonzero(m.any(axis=0))
    if rows.size == 0:
        return (0, 0, 0, 0)
    return (int(cols[0]), int(rows[0]), int(cols[-1] - cols[0] + 1), int(rows[-1] - rows[0] + 1))

"""uav_common.voxel_keys: the one voxel key packing (map server export, world truth, scorer)."""

from __future__ import annotations

import math

import numpy as np
import pytest
from hypothesis import given
from hypothesis import strategies as st

from uav_common.voxel_keys import (
    VoxelKeyError,
    key_columns,
    keys_from_points,
    pack_keys,
    sorted_unique,
    unpack_keys,
)

INDEX = st.integers(-(1 << 20), (1 << 20) - 1)


@given(st.lists(st.tuples(INDEX, INDEX, INDEX), min_size=1, max_size=50))
def test_pack_unpack_round_trip_and_sort_order(ijk: list[tuple[int, int, int]]) -> None:
    arr = np.array(ijk, dtype=np.int64)
    keys = pack_keys(arr)
    np.testing.assert_array_equal(unpack_keys(keys), arr)
    # keys sort like (x, y, z) lexicographically, so sorting keys sorts voxels
    order = np.lexsort(arr.T[::-1])
    np.testing.assert_array_equal(np.argsort(keys, kind="stable"), order)
    np.testing.assert_array_equal(key_columns(keys), pack_keys(np.c_[arr[:, :2], np.zeros(len(arr))]) >> 21)


def test_points_to_keys_uses_floor_and_drops_non_finite() -> None:
    keys = keys_from_points([[-0.1, 0.0, 0.0], [0.49, 0.0, 0.0], [0.51, 0.0, 0.0], [math.nan, 0, 0]], 0.5)
    np.testing.assert_array_equal(unpack_keys(keys), [[-1, 0, 0], [0, 0, 0], [1, 0, 0]])


def test_sorted_unique_does_not_sort_what_is_sorted() -> None:
    k = np.array([1, 2, 5], dtype=np.int64)
    assert sorted_unique(k) is k or np.shares_memory(sorted_unique(k), k)
    np.testing.assert_array_equal(sorted_unique([5, 1, 5, 2]), [1, 2, 5])


@pytest.mark.parametrize(
    ("call", "match"),
    [
        (lambda: pack_keys([[1 << 20, 0, 0]]), "out of range"),
        (lambda: pack_keys([[0, -(1 << 20) - 1, 0]]), "out of range"),
        (lambda: pack_keys([[1, 2]]), "shape"),
        (lambda: keys_from_points([[0, 0, 0]], 0.0), "resolution_m"),
    ],
)
def test_bad_input_is_refused(call: object, match: str) -> None:
    with pytest.raises(VoxelKeyError, match=match):
        call()  # type: ignore[operator]
    with pytest.raises(ValueError, match=match):  # also a ValueError, for callers that catch that
        call()  # type: ignore[operator]

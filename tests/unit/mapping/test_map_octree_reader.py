"""uav_autonomy.core.octree_reader against the real map server core: a binary octree written by liboctomap
decodes to exactly the occupied voxels the C++ export writes, and the readers reject bad input."""

from __future__ import annotations

import json
import subprocess
from pathlib import Path

import numpy as np
import pytest
from helpers.procs import REPO

from uav_autonomy.core.octree_reader import decode_binary_octree, load_occupied_cells
from uav_autonomy.errors import InvalidInputError

BINARY = REPO / "catkin_ws" / "devel" / "lib" / "uav_mapping" / "map_core_tests"


@pytest.fixture(scope="module")
def sample(tmp_path_factory: pytest.TempPathFactory) -> tuple[Path, dict[str, float]]:
    assert BINARY.exists(), f"{BINARY} is missing: run `make build`"
    out = tmp_path_factory.mktemp("map_sample")
    proc = subprocess.run(
        [str(BINARY), "--write-sample", str(out)], capture_output=True, text=True, timeout=60, check=False
    )
    assert proc.returncode == 0, proc.stderr
    return out, json.loads(proc.stdout.strip().splitlines()[-1])


def test_binary_octree_decodes_to_the_exported_voxels(sample: tuple[Path, dict[str, float]]) -> None:
    out, info = sample
    leaves = decode_binary_octree((out / "sample_binary.bin").read_bytes(), info["resolution_m"])
    assert leaves.voxel_counts() == (info["occupied_voxels"], info["free_voxels"])
    assert len(leaves.size_voxels) == info["leaves"]
    assert leaves.size_voxels.max() > 1  # some free space was pruned
    exported = load_occupied_cells(out / "sample_occupied.npy")
    assert exported.resolution_m == 0.25
    assert exported.meta["frame_id"] == "map"
    np.testing.assert_array_equal(leaves.occupied_indices(), exported.cells)


def test_bt_file_body_is_the_same_stream(sample: tuple[Path, dict[str, float]]) -> None:
    out = sample[0]
    raw = (out / "sample.bt").read_bytes()
    header_end = raw.index(b"\ndata\n") + len(b"\ndata\n")
    assert raw.startswith(b"# Octomap OcTree binary file")
    assert b"\nid OcTree\n" in raw[:header_end]
    assert raw[header_end:] == (out / "sample_binary.bin").read_bytes()


def test_coarser_export_is_the_cells_of_the_voxel_centres(sample: tuple[Path, dict[str, float]]) -> None:
    out, _ = sample
    fine = load_occupied_cells(out / "sample_occupied.npy")
    coarse = load_occupied_cells(out / "sample_occupied_1m.npy")
    centres = (fine.cells + 0.5) * fine.resolution_m
    expected = np.unique(np.floor(centres / coarse.resolution_m).astype(np.int64), axis=0)
    np.testing.assert_array_equal(coarse.cells, expected)


def test_truncated_or_padded_streams_are_rejected(sample: tuple[Path, dict[str, float]]) -> None:
    out, _ = sample
    data = (out / "sample_binary.bin").read_bytes()
    with pytest.raises(InvalidInputError, match="truncated"):
        decode_binary_octree(data[: len(data) // 2], 0.25)
    with pytest.raises(InvalidInputError, match="after its last node"):
        decode_binary_octree(data + b"\x00\x00", 0.25)
    with pytest.raises(InvalidInputError, match="resolution_m"):
        decode_binary_octree(data, 0.0)


def test_hand_built_tree() -> None:
    # Root -> child 7 (inner) -> ... down to depth 16: a single occupied voxel at index (0, 0, 0), key 32768.
    # At depth 0 the voxel is in child 7 (x, y, z >= 32768); below that always child 0.
    data = bytes([0x00, 0xC0])  # child 7 = code 3 (bits 14, 15)
    for _ in range(14):
        data += bytes([0x03, 0x00])  # child 0 = inner
    data += bytes([0x02, 0x04])  # child 0 occupied (code 2), child 5 free (code 1 at bits 10, 11)
    leaves = decode_binary_octree(data, 0.5)
    assert leaves.occupied.tolist() == [True, False]
    np.testing.assert_array_equal(leaves.index_min, [[0, 0, 0], [1, 0, 1]])
    np.testing.assert_array_equal(leaves.occupied_indices(), [[0, 0, 0]])
    assert decode_binary_octree(b"", 0.5).voxel_counts() == (0, 0)


def test_load_rejects_mismatched_sidecar(tmp_path: Path) -> None:
    np.save(tmp_path / "x.npy", np.zeros((3, 3), dtype=np.int32))
    (tmp_path / "x.npy.json").write_text(json.dumps({"resolution_m": 0.5, "count": 2}))
    with pytest.raises(InvalidInputError, match="count"):
        load_occupied_cells(tmp_path / "x.npy")
    np.save(tmp_path / "y.npy", np.zeros((3, 2), dtype=np.int32))
    (tmp_path / "y.npy.json").write_text(json.dumps({"resolution_m": 0.5, "count": 3}))
    with pytest.raises(InvalidInputError, match="shape"):
        load_occupied_cells(tmp_path / "y.npy")
    with pytest.raises(InvalidInputError, match="cannot read"):
        load_occupied_cells(tmp_path / "missing.npy")

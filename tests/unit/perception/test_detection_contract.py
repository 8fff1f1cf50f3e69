"""The detector contract's pure half: class ids, box screening (bad boxes counted and discarded), DEM files."""

from __future__ import annotations

import math
from pathlib import Path

import numpy as np
import pytest

from uav_common.config import ConfigError
from uav_common.detection_classes import DetectionClasses, load_detection_classes
from uav_common.paths import config_file
from uav_perception.core.detection.boxes import DISCARD_REASONS, Box, RawDetection, inclusive_to_center, screen
from uav_perception.core.detection.heightfield import HeightGrid
from uav_perception.errors import TerrainFileError
from uav_perception.shell.dem import load_dem, save_dem

CLASSES = DetectionClasses()


def raw(cu: float, cv: float, su: float, sv: float, *hyps: tuple[int, float]) -> RawDetection:
    return RawDetection(cu, cv, su, sv, tuple(hyps) or ((0, 0.9),))


def test_the_shipped_class_map_reads_coco_ids() -> None:
    classes = load_detection_classes(config_file("detection_classes.yaml"))
    assert classes.id_of("person") == 0
    assert classes.id_of("vehicle") == 2
    # a COCO detector's truck (7) and bus (5) are vehicles; its dog (16) is no class of the range
    assert (classes.name_of(7), classes.name_of(5), classes.name_of(16)) == ("vehicle", "vehicle", None)
    assert classes.names == ("person", "vehicle")
    assert classes.footprint_radius_m("vehicle") > classes.footprint_radius_m("person") > 0


def test_a_class_map_that_claims_an_id_twice_names_the_file(tmp_path: Path) -> None:
    bad = tmp_path / "classes.yaml"
    bad.write_text("classes:\n  person: {id: 0}\n  vehicle: {id: 2, accept_ids: [0]}\n")
    with pytest.raises(ConfigError, match=r"classes\.yaml.*id 0 is claimed by both"):
        load_detection_classes(bad)
    bad.write_text("classes:\n  person: {id: 0, colour: red}\n")
    with pytest.raises(ConfigError, match=r"unknown key.*colour"):
        load_detection_classes(bad)


def test_whole_pixel_boxes_round_trip_exactly() -> None:
    for box in [(0, 0, 0, 0), (10, 20, 13, 29), (630, 470, 639, 479)]:
        cu, cv, su, sv = inclusive_to_center(*box)
        (kept,), discarded = screen([raw(cu, cv, su, sv)], CLASSES, width_px=640, height_px=480)
        assert not discarded
        assert kept.inclusive() == box


def test_bad_boxes_are_counted_by_reason_and_discarded() -> None:
    good = raw(100.0, 100.0, 10.0, 20.0)
    dets = [
        good,
        raw(math.nan, 100.0, 10.0, 20.0),  # NaN centre
        raw(100.0, 100.0, math.inf, 20.0),  # infinite size
        raw(100.0, 100.0, 10.0, 20.0, (0, math.nan)),  # NaN score
        raw(100.0, 100.0, 0.0, 20.0),  # empty
        raw(100.0, 100.0, -3.0, 20.0),  # negative size
        raw(1e6, 100.0, 10.0, 20.0),  # garbage coordinates: far outside
        raw(-30.0, 100.0, 10.0, 20.0),  # wholly left of the image
        raw(636.0, 100.0, 10.0, 20.0),  # reaches 1.5 px past the right edge: within the margin, clipped
        raw(640.0, 100.0, 10.0, 20.0),  # reaches 5.5 px past it: out of the image
        raw(100.0, 100.0, 10.0, 20.0, (16, 0.9)),  # a COCO dog: no class of the range
        RawDetection(100.0, 100.0, 10.0, 20.0, ()),  # no hypothesis at all
        raw(100.0, 100.0, 10.0, 20.0, (0, 1.7)),  # score outside [0, 1]
        raw(100.0, 100.0, 10.0, 20.0, (16, 0.95), (7, 0.6)),  # the best known class wins: vehicle
    ]
    kept, discarded = screen(dets, CLASSES, width_px=640, height_px=480)
    assert dict(discarded) == {
        "nan_box": 3,
        "empty_box": 2,
        "out_of_image": 3,
        "unknown_class": 1,
        "no_hypothesis": 1,
        "bad_score": 1,
    }
    assert set(discarded) <= set(DISCARD_REASONS)
    assert len(kept) + sum(discarded.values()) == len(dets)  # nothing lost without a count
    assert [b.class_name for b in kept] == ["person", "person", "vehicle"]
    clipped = kept[1]
    assert clipped.u1 == pytest.approx(639.5)  # clipped to the image's edge
    assert kept[2].score == pytest.approx(0.6)
    assert kept[2].class_id == 2


def test_without_the_image_size_only_the_box_itself_is_checked() -> None:
    kept, discarded = screen([raw(1e6, 5.0, 4.0, 4.0), raw(math.nan, 0, 1, 1)], CLASSES, width_px=None, height_px=None)
    assert len(kept) == 1
    assert dict(discarded) == {"nan_box": 1}


def test_box_geometry() -> None:
    box = Box("person", 0, 0.5, 9.5, 19.5, 13.5, 29.5)
    assert box.center == (11.5, 24.5)
    assert box.size == (4.0, 10.0)
    assert box.inclusive() == (10, 20, 13, 29)


def test_dem_round_trip_and_bad_files(tmp_path: Path) -> None:
    heights = np.arange(12, dtype=np.float64).reshape(3, 4)
    path = tmp_path / "dem.npz"
    save_dem(path, HeightGrid(heights, -10.0, -5.0, 2.0, "bilinear", "terrain"))
    dem = load_dem(path)
    assert dem.interpolation == "bilinear"
    assert dem.name == "terrain"
    assert np.array_equal(dem.heights_m, heights)
    assert (dem.origin_x_m, dem.origin_y_m, dem.resolution_m) == (-10.0, -5.0, 2.0)
    # sample k sits at the centre of cell k: (origin + (k + 0.5) res)
    assert dem.at(-10.0 + 1.0, -5.0 + 1.0)[()] == pytest.approx(0.0)
    assert dem.at(-10.0 + 3.0, -5.0 + 1.0)[()] == pytest.approx(1.0)
    assert dem.at(-10.0 + 2.0, -5.0 + 2.0)[()] == pytest.approx((0 + 1 + 4 + 5) / 4)
    assert math.isnan(dem.at(100.0, 0.0)[()])
    with pytest.raises(TerrainFileError, match=r"none\.npz: no such terrain model"):
        load_dem(tmp_path / "none.npz")
    (tmp_path / "junk.npz").write_bytes(b"not a zip")
    with pytest.raises(TerrainFileError, match=r"junk\.npz: cannot read"):
        load_dem(tmp_path / "junk.npz")
    np.savez(tmp_path / "other.npz", heights_m=heights)
    with pytest.raises(TerrainFileError, match=r"other\.npz: terrain model lacks origin_x_m"):
        load_dem(tmp_path / "other.npz")
    np.savez(
        tmp_path / "nan.npz",
        heights_m=np.full((2, 2), np.nan),
        origin_x_m=0.0,
        origin_y_m=0.0,
        resolution_m=1.0,
        frame_id="map",
        format="uav_dem_v1",
    )
    with pytest.raises(TerrainFileError, match="no finite height"):
        load_dem(tmp_path / "nan.npz")

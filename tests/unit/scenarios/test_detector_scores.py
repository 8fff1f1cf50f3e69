"""Scores that mean something: COCO AP on hand-built cases with known answers, HOTA on hand-built tracks, and
the run scorer with a detector that is not the ground truth (contexts, geolocation, gallery, operating point)."""

from __future__ import annotations

import math

import numpy as np
import pytest

from uav_scenarios.core.config import ScoringSpec
from uav_scenarios.core.scoring.coco import CocoScores, ContextBands
from uav_scenarios.core.scoring.gallery import Gallery, crop_tile, mosaic
from uav_scenarios.core.scoring.hota import HotaAccumulator, ground_similarity
from uav_scenarios.core.scoring.run import RunScorer
from uav_scenarios.core.scoring.types import Detection, DetectionFrame, PoseSample, SceneTruth, Track, TrackFrame

NAN3 = (math.nan, math.nan, math.nan)


def det(box: tuple[int, int, int, int], score: float = 1.0, cls: str = "person", **kw: object) -> Detection:
    return Detection(0, cls, score, box, kw.pop("range_m", math.nan), kw.pop("vis", math.nan), **kw)  # type: ignore[arg-type]


# ---- COCO ------------------------------------------------------------------------------------------------------------


def test_coco_ap_of_a_hand_built_case() -> None:
    """Two people; three detections: a hit (score 0.9), a false box (0.8), a looser hit (0.7, IoU 260/340 = 0.765).

    At IoU 0.5 the ranking is TP (P 1, R .5), FP (P .5, R .5), TP (P .67, R 1): COCO's interpolated precision is 1 up
    to recall 0.5 (51 of its 101 recall points) and 2/3 beyond (50 points), so AP50 = (51 + 50 * 2/3) / 101. The
    loose hit counts up to IoU 0.75 (6 of the 10 thresholds 0.50:0.05:0.95); above it, precision is 1 up to recall
    0.5 and 0 beyond (51/101): AP = (6 AP50 + 4 * 51/101) / 10 = 0.70297, AR = (6 * 1 + 4 * 0.5) / 10 = 0.8.
    """
    g1, g2 = det((10, 10, 19, 29)), det((100, 100, 109, 129))
    a = det((10, 10, 19, 29), 0.9)
    b = det((300, 300, 309, 329), 0.8)
    c = det((100, 104, 109, 133), 0.7)
    scores = CocoScores()
    scores.add_image([g1, g2], [{}, {}], [a, b, c], [{}, {}, {}], {})
    out = scores.evaluate()
    ap50 = (51 + 50 * 2 / 3) / 101
    assert out["AP50"] == pytest.approx(ap50)
    assert out["AP"] == pytest.approx((6 * ap50 + 4 * 51 / 101) / 10)
    assert out["AP"] == pytest.approx(0.70297, abs=1e-5)
    assert out["AR"] == pytest.approx(0.8)
    assert out["pr_curve"][50] == pytest.approx(1.0)
    assert out["pr_curve"][51] == pytest.approx(2 / 3)
    assert (out["truths"], out["detections"], out["images"]) == (2, 3, 1)


def test_coco_matching_image_by_image_equals_matching_them_all_at_once() -> None:
    rng = np.random.default_rng(3)
    bands = {"range": ContextBands((0.0, 50.0, 100.0), "m")}
    frames = []
    for _ in range(30):
        truth = [
            det((int(x), int(y), int(x) + 9, int(y) + 19), range_m=float(r)) for x, y, r in rng.uniform(0, 300, (3, 3))
        ]
        hyps = [
            det((t.bbox_px[0] + 1, t.bbox_px[1], t.bbox_px[2] + 1, t.bbox_px[3]), float(s))
            for t, s in zip(truth, rng.random(3), strict=True)
        ]
        hyps.append(det((400, 400, 409, 419), float(rng.random())))
        frames.append((truth, hyps))
    at_once, in_steps = CocoScores(object_contexts=bands), CocoScores(object_contexts=bands)
    for k, (truth, hyps) in enumerate(frames):
        for scores in (at_once, in_steps):
            scores.add_image(truth, [{"range": t.range_m} for t in truth], hyps, [{} for _ in hyps], {})
        if k % 7 == 3:
            in_steps.update()
    assert in_steps.evaluate() == at_once.evaluate()


def test_coco_classes_and_an_empty_detector() -> None:
    truth = [det((10, 10, 19, 29)), det((50, 50, 89, 69), cls="vehicle")]
    scores = CocoScores()
    scores.add_image(truth, [{}, {}], [det((50, 50, 89, 69), 0.8, cls="person")], [{}], {})  # right box, wrong class
    out = scores.evaluate()
    assert out["AP50"] == 0.0
    assert out["per_class"]["vehicle"]["AP50"] == 0.0
    empty = CocoScores()
    empty.add_image(truth, [{}, {}], [], [], {})
    assert empty.evaluate()["AP"] == 0.0  # every object missed


def test_coco_by_context_ignores_other_bands_and_reports_empty_ones() -> None:
    sizes = ContextBands((1.0, 8.0, 12.0, 20.0, 32.0, 10000.0), "px")
    near, far = det((10, 10, 29, 49)), det((200, 200, 203, 205))  # sqrt areas 28.3 and 4.9 px
    hit_near = det((10, 10, 29, 49), 0.9)
    false_small = det((400, 400, 402, 404), 0.95)  # 3.9 px: a false box counts in the band of its own size
    scores = CocoScores(
        object_contexts={"pixel_size": sizes, "visible_fraction": ContextBands((0.0, 0.65, 1.0))},
        frame_contexts={"altitude": ContextBands((0.0, 20.0, 40.0), "m")},
    )
    scores.add_image(
        [near, far],
        [{"pixel_size": near.size_px, "visible_fraction": 1.0}, {"pixel_size": far.size_px, "visible_fraction": 0.5}],
        [hit_near, false_small],
        [{"pixel_size": hit_near.size_px, "visible_fraction": math.nan}, {"pixel_size": false_small.size_px}],
        {"altitude": 30.0},
    )
    out = scores.evaluate()
    px = out["by_context"]["pixel_size"]
    assert list(px) == ["1-8 px", "8-12 px", "12-20 px", "20-32 px", ">=32 px"]
    assert px["20-32 px"]["AP50"] == pytest.approx(1.0)  # the near person, found; the small false box is elsewhere
    assert px["1-8 px"]["AP50"] == pytest.approx(0.0)  # the far one missed; the false box is of its size
    assert math.isnan(px["8-12 px"]["AP50"])
    assert px["8-12 px"]["truths"] == 0  # no truth: no AP, still listed
    vis = out["by_context"]["visible_fraction"]
    # Detections have no visible fraction: the false box (0.95) counts in every band, the hit only where its truth
    # is. Fully visible: FP then TP, precision 0.5 at every recall. Occluded: the far person missed, one FP.
    assert vis["0.65-1"]["AP50"] == pytest.approx(0.5)
    assert vis["0-0.65"]["AP50"] == pytest.approx(0.0)
    assert out["by_context"]["altitude"]["20-40 m"]["truths"] == 2
    assert out["by_context"]["altitude"]["0-20 m"]["truths"] == 0


# ---- HOTA ------------------------------------------------------------------------------------------------------------


def test_hota_perfect_tracking_is_one() -> None:
    acc = HotaAccumulator()
    for k in range(10):
        xy = np.array([[k, 0.0], [k, 10.0]])
        acc.update([1, 2], [7, 8], ground_similarity(xy, xy, 5.0))
    r = acc.result()
    assert (r.hota, r.deta, r.assa, r.loca) == pytest.approx((1.0, 1.0, 1.0, 1.0))


def test_hota_an_identity_switch_halves_association() -> None:
    """One object, four frames, the track's id changes after two: every frame is a TP (DetA 1); each of the two
    (truth, track) pairs shares 2 of 4 + 2 - 2 frames, so AssA = 0.5 and HOTA = sqrt(0.5)."""
    acc = HotaAccumulator()
    for k, tid in enumerate((5, 5, 6, 6)):
        xy = np.array([[float(k), 0.0]])
        acc.update([1], [tid], ground_similarity(xy, xy, 5.0))
    r = acc.result()
    assert r.deta == pytest.approx(1.0)
    assert r.assa == pytest.approx(0.5)
    assert r.hota == pytest.approx(math.sqrt(0.5))


def test_hota_localisation_thresholds() -> None:
    """Every track 1.25 m off with a 5 m gate: similarity 0.75, a TP for the 15 thresholds up to 0.75 and a miss plus
    a false track for the 4 above; HOTA = 15/19. LocA is 0.75 where there are TPs and, by the paper's (and
    TrackEval's) convention, 1 at a threshold without any: (15 * 0.75 + 4) / 19."""
    acc = HotaAccumulator()
    for k in range(6):
        acc.update([1], [3], ground_similarity(np.array([[k, 0.0]]), np.array([[k + 1.25, 0.0]]), 5.0))
    r = acc.result()
    assert r.hota == pytest.approx(15 / 19)
    assert r.loca == pytest.approx((15 * 0.75 + 4) / 19)
    assert (r.tp_05, r.fn_05, r.fp_05) == (6, 0, 0)


def test_hota_nothing_tracked_is_zero_and_nothing_to_track_is_undefined() -> None:
    none_tracked = HotaAccumulator()
    none_tracked.update([1], [], np.zeros((1, 0)))
    assert none_tracked.result().hota == 0.0
    empty = HotaAccumulator()
    empty.update([], [], np.zeros((0, 0)))
    assert math.isnan(empty.result().hota)


# ---- the run scorer with a detector -------------------------------------------------------------------------------


def truth_frame(t: float) -> DetectionFrame:
    person = Detection(
        42, "person", 1.0, (300, 200, 320, 240), 60.0, 0.9, (30.0, -80.0, 1.0), (0.0,) * 9, "ground_truth"
    )
    car = Detection(
        57, "vehicle", 1.0, (100, 300, 160, 330), 45.0, 0.4, (-20.0, -60.0, 0.8), (0.0,) * 9, "ground_truth"
    )
    return DetectionFrame(t, "forward", "ground_truth", (person, car))


def placed(box: tuple[int, int, int, int], score: float, xy: tuple[float, float], cls: str = "person") -> Detection:
    cov = (1.0, 0.0, 0.0, 0.0, 1.0, 0.0, 0.0, 0.0, 1.0)
    return Detection(0, cls, score, box, 55.0, math.nan, (xy[0], xy[1], 0.0), cov, "elevation")


def test_the_run_scorer_scores_a_box_only_detector() -> None:
    truth = SceneTruth((-100, -100, 100, 100), objects=np.array([[42.0, 30.0, -80.0, 0.0]]), object_classes=("person",))
    scorer = RunScorer(ScoringSpec(gallery_size=3), truth, detection_source="stand_in")
    scorer.score_threshold = 0.5
    scorer.person_id = 42
    for k in range(20):
        t = 10.0 + 0.1 * k
        scorer.add_pose(PoseSample(t, (0.0, 0.0, 40.0)))
        hyps = [
            placed((301, 201, 321, 241), 0.9, (30.3 + 0.1 * (k % 3), -80.4)),  # the person, placed 0.5-0.64 m off
            placed((500, 100, 510, 125), 0.3 + 0.03 * k, (70.0, -120.0)),  # a false box, weak at first
            Detection(0, "person", 0.8, (20, 20, 24, 30), math.nan, math.nan, NAN3, (), "unplaced:no_surface"),
        ]
        scorer.add_detections(truth_frame(t), is_truth=True)
        scorer.add_detections(
            DetectionFrame(t, "forward", "stand_in", tuple(hyps), (("nan_box", 1),) if k == 3 else ()), is_truth=False
        )
        scorer.add_tracks(TrackFrame(t, "forward", (Track(9, "person", (30.4, -80.3, 0.0)),), 3 * (k + 1), k + 1, 0))
    out = scorer.summary(12.0, coco=True)
    d = out["detection"]
    # at the operating threshold: the person found 20 times, the car never, the false box 13 times (score >= 0.5
    # from k = 7), the unplaced false box 20 times
    assert (d["tp"], d["fn"], d["fp"]) == (20, 20, 13 + 20)
    geo = d["geolocation"]
    assert geo["placed"] == {"elevation": 40}
    assert geo["unplaced"] == {"no_surface": 20}
    assert geo["discarded"] == {"nan_box": 1}
    assert geo["error"]["n"] == 20
    assert geo["error"]["median_m"] == pytest.approx(math.hypot(0.4, 0.4))
    assert geo["error"]["within_95"] == 1.0  # 1 m sigma, errors under 0.65 m
    coco = d["coco"]
    assert coco["per_class"]["vehicle"]["AP50"] == 0.0
    assert coco["per_class"]["person"]["AP50"] > 0.5
    assert set(coco["by_context"]) == {"range", "view_angle", "pixel_size", "visible_fraction", "altitude", "clutter"}
    assert coco["by_context"]["visible_fraction"]["0.2-0.65"]["truths"] == 20  # the car, 40 % visible
    assert set(d["by_context"]) >= {"pixel_size", "visible_fraction"}
    gallery = d["gallery"]
    fps = [g for g in gallery if g["kind"] == "false_positive"]
    misses = [g for g in gallery if g["kind"] == "miss"]
    # one object seen frame after frame is one mistake: the worst view of each
    assert [g["score"] for g in fps] == sorted((g["score"] for g in fps), reverse=True)
    assert len({tuple(g["bbox_px"]) for g in fps}) == len(fps)
    assert misses
    assert all(g["class"] == "vehicle" for g in misses)
    tr = out["tracking"]
    assert tr["hota"] > 0.0
    assert tr["mota"] is not None
    assert tr["inputs"] == {"detections_received": 60, "detections_unplaced": 20, "detections_below_threshold": 0}
    assert out["search"]["confirmed"] is False
    scorer.mark_confirmed(12.0, (30.5, -80.0, 0.0))
    search = scorer.summary(12.0, tracking=False)["search"]
    assert search["correct"] is True
    assert search["error_m"] == pytest.approx(0.5)


def test_gallery_tiles_and_mosaic() -> None:
    gallery = Gallery(size=2)
    for k, score in enumerate((0.6, 0.95, 0.7, 0.9)):
        gallery.false_positive(float(k * 10), "forward", det((10 * k, 5, 10 * k + 4, 15), score))
    kept = gallery.items()
    assert [i.score for i in kept] == [0.95, 0.9]
    image = np.zeros((480, 640, 3), np.uint8)
    tile = crop_tile(image, kept[0])
    assert tile.shape == (128, 128, 3)
    assert tile.max() > 0  # the box and the label are drawn
    assert mosaic({"false_positive": [tile]}, 2).shape == (128, 256, 3)
    assert mosaic({}, 2) is None

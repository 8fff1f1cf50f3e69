"""HOTA (Higher Order Tracking Accuracy), implemented from the paper, on ground positions.

Luiten et al., "HOTA: A Higher Order Metric for Evaluating Multi-Object Tracking", IJCV 129 (2021).
Written here rather than taken from TrackEval (MIT): TrackEval's released code uses ``np.float``, which
numpy 1.24 removed, and is not on PyPI; the definitions are short. A one-off check against TrackEval's
own ``HOTA.eval_sequence`` (numbers in docs/scenarios.md) agrees to 1e-12.

Per localisation threshold ``alpha`` in 0.05, 0.10, ..., 0.95:

* each frame's truth objects and tracks are matched one-to-one (Hungarian) maximising
  ``A_global(gt, tr) * S(gt, tr)``, where ``S`` is the frame's similarity and ``A_global`` is the
  Jaccard overlap of the two whole trajectories (sum over frames of each pair's normalised similarity,
  over the frames either appears in); pairs with ``S >= alpha`` are true positives (TP), the other
  truth objects false negatives (FN), the other tracks false positives (FP);
* ``DetA = |TP| / (|TP| + |FN| + |FP|)``;
* ``AssA = (1/|TP|) sum_{c in TP} |TPA(c)| / (|TPA(c)| + |FNA(c)| + |FPA(c)|)``: for the pair of ids of
  each TP, how much of both trajectories that pair shares (``matches / (gt frames + track frames - matches)``);
* ``HOTA_alpha = sqrt(DetA * AssA)``; ``LocA`` is the mean ``S`` of the TPs.

HOTA, DetA, AssA and LocA are the means over the 19 thresholds. The similarity of a truth object and a
track on the ground is ``max(0, 1 - d / gate_m)`` (``d`` the horizontal distance): 1 on top of it, 0 at
the gate, so ``alpha = 0.5`` asks for half the gate.
"""

from __future__ import annotations

import math
from collections.abc import Sequence
from dataclasses import dataclass

import numpy as np
import numpy.typing as npt
from scipy.optimize import linear_sum_assignment

from uav_scenarios.errors import ScoringError

__all__ = ["ALPHAS", "HotaAccumulator", "HotaResult", "ground_similarity"]

FloatArray = npt.NDArray[np.float64]

#: Localisation thresholds, as in the paper.
ALPHAS = np.arange(1, 20) * 0.05
_EPS = float(np.finfo(np.float64).eps)


def ground_similarity(truth_xy_m: npt.ArrayLike, track_xy_m: npt.ArrayLike, gate_m: float) -> FloatArray:
    """``S = max(0, 1 - d / gate_m)`` for every (truth, track) pair of horizontal positions, ``(N, M)``."""
    gt = np.asarray(truth_xy_m, dtype=np.float64).reshape(-1, 2)
    tr = np.asarray(track_xy_m, dtype=np.float64).reshape(-1, 2)
    d = np.linalg.norm(gt[:, None, :] - tr[None, :, :], axis=2)
    return np.asarray(np.clip(1.0 - d / gate_m, 0.0, 1.0), dtype=np.float64)


@dataclass(frozen=True)
class HotaResult:
    hota: float
    deta: float
    assa: float
    loca: float
    #: Detection recall and precision, association recall and precision (means over alpha).
    detre: float
    detpr: float
    assre: float
    asspr: float
    #: Totals at alpha = 0.5.
    tp_05: int
    fn_05: int
    fp_05: int
    frames: int

    def as_dict(self) -> dict[str, float]:
        return {k: float(v) for k, v in self.__dict__.items()}


class HotaAccumulator:
    """Frames in, HOTA out. Ids are any integers; each frame gives the truth ids, the track ids and the
    similarity matrix between them (rows truth, columns tracks, values in [0, 1])."""

    def __init__(self) -> None:
        self._frames: list[tuple[npt.NDArray[np.int64], npt.NDArray[np.int64], FloatArray]] = []
        self._result: HotaResult | None = None

    @property
    def frames(self) -> int:
        return len(self._frames)

    def update(self, truth_ids: Sequence[int], track_ids: Sequence[int], similarity: npt.ArrayLike) -> None:
        """One frame.

        Raises:
            ScoringError: the similarity's shape does not match the ids, or a value is outside [0, 1].
        """
        gt = np.asarray(truth_ids, dtype=np.int64).reshape(-1)
        tr = np.asarray(track_ids, dtype=np.int64).reshape(-1)
        sim = (
            np.asarray(similarity, dtype=np.float64).reshape(gt.size, tr.size)
            if gt.size * tr.size
            else np.zeros((gt.size, tr.size))
        )
        if sim.shape != (gt.size, tr.size):
            msg = f"similarity is {sim.shape} for {gt.size} truth objects and {tr.size} tracks"
            raise ScoringError(msg)
        if sim.size and not (np.all(np.isfinite(sim)) and sim.min() >= 0.0 and sim.max() <= 1.0):
            msg = "similarity values must be finite and within [0, 1]"
            raise ScoringError(msg)
        self._frames.append((gt, tr, sim))
        self._result = None

    def result(self) -> HotaResult:
        """HOTA over every frame so far (NaN when there was nothing to track and nothing tracked)."""
        if self._result is None:
            self._result = self._compute()
        return self._result

    def _compute(self) -> HotaResult:  # noqa: PLR0915 - the paper's two passes, written out
        frames = self._frames
        n_alpha = ALPHAS.size
        n_gt = sum(f[0].size for f in frames)
        n_tr = sum(f[1].size for f in frames)
        nan = math.nan
        if n_gt == 0 and n_tr == 0:
            return HotaResult(nan, nan, nan, nan, nan, nan, nan, nan, 0, 0, 0, len(frames))
        if n_gt == 0 or n_tr == 0:
            # Nothing can match: detection and association accuracy are 0.
            return HotaResult(0.0, 0.0, 0.0, 1.0, 0.0, 0.0, 0.0, 0.0, 0, n_gt, n_tr, len(frames))
        gt_index = {int(i): k for k, i in enumerate(sorted({int(i) for f in frames for i in f[0]}))}
        tr_index = {int(i): k for k, i in enumerate(sorted({int(i) for f in frames for i in f[1]}))}
        local = [
            (
                np.array([gt_index[int(i)] for i in g], dtype=np.int64),
                np.array([tr_index[int(i)] for i in t], dtype=np.int64),
                s,
            )
            for g, t, s in frames
        ]
        # Pass 1: how much each truth trajectory and each track overlap over the whole sequence.
        overlap = np.zeros((len(gt_index), len(tr_index)))
        gt_frames = np.zeros(len(gt_index))
        tr_frames = np.zeros(len(tr_index))
        for g, t, s in local:
            gt_frames[g] += 1
            tr_frames[t] += 1
            if g.size and t.size:
                union = s.sum(axis=0)[None, :] + s.sum(axis=1)[:, None] - s
                norm = np.divide(s, union, out=np.zeros_like(s), where=union > _EPS)
                overlap[np.ix_(g, t)] += norm
        alignment = overlap / (gt_frames[:, None] + tr_frames[None, :] - overlap)
        # Pass 2: per frame, the best one-to-one matching under that alignment, counted per threshold.
        tp = np.zeros(n_alpha)
        fn = np.zeros(n_alpha)
        fp = np.zeros(n_alpha)
        loc = np.zeros(n_alpha)
        pair_matches = np.zeros((n_alpha, len(gt_index), len(tr_index)))
        alphas = ALPHAS[:, None] - _EPS
        for g, t, s in local:
            if g.size == 0 or t.size == 0:
                fn += g.size
                fp += t.size
                continue
            rows, cols = linear_sum_assignment(-(alignment[np.ix_(g, t)] * s))
            matched_sim = s[rows, cols]
            ok = matched_sim[None, :] >= alphas  # (alpha, match): a TP at that threshold
            n = ok.sum(axis=1)
            tp += n
            fn += g.size - n
            fp += t.size - n
            loc += (ok * matched_sim[None, :]).sum(axis=1)
            np.add.at(pair_matches, (np.arange(n_alpha)[:, None], g[rows][None, :], t[cols][None, :]), ok)
        m = pair_matches
        denom = np.maximum(1.0, gt_frames[None, :, None] + tr_frames[None, None, :] - m)
        tp_safe = np.maximum(1.0, tp)
        assa = np.sum(m * m / denom, axis=(1, 2)) / tp_safe
        assre = np.sum(m * m / np.maximum(1.0, gt_frames[None, :, None]), axis=(1, 2)) / tp_safe
        asspr = np.sum(m * m / np.maximum(1.0, tr_frames[None, None, :]), axis=(1, 2)) / tp_safe
        deta = tp / np.maximum(1.0, tp + fn + fp)
        detre = tp / np.maximum(1.0, tp + fn)
        detpr = tp / np.maximum(1.0, tp + fp)
        hota = np.sqrt(deta * assa)
        loca = np.maximum(1e-10, loc) / np.maximum(1e-10, tp)
        half = int(np.argmin(np.abs(ALPHAS - 0.5)))
        return HotaResult(
            hota=float(hota.mean()),
            deta=float(deta.mean()),
            assa=float(assa.mean()),
            loca=float(loca.mean()),
            detre=float(detre.mean()),
            detpr=float(detpr.mean()),
            assre=float(assre.mean()),
            asspr=float(asspr.mean()),
            tp_05=int(tp[half]),
            fn_05=int(fn[half]),
            fp_05=int(fp[half]),
            frames=len(frames),
        )

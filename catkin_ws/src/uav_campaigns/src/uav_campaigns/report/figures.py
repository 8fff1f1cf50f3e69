"""The campaign report's figures: per key metric, the runs of every arm (box + points) and the paired
differences against the reference arm (each seed's difference, the mean and its confidence interval)."""

from __future__ import annotations

import math
from collections.abc import Mapping, Sequence
from pathlib import Path
from typing import Any

import matplotlib as mpl

mpl.use("Agg")
import matplotlib.pyplot as plt
import numpy as np

from uav_campaigns.core.table import PairedRow

__all__ = ["metric_figure"]

_COLORS = ("#2563eb", "#dc2626", "#059669", "#d97706", "#7c3aed", "#0891b2", "#be185d", "#4b5563")


def _num(v: Any) -> float:
    try:
        return float(v)
    except (TypeError, ValueError):
        return math.nan


def metric_figure(
    metric: str,
    arms: Sequence[str],
    rows: Sequence[Mapping[str, Any]],
    paired: Sequence[PairedRow],
    path: Path,
) -> Path | None:
    """Two panels for ``metric``: box and points per arm; paired differences against the reference arm.

    Returns:
        the PNG written, or None when no done run has the metric.
    """
    done = [r for r in rows if r.get("status") == "done"]
    values = {arm: np.array([_num(r.get(metric)) for r in done if r.get("arm") == arm]) for arm in arms}
    values = {a: v[np.isfinite(v)] for a, v in values.items()}
    if not any(v.size for v in values.values()):
        return None
    fig, (ax1, ax2) = plt.subplots(1, 2, figsize=(11, 3.6), gridspec_kw={"width_ratios": [1.2, 1]})
    jitter = np.random.default_rng(0)
    data = [values[a] if values[a].size else np.array([np.nan]) for a in arms]
    ax1.boxplot(data, showfliers=False, widths=0.5, medianprops={"color": "#111"})
    for i, arm in enumerate(arms):
        v = values[arm]
        ax1.scatter(
            i + 1 + jitter.uniform(-0.12, 0.12, v.size), v, s=18, color=_COLORS[i % len(_COLORS)], alpha=0.8, zorder=3
        )
        ax1.text(i + 1, 1.0, f"n={v.size}", transform=ax1.get_xaxis_transform(), ha="center", va="bottom", fontsize=8)
    ax1.set_xticks(range(1, len(arms) + 1), list(arms), rotation=15 if len(arms) > 3 else 0)
    ax1.set_title(f"{metric} per run", fontsize=10, pad=14)
    ax1.grid(axis="y", alpha=0.3)

    comps = [p for p in paired if p.metric == metric]
    ref = comps[0].reference if comps else (arms[0] if arms else "")
    by_arm: dict[str, dict[tuple[Any, Any], float]] = {}
    for r in done:
        by_arm.setdefault(str(r.get("arm")), {})[(r.get("seed"), r.get("repeat"))] = _num(r.get(metric))
    for i, comp in enumerate(comps):
        ref_vals, other = by_arm.get(ref, {}), by_arm.get(comp.arm, {})
        diffs = np.array([other[k] - ref_vals[k] for k in sorted(set(ref_vals) & set(other), key=str)])
        diffs = diffs[np.isfinite(diffs)]
        color = _COLORS[(arms.index(comp.arm) if comp.arm in arms else i) % len(_COLORS)]
        ax2.scatter(diffs, i + jitter.uniform(-0.1, 0.1, diffs.size), s=16, color=color, alpha=0.6)
        c = comp.comparison
        if c.n and math.isfinite(c.mean_diff):
            lo, hi = c.ci_low, c.ci_high
            if math.isfinite(lo) and math.isfinite(hi):
                ax2.errorbar(
                    c.mean_diff, i, xerr=[[c.mean_diff - lo], [hi - c.mean_diff]], fmt="D", color="#111", capsize=4
                )
            else:
                ax2.plot(c.mean_diff, i, "D", color="#111")
    ax2.axvline(0.0, color="#888", lw=1)
    labels = []
    for row in comps:
        p = row.comparison.wilcoxon.p_value
        pair = f"{row.arm} − {row.reference}\nn={row.comparison.n}"
        labels.append(pair + (f", p={p:.2g}" if math.isfinite(p) else ""))
    ax2.set_yticks(range(len(comps)), labels, fontsize=8)
    ax2.set_ylim(-0.6, max(0.6, len(comps) - 0.4))
    ax2.set_title("paired difference (same seed): runs, mean and CI", fontsize=10)
    ax2.grid(axis="x", alpha=0.3)
    fig.tight_layout()
    path.parent.mkdir(parents=True, exist_ok=True)
    fig.savefig(path, dpi=90)
    plt.close(fig)
    return path

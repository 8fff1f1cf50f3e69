"""The training curve as a PNG (matplotlib, Agg)."""

from __future__ import annotations

import json
from pathlib import Path

__all__ = ["plot_curve"]


def plot_curve(curve_jsonl: Path, png: Path) -> None:
    """Plot the total, heatmap, offset and size losses per step of ``curve_jsonl`` into ``png``."""
    import matplotlib  # noqa: PLC0415

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt  # noqa: PLC0415

    points = [json.loads(line) for line in curve_jsonl.read_text().splitlines() if line.strip()]
    fig, ax = plt.subplots(figsize=(7, 4), dpi=100)
    steps = [p["step"] for p in points]
    for key in ("loss", "heat", "offset", "size"):
        ax.plot(steps, [p[key] for p in points], label=key)
    ax.set_yscale("log")
    ax.set_xlabel("step")
    ax.set_ylabel("training loss (mean over the logged steps)")
    ax.set_title("uav-train-detector: training curve")
    ax.grid(True, alpha=0.3)
    ax.legend()
    fig.tight_layout()
    fig.savefig(png)
    plt.close(fig)

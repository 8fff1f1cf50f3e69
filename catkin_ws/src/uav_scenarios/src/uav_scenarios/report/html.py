"""The run report: one self-contained HTML page (PNG figures embedded) per run."""

from __future__ import annotations

import base64
import html
import math
from collections.abc import Mapping
from dataclasses import dataclass
from pathlib import Path
from typing import Any

from uav_scenarios.errors import ReportError
from uav_scenarios.report.data import RunData
from uav_scenarios.report.figures import FIGURES

__all__ = ["Report", "build_report", "faults_table", "flatten_metrics"]

_HEADLINES = (
    ("time.duration_s", "run length (sim s)"),
    ("time.complete_s", "time to complete (s)"),
    ("coverage.mapped_pct", "scene mapped (%)"),
    ("coverage.efficiency", "coverage efficiency (of swath limit)"),
    ("map_accuracy.iou", "map IoU"),
    ("flight.distance_m", "distance flown (m)"),
    ("battery.used_mah", "battery used (mAh)"),
    ("battery.used_pct", "battery used (%)"),
    ("flight.agl_min_m", "min altitude above ground (m)"),
    ("collisions.count", "collisions"),
    ("detection.person_first_detected.t_s", "person first detected (s)"),
    ("detection.coco.AP50", "detector AP50"),
    ("detection.coco.AP", "detector AP (IoU .50:.95)"),
    ("detection.precision", "precision at threshold"),
    ("detection.recall", "recall at threshold"),
    ("detection.geolocation.error.median_m", "geolocation median error (m)"),
    ("tracking.mota", "tracking MOTA"),
    ("tracking.idf1", "tracking IDF1"),
    ("tracking.hota", "tracking HOTA"),
    ("moving_objects.movers", "moving people and vehicles"),
    ("moving_objects.cleared_fraction", "their trail voxels the map cleared (fraction)"),
)

_CSS = """
body{font-family:system-ui,-apple-system,Segoe UI,Roboto,sans-serif;margin:0;background:#f6f7f9;color:#222}
header{background:#1f2a37;color:#fff;padding:18px 28px}
header h1{margin:0;font-size:22px} header p{margin:4px 0 0;color:#cfd6df;font-size:14px}
main{max-width:1200px;margin:0 auto;padding:18px 28px}
section{background:#fff;border-radius:8px;box-shadow:0 1px 3px rgba(0,0,0,.08);margin:18px 0;padding:14px 20px}
h2{font-size:17px;margin:4px 0 12px}
img{max-width:100%;height:auto;display:block;margin:auto}
.cards{display:grid;grid-template-columns:repeat(auto-fill,minmax(170px,1fr));gap:10px}
.card{background:#f0f3f7;border-radius:6px;padding:10px} .card b{display:block;font-size:20px}
.card span{font-size:12px;color:#555}
table{border-collapse:collapse;width:100%;font-size:13px}
td,th{border-bottom:1px solid #e5e7eb;padding:3px 8px;text-align:left}
td.v{font-family:ui-monospace,monospace;text-align:right}
pre{background:#f0f3f7;padding:10px;overflow:auto;font-size:12px}
.note{color:#8a5a00;background:#fff6e0;padding:8px 12px;border-radius:6px;margin:6px 0}
.missing{color:#777;font-style:italic}
"""


@dataclass(frozen=True)
class Report:
    html_path: Path
    figures: dict[str, Path]
    missing: tuple[str, ...]


def flatten_metrics(data: Mapping[str, Any], prefix: str = "") -> list[tuple[str, Any]]:
    """Nested metrics -> ``[("coverage.mapped_pct", 12.3), ...]`` (lists of events skipped)."""
    out: list[tuple[str, Any]] = []
    for key, value in data.items():
        name = f"{prefix}{key}"
        if isinstance(value, Mapping):
            out.extend(flatten_metrics(value, name + "."))
        elif not isinstance(value, list):
            out.append((name, value))
    return out


def _fmt(value: Any) -> str:
    if value is None or (isinstance(value, float) and math.isnan(value)):
        return "–"
    if isinstance(value, float):
        return f"{value:.4g}" if abs(value) < 1e5 else f"{value:.0f}"
    return html.escape(str(value))


def _lookup(data: Mapping[str, Any], dotted: str) -> Any:
    cur: Any = data
    for part in dotted.split("."):
        if not isinstance(cur, Mapping) or part not in cur:
            return None
        cur = cur[part]
    return cur


def _img_tag(path: Path, alt: str) -> str:
    data = base64.b64encode(path.read_bytes()).decode("ascii")
    return f'<img alt="{html.escape(alt)}" src="data:image/png;base64,{data}">'


def _context_table(summary: Mapping[str, Any]) -> str:
    """One row per context band: COCO AP/AP50/AR and counts, precision/recall at the operating threshold,
    MOTA/IDF1/HOTA. Every band is listed, those without truth objects too."""
    det = summary.get("detection") or {}
    coco = (det.get("coco") or {}).get("by_context") or {}
    counts = det.get("by_context") or {}
    tracking = (summary.get("tracking") or {}).get("by_context") or {}
    names = [
        n
        for n in ("pixel_size", "range", "view_angle", "visible_fraction", "altitude", "clutter")
        if n in coco or n in counts
    ]
    if not names:
        return ""
    head = (
        "<tr><th>context</th><th>band</th><th>truths</th><th>detections</th><th>AP</th><th>AP50</th><th>AR</th>"
        "<th>precision</th><th>recall</th><th>MOTA</th><th>IDF1</th><th>HOTA</th></tr>"
    )
    rows = []
    for name in names:
        bands = list(dict.fromkeys([*(coco.get(name) or {}), *(counts.get(name) or {}), *(tracking.get(name) or {})]))
        for band in bands:
            c = (coco.get(name) or {}).get(band) or {}
            k = (counts.get(name) or {}).get(band) or {}
            tr = (tracking.get(name) or {}).get(band) or {}
            cells = [c.get("truths"), c.get("detections"), c.get("AP"), c.get("AP50"), c.get("AR")]
            cells += [k.get("precision"), k.get("recall"), tr.get("mota"), tr.get("idf1"), tr.get("hota")]
            tds = "".join(f"<td class=v>{_fmt(v)}</td>" for v in cells)
            rows.append(f"<tr><td>{html.escape(name)}</td><td>{html.escape(band)}</td>{tds}</tr>")
    note = (
        '<p class="missing">AP, AP50, AR: COCO (pycocotools) over every score; precision and recall at the operating '
        "threshold; a band without truth objects has no AP; false positives without a value of the context "
        "(no visible fraction, unplaced) count in every band of it.</p>"
    )
    return f"<table>{head}{''.join(rows)}</table>{note}"


def faults_table(summary: Mapping[str, Any]) -> str:
    """The run's scripted faults (metrics ``faults``) as an HTML table: when, what, the answer, what followed and,
    for a camera fault, its camera's frames; "" without faults."""
    faults = summary.get("faults") if isinstance(summary, Mapping) else None
    if not isinstance(faults, list) or not faults:
        return ""
    rows = []
    for f in faults:
        if not isinstance(f, Mapping):
            continue
        inst = f" {f.get('instance')}" if f.get("instance") else ""
        what = f"{f.get('unit')}{inst} {f.get('type')}" + (" (end of the fault)" if f.get("clear") else "")
        answer = f"{f.get('result')}" + (f": {f.get('detail')}" if f.get("detail") else "")
        followed = "<br>".join(
            f"+{_fmt(c.get('after_s'))} s {html.escape(str(c.get('what')))}"
            for c in f.get("followed", [])
            if isinstance(c, Mapping)
        )
        cam = f.get("camera")
        frames = (
            f"{cam.get('frames')} frames ({_fmt(cam.get('rate_hz'))} Hz, before {_fmt(cam.get('rate_before_hz'))} Hz), "
            f"{cam.get('distinct_images')} distinct, {cam.get('noise_frames')} noise"
            if isinstance(cam, Mapping)
            else ""
        )
        rows.append(
            f"<tr><td class=v>{_fmt(f.get('run_t_s'))}</td><td>{html.escape(what)}</td>"
            f"<td>{html.escape(answer)}</td><td>{followed or '–'}</td><td>{html.escape(frames) or '–'}</td></tr>"
        )
    return (
        "<table><tr><th>run t (s)</th><th>fault</th><th>answer</th><th>what followed</th>"
        f"<th>camera frames until the next fault</th></tr>{''.join(rows)}</table>"
    )


def build_report(run: RunData, out_dir: Path, *, versions: Mapping[str, str] | None = None) -> Report:
    """Draw every figure into ``out_dir/figures`` and write ``out_dir/report.html``.

    Figures without data are listed as missing (with the reason from ``run.notes``)
    rather than failing the report.

    Raises:
        ReportError: ``out_dir`` cannot be written.
    """
    fig_dir = out_dir / "figures"
    try:
        fig_dir.mkdir(parents=True, exist_ok=True)
    except OSError as err:
        msg = f"cannot create the report folder {fig_dir}: {err.strerror}"
        raise ReportError(msg) from err
    figures: dict[str, Path] = {}
    missing: list[str] = []
    for fig_id, (_title, draw) in FIGURES.items():
        drawn = draw(run, fig_dir / f"{fig_id}.png")
        if drawn is None:
            missing.append(fig_id)
        else:
            figures[fig_id] = drawn
    parts = [
        f"<!DOCTYPE html><html lang=en><head><meta charset=utf-8><title>{html.escape(run.name)} run report</title>"
    ]
    parts.append(f"<style>{_CSS}</style></head><body>")
    duration = _lookup(run.summary, "time.duration_s")
    stop = html.escape(run.stop_reason or "unknown")
    sub = f"stop: {stop} · {_fmt(duration)} simulated seconds · bag {html.escape(run.bag_path)}"
    parts.append(f"<header><h1>Run report: {html.escape(run.name)}</h1><p>{sub}</p></header><main>")
    for note in run.notes:
        parts.append(f'<div class="note">{html.escape(note)}</div>')
    cards = "".join(
        f'<div class="card"><b>{_fmt(_lookup(run.summary, key))}</b><span>{html.escape(label)}</span></div>'
        for key, label in _HEADLINES
    )
    parts.append(f'<section><h2>Summary</h2><div class="cards">{cards}</div></section>')
    for fig_id, (title, _draw) in FIGURES.items():
        body = (
            _img_tag(figures[fig_id], title)
            if fig_id in figures
            else '<p class="missing">no data for this figure in the run</p>'
        )
        parts.append(f'<section id="{fig_id}"><h2>{html.escape(title)}</h2>{body}</section>')
    context_table = _context_table(run.summary)
    if context_table:
        parts.append(f'<section id="by_context"><h2>Detector and tracker by context</h2>{context_table}</section>')
    rows = "".join(
        f"<tr><td>{html.escape(k)}</td><td class=v>{_fmt(v)}</td></tr>" for k, v in flatten_metrics(run.summary)
    )
    parts.append(
        f'<section id="metrics"><h2>Metrics</h2><table><tr><th>metric</th><th>value</th></tr>{rows}</table></section>'
    )
    faults = faults_table(run.summary)
    if faults:
        parts.append(f'<section id="faults"><h2>Scripted faults</h2>{faults}</section>')
    events = run.summary.get("events", []) if isinstance(run.summary, Mapping) else []
    if events:
        ev_rows = "".join(
            f"<tr><td class=v>{_fmt(e.get('t_s'))}</td><td>{html.escape(str(e.get('what')))}</td></tr>" for e in events
        )
        parts.append(
            '<section id="events"><h2>Events</h2><table><tr><th>t (s)</th><th>event</th></tr>'
            f"{ev_rows}</table></section>"
        )
    ver_rows = "".join(
        f"<tr><td>{html.escape(k)}</td><td>{html.escape(v)}</td></tr>" for k, v in sorted((versions or {}).items())
    )
    parts.append(f'<section id="versions"><h2>Versions</h2><table>{ver_rows}</table></section>')
    parts.append(
        '<section id="config"><h2>Scenario configuration</h2>'
        f"<pre>{html.escape(run.scenario_yaml or '(not recorded)')}</pre></section>"
    )
    parts.append("</main></body></html>")
    html_path = out_dir / "report.html"
    try:
        html_path.write_text("\n".join(parts), encoding="utf-8")
    except OSError as err:
        msg = f"cannot write {html_path}: {err.strerror}"
        raise ReportError(msg) from err
    return Report(html_path, figures, tuple(missing))

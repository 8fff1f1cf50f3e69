"""The campaign report: one self-contained ``report.html`` (PNG figures embedded) over the tables."""

from __future__ import annotations

import base64
import html
import math
import re
from collections.abc import Mapping, Sequence
from pathlib import Path
from typing import Any

from uav_campaigns.core.config import Campaign
from uav_campaigns.core.manifest import fold
from uav_campaigns.report.figures import metric_figure
from uav_campaigns.shell.results import Tables
from uav_campaigns.shell.store import CampaignDir

__all__ = ["build_report"]

_CSS = """
body{font-family:system-ui,-apple-system,Segoe UI,Roboto,sans-serif;margin:0;background:#f6f7f9;color:#222}
header{background:#1f2a37;color:#fff;padding:18px 28px}
header h1{margin:0;font-size:22px} header p{margin:4px 0 0;color:#cfd6df;font-size:14px}
main{max-width:1250px;margin:0 auto;padding:18px 28px}
section{background:#fff;border-radius:8px;box-shadow:0 1px 3px rgba(0,0,0,.08);margin:18px 0;padding:14px 20px}
h2{font-size:17px;margin:4px 0 12px} h3{font-size:14px;margin:14px 0 6px}
img{max-width:100%;height:auto;display:block;margin:6px auto}
table{border-collapse:collapse;width:100%;font-size:13px}
td,th{border-bottom:1px solid #e5e7eb;padding:3px 8px;text-align:left;vertical-align:top}
td.v{font-family:ui-monospace,monospace;text-align:right;white-space:nowrap}
pre{background:#f0f3f7;padding:10px;overflow:auto;font-size:12px}
.note{color:#555;font-size:13px} .bad{color:#b91c1c} .good{color:#047857}
.cards{display:grid;grid-template-columns:repeat(auto-fill,minmax(150px,1fr));gap:10px}
.card{background:#f0f3f7;border-radius:6px;padding:10px} .card b{display:block;font-size:20px}
.card span{font-size:12px;color:#555}
"""


def _fmt(v: Any, digits: int = 4) -> str:
    if v is None or v == "":
        return "–"
    if isinstance(v, float):
        if not math.isfinite(v):
            return "–"
        return f"{v:.{digits}g}"
    return html.escape(str(v))


def _img(path: Path) -> str:
    data = base64.b64encode(path.read_bytes()).decode()
    return f'<img src="data:image/png;base64,{data}" alt="{html.escape(path.stem)}">'


def _slug(text: str) -> str:
    return re.sub(r"[^A-Za-z0-9_.-]+", "_", text)


def _table(header: Sequence[str], rows: Sequence[Sequence[str]], numeric_from: int = 1) -> str:
    head = "".join(f"<th>{html.escape(h)}</th>" for h in header)
    body = "".join(
        "<tr>"
        + "".join(f'<td class="v">{c}</td>' if i >= numeric_from else f"<td>{c}</td>" for i, c in enumerate(r))
        + "</tr>"
        for r in rows
    )
    return f"<table><tr>{head}</tr>{body}</table>"


def _key_metrics(campaign: Campaign, tables: Tables) -> list[str]:
    present = {s.metric for s in tables.summary if s.summary.n}
    return [m for m in campaign.key_metrics if m in present]


def _summary_section(campaign: Campaign, tables: Tables, metrics: Sequence[str], title: str) -> str:
    conf = round(100 * campaign.statistics.confidence)
    rows = []
    for s in tables.summary:
        if s.metric not in metrics:
            continue
        m = s.summary
        rows.append(
            [
                html.escape(s.metric),
                html.escape(s.arm),
                str(m.n),
                _fmt(m.mean),
                _fmt(m.std),
                _fmt(m.median),
                f"[{_fmt(m.ci_low)}, {_fmt(m.ci_high)}]",
            ]
        )
    rows.sort(key=lambda r: metrics.index(html.unescape(r[0])) if html.unescape(r[0]) in metrics else 0)
    header = ["metric", "arm", "n", "mean", "std", "median", f"{conf} % CI of the mean (bootstrap)"]
    return f"<h3>{html.escape(title)}</h3>" + _table(header, rows, numeric_from=2)


def _paired_section(campaign: Campaign, tables: Tables, metrics: Sequence[str]) -> str:
    conf = round(100 * campaign.statistics.confidence)
    rows = []
    for p in tables.paired:
        if p.metric not in metrics:
            continue
        c = p.comparison
        pv = c.wilcoxon.p_value
        cls = "bad" if math.isfinite(pv) and pv < 0.05 else ""
        rows.append(
            [
                html.escape(p.metric),
                f"{html.escape(p.arm)} − {html.escape(p.reference)}",
                str(c.n),
                _fmt(c.mean_diff),
                f"[{_fmt(c.ci_low)}, {_fmt(c.ci_high)}]",
                f'<span class="{cls}">{_fmt(pv, 3)}</span>',
                html.escape(c.wilcoxon.method),
            ]
        )
    header = ["metric", "difference", "pairs", "mean difference", f"{conf} % CI", "Wilcoxon p", "p method"]
    return _table(header, rows, numeric_from=2)


def _success_section(campaign: Campaign, tables: Tables) -> str:
    conf = round(100 * campaign.statistics.confidence)
    rows = [
        [
            html.escape(s.criterion),
            html.escape(s.arm),
            f"{s.successes}/{s.n}",
            _fmt(s.rate, 3),
            f"[{_fmt(s.ci_low, 3)}, {_fmt(s.ci_high, 3)}]",
            f"<code>{html.escape(s.rule)}</code>",
        ]
        for s in tables.success
    ]
    return _table(["criterion", "arm", "runs", "rate", f"{conf} % Wilson interval", "rule"], rows, numeric_from=2)


def _runs_section(rows: Sequence[Mapping[str, Any]]) -> str:
    out = []
    for r in rows:
        report = r.get("report") or ""
        link = f'<a href="{html.escape(str(report))}">report</a>' if report else "–"
        status = str(r.get("status", ""))
        cls = "good" if status == "done" else "bad" if status == "failed" else ""
        out.append(
            [
                html.escape(str(r.get("arm"))),
                str(r.get("seed")),
                str(r.get("repeat")),
                f'<span class="{cls}">{html.escape(status)}</span> {html.escape(str(r.get("reason") or ""))}',
                str(r.get("attempts")),
                str(r.get("orphaned")),
                html.escape(str(r.get("stop_reason") or "")),
                _fmt(r.get("wall_s"), 3),
                _fmt(r.get("sim_s"), 3),
                link,
                f"<code>{html.escape(str(r.get('config_hash', ''))[:12])}</code>",
            ]
        )
    header = ["arm", "seed", "repeat", "status", "tries", "orphaned", "stop", "wall s", "sim s", "run", "config"]
    return _table(header, out, numeric_from=99)


def _problems_section(cdir: CampaignDir, labels: Mapping[str, str]) -> str:
    items = []
    for key, st in fold(cdir.events()).items():
        if key not in labels:
            continue
        for ev in st.history:
            if ev.get("event") == "orphaned" or ev.get("status") == "failed":
                what = "orphaned" if ev.get("event") == "orphaned" else f"failed: {ev.get('reason')}"
                tail = html.escape(str(ev.get("log_tail") or "")[-1500:])
                logs = html.escape(str(ev.get("run_path") or ev.get("run_dir") or ""))
                items.append(
                    f"<h3>{html.escape(labels[key])} try {ev.get('try')}: {html.escape(what)}</h3>"
                    f"<p class='note'>{html.escape(str(ev.get('reason', '')))} — worker "
                    f"{html.escape(str(ev.get('worker')))}, logs <code>{logs}</code></p>"
                    + (f"<pre>{tail}</pre>" if tail else "")
                )
    return "".join(items) or "<p class='note'>No run failed, hung or lost its worker.</p>"


def build_report(cdir: CampaignDir, campaign: Campaign, tables: Tables, campaign_text: str) -> Path:
    """Write ``DIR/report.html`` (and its figures in ``DIR/figures/``); returns its path."""
    metrics = _key_metrics(campaign, tables)
    arms = list(campaign.arm_names)
    figs = []
    for m in metrics:
        path = metric_figure(m, arms, tables.rows, tables.paired, cdir.path / "figures" / f"{_slug(m)}.png")
        if path is not None:
            figs.append(f"<h3>{html.escape(m)}</h3>{_img(path)}")
    n = len(tables.rows)
    counts = {s: sum(1 for r in tables.rows if r.get("status") == s) for s in ("done", "failed", "pending")}
    cards = "".join(
        f"<div class='card'><b>{v}</b><span>{html.escape(k)}</span></div>"
        for k, v in [
            ("runs planned", n),
            ("done", counts["done"]),
            ("failed (given up)", counts["failed"]),
            ("not yet run", counts["pending"]),
            ("arms", len(arms)),
            ("seeds x repeats", f"{len(campaign.seeds)} x {campaign.repeats}"),
        ]
    )
    all_metrics = sorted({s.metric for s in tables.summary})
    ref = campaign.reference_arm
    limit = html.escape(str(campaign.time_limit_s or "the scenario's"))
    labels = {str(r["key"]): f"{r['arm']}/s{r['seed']}/r{r['repeat']}" for r in tables.rows}
    problems = _problems_section(cdir, labels)
    body = f"""
<header><h1>Campaign {html.escape(campaign.name)}</h1>
<p>{html.escape(campaign.description)}</p>
<p>scenario {html.escape(str(campaign.scenario))} · time {html.escape(campaign.time.mode.value)}
{"deterministic" if campaign.time.deterministic else ""} · {limit} s simulated per run</p></header>
<main>
<section><h2>Runs</h2><div class="cards">{cards}</div>
<p class="note">Statistics use the runs whose status is <i>done</i>. Intervals: percentile bootstrap of the mean
({campaign.statistics.resamples} resamples, seed {campaign.statistics.seed}); paired differences are
other arm − {html.escape(ref)} on the same seed and repeat, with the two-sided Wilcoxon signed-rank test;
success rates with Wilson score intervals.</p></section>
<section><h2>Key metrics per arm</h2>{_summary_section(campaign, tables, metrics, "summary")}</section>
<section><h2>Success rates</h2>{_success_section(campaign, tables)}</section>
<section><h2>Paired comparisons against {html.escape(ref)}</h2>{_paired_section(campaign, tables, metrics)}</section>
<section><h2>Figures</h2>{"".join(figs) or "<p class='note'>No finished run yet.</p>"}</section>
<section><h2>Every run</h2>{_runs_section(tables.rows)}</section>
<section><h2>Failures, hangs and lost workers</h2>{problems}</section>
<section><h2>All metrics</h2><details><summary>summary of every metric ({len(all_metrics)})</summary>
{_summary_section(campaign, tables, all_metrics, "every metric")}
<h3>paired comparisons of every metric</h3>{_paired_section(campaign, tables, all_metrics)}</details></section>
<section><h2>Campaign file</h2><pre>{html.escape(campaign_text)}</pre></section>
</main>"""
    page = (
        "<!DOCTYPE html><html><head><meta charset='utf-8'>"
        f"<title>Campaign {html.escape(campaign.name)}</title><style>{_CSS}</style></head><body>{body}</body></html>"
    )
    out = cdir.path / "report.html"
    tmp = out.with_suffix(".html.tmp")
    tmp.write_text(page)
    tmp.replace(out)
    return out

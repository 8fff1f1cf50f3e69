"""The campaign directory: identity and manifest, the tables and the report rebuilt from the run folders."""

from __future__ import annotations

import csv
import io
import json
import math
import re
from pathlib import Path
from typing import Any

import pytest
from builders import campaign_file, metrics, write_run

from uav_campaigns.cli.campaign import _plan, main
from uav_campaigns.core.config import load_campaign
from uav_campaigns.core.plan import PlannedRun, campaign_fingerprint
from uav_campaigns.core.table import freshness
from uav_campaigns.errors import CampaignDirError
from uav_campaigns.report.html import build_report
from uav_campaigns.shell.results import build_tables, read_series
from uav_campaigns.shell.runner import pack_run_dir, unpack_run_dir
from uav_campaigns.shell.store import CampaignDir

BODY = """\
arms: {base: {}, stale: {autonomy.weights.age: -1.0}}
seeds: [1, 2, 3]
max_attempts: 2
success: {mapped_10: "coverage.mapped_pct >= 10"}
statistics: {resamples: 2000}
"""


def read_csv(path: Path) -> list[dict[str, str]]:
    with path.open(newline="") as fh:
        return list(csv.DictReader(fh))


def finished(cdir: CampaignDir, run: PlannedRun, try_no: int, **extra: Any) -> None:
    run_dir = cdir.run_dir(run, try_no)
    cdir.append({"event": "started", "key": run.key, "try": try_no, "worker": "tcp://w1", "run_dir": str(run_dir)})
    cdir.append(
        {"event": "finished", "key": run.key, "try": try_no, "worker": "tcp://w1", "run_dir": str(run_dir),
         "run_path": str(run_dir.relative_to(cdir.path)), "wall_s": 30.0, "sim_s": 60.0, **extra}
    )  # fmt: skip


@pytest.fixture
def campaign_dir(tmp_path: Path) -> tuple[CampaignDir, Path]:
    path = campaign_file(tmp_path, BODY)
    campaign = load_campaign(path)
    runs = _plan(campaign)
    cdir = CampaignDir(tmp_path / "out")
    assert cdir.check(campaign, campaign_fingerprint(campaign)) is None
    cdir.write_identity(campaign, campaign_fingerprint(campaign), path.read_text(), runs)
    by = {(r.arm, r.seed): r for r in runs}
    for seed, mapped in ((1, 8.0), (2, 9.0), (3, 10.0)):
        run = by[("base", seed)]
        write_run(cdir.run_dir(run, 1), metrics(mapped_pct=mapped, iou=0.06, battery_pct=9.0), age_slope=1.0)
        finished(cdir, run, 1, status="done", stop_reason="time_limit")
    for seed, mapped in ((1, 11.0), (2, 12.5)):
        run = by[("stale", seed)]
        data = metrics(mapped_pct=mapped, iou=0.07, battery_pct=9.5, collisions=int(seed == 2))
        write_run(cdir.run_dir(run, 2), data, age_slope=0.05)
        cdir.append({"event": "orphaned", "key": run.key, "try": 1, "worker": "tcp://w2", "reason": "worker left"})
        finished(cdir, run, 2, status="done", stop_reason="time_limit")
    lost = by[("stale", 3)]
    for try_no in (1, 2):
        finished(cdir, lost, try_no, status="failed", reason="hung", log_tail="uav-run: still waiting")
    return cdir, path


def test_the_tables_hold_every_run_and_honest_statistics(campaign_dir: tuple[CampaignDir, Path]) -> None:
    cdir, _ = campaign_dir
    campaign, plan = cdir.load()
    tables = build_tables(cdir, campaign, plan)
    runs = read_csv(cdir.path / "runs.csv")
    assert len(runs) == 6
    assert [r["status"] for r in runs] == ["done"] * 5 + ["failed"]
    assert runs[-1]["reason"] == "hung"
    assert runs[-1]["attempts"] == "2"
    assert {r["orphaned"] for r in runs if r["arm"] == "stale" and r["status"] == "done"} == {"1"}
    first = runs[0]
    assert first["coverage.mapped_pct"] == "8"
    assert first["config_hash"]
    assert first["key"].startswith(first["config_hash"][:20])
    assert first["report"] == "runs/base/s1-r0-t1/report.html"
    assert "detection.by_context.range.0-25.tp" not in first  # per-context breakdowns stay in the run folders
    assert float(first["freshness.age_growth"]) == pytest.approx(1.0, abs=1e-6)
    summary = {(r["arm"], r["metric"]): r for r in read_csv(cdir.path / "summary.csv")}
    base = summary[("base", "coverage.mapped_pct")]
    assert (base["n"], float(base["mean"]), float(base["median"])) == ("3", 9.0, 9.0)
    assert float(base["std"]) == pytest.approx(1.0)
    assert float(base["ci_low"]) <= 9.0 <= float(base["ci_high"])
    assert summary[("stale", "coverage.mapped_pct")]["n"] == "2"  # the failed run is not in the statistics
    assert ("base", "versions.python") not in summary
    assert ("base", "world.seed") not in summary
    paired = {(r["arm"], r["metric"]): r for r in read_csv(cdir.path / "paired.csv")}
    p = paired[("stale", "coverage.mapped_pct")]
    assert (p["reference"], p["n_pairs"]) == ("base", "2")  # seeds 1 and 2 are shared
    assert float(p["mean_diff"]) == pytest.approx(3.25)
    assert p["wilcoxon_method"] == "exact"
    assert float(p["wilcoxon_p"]) == pytest.approx(0.5)  # 2 pairs, both positive: 2 * 1/4
    success = {(r["arm"], r["criterion"]): r for r in read_csv(cdir.path / "success.csv")}
    assert success[("stale", "no_collision")]["successes"] == "1"
    assert success[("base", "mapped_10")]["successes"] == "1"
    assert float(success[("base", "mapped_10")]["ci_high"]) < 1.0
    assert len(tables.rows) == 6


def test_the_report_links_every_run_and_shows_the_figures(
    campaign_dir: tuple[CampaignDir, Path], artifacts: Path
) -> None:
    cdir, path = campaign_dir
    campaign, plan = cdir.load()
    report = build_report(cdir, campaign, build_tables(cdir, campaign, plan), path.read_text())
    html = report.read_text()
    links = re.findall(r'href="([^"]+)"', html)
    assert sorted(links) == sorted(
        f"runs/{a}/s{s}-r0-t{t}/report.html"
        for a, s, t in [("base", 1, 1), ("base", 2, 1), ("base", 3, 1), ("stale", 1, 2), ("stale", 2, 2)]
    )
    assert all((cdir.path / link).is_file() for link in links)
    assert html.count("data:image/png;base64,") >= 3
    for text in ("Wilcoxon", "Wilson", "hung", "uav-run: still waiting", "orphaned", "coverage.mapped_pct"):
        assert text in html
    (artifacts / "campaign_report.html").write_text(html)
    fig = cdir.path / "figures" / "coverage.mapped_pct.png"
    assert fig.stat().st_size > 5000
    (artifacts / fig.name).write_bytes(fig.read_bytes())


def test_uav_campaign_report_rebuilds_the_tables_offline(campaign_dir: tuple[CampaignDir, Path]) -> None:
    cdir, _ = campaign_dir
    for name in ("runs.csv", "summary.csv", "report.html"):
        (cdir.path / name).unlink(missing_ok=True)
    out = io.StringIO()
    assert main(["report", str(cdir.path)], out=out) == 0
    assert (cdir.path / "runs.csv").is_file()
    assert (cdir.path / "report.html").is_file()
    assert "report:" in out.getvalue()
    assert main(["report", str(cdir.path / "runs")]) == 2  # not a campaign directory


def test_a_directory_made_by_another_campaign_file_is_refused(
    campaign_dir: tuple[CampaignDir, Path], tmp_path: Path
) -> None:
    cdir, path = campaign_dir
    other = load_campaign(campaign_file(tmp_path, BODY.replace("[1, 2, 3]", "[1, 2]"), name="other.yaml"))
    with pytest.raises(CampaignDirError, match="never mixed"):
        cdir.check(other, campaign_fingerprint(other))
    same = load_campaign(path)
    assert cdir.check(same, campaign_fingerprint(same)) is not None
    stray = tmp_path / "stray"
    stray.mkdir()
    (stray / "notes.txt").write_text("mine")
    with pytest.raises(CampaignDirError, match="not a campaign directory"):
        CampaignDir(stray).check(same, campaign_fingerprint(same))
    # and through the command line: exit 2, nothing written
    err_out = io.StringIO()
    rc = main(["run", str(tmp_path / "other.yaml"), "--out", str(cdir.path), "--dry-run"], out=err_out)
    assert rc == 2


def test_a_truncated_manifest_line_is_skipped(tmp_path: Path) -> None:
    cdir = CampaignDir(tmp_path)
    cdir.append({"event": "started", "key": "k", "try": 1})
    with cdir.manifest_path.open("a") as fh:
        fh.write('{"event": "finished", "key": "k", "tr')  # the machine died mid-write
    (only,) = cdir.events()
    assert {k: v for k, v in only.items() if k != "t"} == {"event": "started", "key": "k", "try": 1}
    assert only["t"] > 1.7e9  # every event is stamped (Unix seconds)


def test_freshness_tells_a_settled_age_from_a_growing_one(tmp_path: Path) -> None:
    growing = freshness(
        read_series(write_run(tmp_path / "g", metrics(mapped_pct=1, iou=0, battery_pct=1)) / "timeseries.csv")
    )
    settled = freshness(read_series(write_run(tmp_path / "s", metrics(mapped_pct=1, iou=0, battery_pct=1),
                                              age_slope=0.0) / "timeseries.csv"))  # fmt: skip
    assert growing["freshness.age_growth"] == pytest.approx(1.0)
    assert settled["freshness.age_growth"] == pytest.approx(0.0, abs=1e-9)
    assert growing["freshness.mean_cell_age_s"] == pytest.approx(62.0)
    assert growing["freshness.max_home_distance_m"] == pytest.approx(10.0)
    assert growing["freshness.mapped_pct_per_min"] == pytest.approx(6.0)
    assert all(math.isnan(v) for v in freshness([]).values())  # NaN without a time series


def test_run_folders_travel_without_bags(tmp_path: Path) -> None:
    src = write_run(tmp_path / "run", metrics(mapped_pct=1, iou=0, battery_pct=1))
    (src / "run.bag").write_bytes(b"\0" * 100_000)
    (src / "logs").mkdir()
    (src / "logs" / "roslaunch.log").write_text("log")
    dest = tmp_path / "back"
    unpack_run_dir(pack_run_dir(src), dest)
    assert json.loads((dest / "metrics.json").read_text())["final"] is True
    assert (dest / "logs" / "roslaunch.log").read_text() == "log"
    assert not (dest / "run.bag").exists()

"""``uav-campaign``: run a campaign of scenario runs on Dask, or rebuild its report offline.

::

    uav-campaign run CAMPAIGN.yaml --out DIR                           # embedded local Dask cluster
    uav-campaign run CAMPAIGN.yaml --out DIR --scheduler tcp://HOST:8786   # an existing Dask cluster
    uav-campaign run CAMPAIGN.yaml --out DIR --dry-run                  # the plan, what is done, what would run
    uav-campaign report DIR                                              # tables and report.html again, offline

Exit status (``uav_common.exit_codes``): 0 every run is done; 1 some runs failed ``max_attempts`` times
(or could not run); 2 a bad campaign file, arm override or argument, or a directory made by another
campaign file; 3 the scheduler cannot be reached or its workers cannot run the project; 130 interrupted
(the next invocation resumes). See docs/campaigns.md.
"""

from __future__ import annotations

import argparse
import signal
import sys
from collections.abc import Sequence
from pathlib import Path
from typing import Any, TextIO

from uav_campaigns.core.config import Campaign, load_campaign
from uav_campaigns.core.manifest import Decision, decide, fold
from uav_campaigns.core.plan import PlannedRun, campaign_fingerprint, plan_runs
from uav_campaigns.core.progress import format_duration
from uav_campaigns.errors import CampaignConfigError, CampaignError
from uav_campaigns.report.html import build_report
from uav_campaigns.shell.dask_exec import Executor, InvocationResult, connect, throughput
from uav_campaigns.shell.results import Tables, build_tables
from uav_campaigns.shell.store import CampaignDir
from uav_common.config import ConfigError, load_yaml_mapping
from uav_common.errors import ResourceError
from uav_common.exit_codes import ExitCode
from uav_scenarios.core.config import load_scenario
from uav_scenarios.shell.preflight import check_runs

__all__ = ["main"]


def _parse(argv: Sequence[str] | None) -> argparse.Namespace:
    p = argparse.ArgumentParser(
        prog="uav-campaign", description="Campaigns of scenario runs on Dask (docs/campaigns.md)."
    )
    sub = p.add_subparsers(dest="command", required=True)
    run = sub.add_parser("run", help="run every (arm, seed, repeat) of a campaign; skips the runs already done")
    run.add_argument("campaign", type=Path, help="campaign file, e.g. config/campaigns/smoke.yaml")
    run.add_argument("--out", type=Path, required=True, help="campaign directory (manifest, runs, tables, report)")
    run.add_argument("--scheduler", help="address of an existing Dask scheduler, e.g. tcp://HOST:8786")
    run.add_argument("--workers", type=int, help="workers of the embedded cluster (default: cores // cores_per_run)")
    run.add_argument("--dashboard-address", default=":8787", help="the embedded cluster's dashboard (default :8787)")
    run.add_argument(
        "--copy-results",
        action="store_true",
        help="workers send run folders back even if they see --out (no shared disk)",
    )
    run.add_argument("--retry-failed", action="store_true", help="try the runs given up on again (max_attempts more)")
    run.add_argument("--dry-run", action="store_true", help="print the plan and what would run; start nothing")
    run.add_argument("--arms", help="run only these arms now (comma-separated); the others stay to run later")
    run.add_argument("--seeds", help="run only these seeds now (comma-separated)")
    rep = sub.add_parser("report", help="rebuild runs.csv, summary.csv, paired.csv, success.csv and report.html")
    rep.add_argument("dir", type=Path, help="a campaign directory")
    return p.parse_args(argv)


def _plan(campaign: Campaign) -> list[PlannedRun]:
    load_scenario(campaign.scenario)  # the base scenario itself must load (clear error naming it)
    base = load_yaml_mapping(campaign.scenario)

    def read_world(path: Path) -> str:
        try:
            return path.read_text()
        except OSError as err:
            msg = f"cannot read world file {path}: {err.strerror}"
            raise ConfigError(msg) from err

    runs = plan_runs(campaign, base, read_world)
    # what the sim bridge or the SITL would refuse is an error now, not every run dying at its start
    check_runs((f"{campaign.source or 'the campaign'}: arm {r.arm!r} (seed {r.seed})", r.scenario) for r in runs)
    return runs


def _summary_lines(campaign: Campaign, tables: Tables) -> list[str]:
    lines = []
    conf = round(100 * campaign.statistics.confidence)
    for metric in campaign.key_metrics:
        rows = [s for s in tables.summary if s.metric == metric and s.summary.n]
        if not rows:
            continue
        lines.append(f"  {metric}:")
        for s in rows:
            m = s.summary
            ci = f"[{m.ci_low:.4g}, {m.ci_high:.4g}]" if m.n > 1 else "[–]"
            lines.append(f"    {s.arm:24s} n={m.n:<3d} mean {m.mean:<10.4g} {conf}% CI {ci}")
        for p in tables.paired:
            if p.metric == metric and p.comparison.n:
                c = p.comparison
                ci = f"[{c.ci_low:.4g}, {c.ci_high:.4g}]" if c.n > 1 else "[–]"
                lines.append(
                    f"    {p.arm} − {p.reference}: {c.mean_diff:+.4g} {ci}, "
                    f"Wilcoxon p={c.wilcoxon.p_value:.3g} ({c.n} pairs)"
                )
    return lines


def _report(cdir: CampaignDir, campaign: Campaign, out: TextIO) -> Tables:
    _, plan = cdir.load()
    text = str((cdir.identity() or {}).get("campaign_text", ""))
    tables = build_tables(cdir, campaign, plan)
    report = build_report(cdir, campaign, tables, text)
    out.write(f"tables: {cdir.path / 'runs.csv'}, summary.csv, paired.csv, success.csv\nreport: {report}\n")
    return tables


def _only(decision: Decision, runs: Sequence[PlannedRun], args: argparse.Namespace, campaign: Campaign) -> Decision:
    """The decision restricted to ``--arms`` / ``--seeds`` (the rest of the plan stays to run later)."""
    arms = set(args.arms.split(",")) if args.arms else set(campaign.arms)
    try:
        seeds = {int(s) for s in args.seeds.split(",")} if args.seeds else set(campaign.seeds)
    except ValueError as err:
        msg = f"--seeds takes comma-separated integers, got {args.seeds!r}"
        raise CampaignConfigError(msg) from err
    unknown = sorted(arms - set(campaign.arms)) + sorted(str(s) for s in seeds - set(campaign.seeds))
    if unknown:
        msg = f"--arms/--seeds name {unknown}, which the campaign does not have"
        raise CampaignConfigError(msg)
    chosen = {r.key for r in runs if r.arm in arms and r.seed in seeds}
    return Decision(decision.done, tuple(x for x in decision.run if x[0] in chosen), decision.gave_up)


def _dry_run(runs: Sequence[PlannedRun], decision: Decision, out: TextIO) -> None:
    todo = dict(decision.run)
    for r in runs:
        state = "done" if r.key in decision.done else "given up" if r.key in decision.gave_up else "run"
        extra = f" (try {todo[r.key]})" if r.key in todo else ""
        out.write(f"  {r.label:32s} {r.config_hash[:16]}  {state}{extra}\n")


def _execute(
    args: argparse.Namespace, campaign: Campaign, runs: Sequence[PlannedRun], decision: Decision, out: TextIO
) -> InvocationResult:
    """Connect (or start the embedded cluster), then run the decision; Ctrl-C stops it cleanly."""
    fingerprint = campaign_fingerprint(campaign)
    cdir = CampaignDir(args.out.resolve())
    cluster = connect(
        args.scheduler,
        workers=args.workers,
        cores_per_run=campaign.cores_per_run,
        dashboard_address=args.dashboard_address,
    )
    try:
        cdir.write_identity(campaign, fingerprint, args.campaign.read_text(), runs)
        workers = cluster.workers()
        out.write(
            f"Dask: {cluster.mode} cluster at {cluster.address}, {len(workers)} worker(s), "
            f"{sum(workers.values())} run(s) at once\ndashboard: {cluster.dashboard or 'n/a'}\n"
        )
        out.flush()
        cdir.append(
            {"event": "invocation", "mode": cluster.mode, "scheduler": cluster.address, "to_run": len(decision.run)}
        )
        transfer = "always" if args.copy_results else "auto"
        executor = Executor(cluster, cdir, campaign, fingerprint, runs, out=out, transfer=transfer)

        def on_signal(_sig: int, _frame: Any) -> None:
            executor.stop_requested.set()
            signal.signal(signal.SIGINT, signal.default_int_handler)  # a second Ctrl-C abandons the runs

        old_int = signal.signal(signal.SIGINT, on_signal)
        old_term = signal.signal(signal.SIGTERM, on_signal)
        try:
            result = executor.execute(decision)
        finally:
            signal.signal(signal.SIGINT, old_int)
            signal.signal(signal.SIGTERM, old_term)
    finally:
        cluster.close()
    rate, overhead = throughput(result)
    if result.run_wall_s:
        out.write(
            f"this invocation: {result.finished} run(s) done in {format_duration(result.wall_s)}, "
            f"{sum(result.run_sim_s):.0f} s simulated ({rate:.2f} simulated s per wall s); "
            f"{result.failed_tries} failed tries, {overhead:.1f} s per run outside uav-run ({result.slots} slots)\n"
        )
    return result


def _run(args: argparse.Namespace, out: TextIO) -> int:
    campaign = load_campaign(args.campaign)
    runs = _plan(campaign)
    fingerprint = campaign_fingerprint(campaign)
    cdir = CampaignDir(args.out.resolve())
    cdir.check(campaign, fingerprint)
    keys = [r.key for r in runs]
    states = fold(cdir.events())
    if args.retry_failed and not args.dry_run:
        for key, st in states.items():
            if key in keys and st.done is None and st.failures:
                cdir.append({"event": "retry", "key": key, "try": st.tries})
        states = fold(cdir.events())
    decision = decide(keys, states, campaign.max_attempts)
    if args.arms or args.seeds:
        decision = _only(decision, runs, args, campaign)
    unique = len(set(keys))
    stale = sum(1 for k, s in states.items() if s.done is not None and k not in set(keys))
    out.write(
        f"campaign {campaign.name}: {len(runs)} runs ({len(campaign.arms)} arms x {len(campaign.seeds)} seeds x "
        f"{campaign.repeats} repeats{f', {unique} distinct configurations' if unique != len(runs) else ''}); "
        f"{len(decision.done)} done already, {len(decision.run)} to run, {len(decision.gave_up)} given up "
        f"(--retry-failed tries them again)\n"
    )
    if stale:
        out.write(
            f"note: {stale} finished run(s) in {cdir.path} no longer match the campaign's effective configuration "
            "(the scenario file changed): they are kept, not counted, and the changed runs run again\n"
        )
    if args.dry_run:
        _dry_run(runs, decision, out)
        return int(ExitCode.OK)
    result = None
    if decision.run:
        result = _execute(args, campaign, runs, decision, out)
    else:
        cdir.write_identity(campaign, fingerprint, args.campaign.read_text(), runs)
    tables = _report(cdir, campaign, out)
    for line in _summary_lines(campaign, tables):
        out.write(line + "\n")
    statuses = [r["status"] for r in tables.rows]
    if result is not None and result.interrupted:
        out.write(
            f"interrupted: run the same command again to resume ({statuses.count('done')} of {len(statuses)} done)\n"
        )
        return 130
    if all(s == "done" for s in statuses):
        return int(ExitCode.OK)
    out.write(
        f"{statuses.count('failed')} run(s) failed {campaign.max_attempts} times and "
        f"{statuses.count('pending')} did not finish; see the failures in {cdir.path / 'report.html'}\n"
    )
    return int(ExitCode.FAILURE)


def main(argv: Sequence[str] | None = None, out: TextIO = sys.stdout) -> int:
    args = _parse(argv)
    try:
        if args.command == "report":
            cdir = CampaignDir(args.dir.resolve())
            campaign, _ = cdir.load()
            _report(cdir, campaign, out)
            return int(ExitCode.OK)
        return _run(args, out)
    except (ConfigError, CampaignConfigError) as err:
        sys.stderr.write(f"uav-campaign: {err}\n")
        return int(ExitCode.CONFIG)
    except ResourceError as err:
        sys.stderr.write(f"uav-campaign: {err}\n")
        return int(ExitCode.RESOURCE)
    except CampaignError as err:
        sys.stderr.write(f"uav-campaign: {err}\n")
        return int(ExitCode.FAILURE)
    except KeyboardInterrupt:
        sys.stderr.write("uav-campaign: interrupted; run the same command again to resume\n")
        return 130

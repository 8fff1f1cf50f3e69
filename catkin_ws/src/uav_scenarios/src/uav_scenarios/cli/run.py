"""``uav-run SCENARIO.yaml``: run a scenario from a shell, show its progress, build its report.

It writes the effective scenario (with command-line overrides) into a new run folder
``runs/<name>-<YYYYmmdd-HHMMSS>/``, starts ``roslaunch uav_scenarios <mission>.launch``
on a private ROS master and free ports, shows one progress line (simulation time,
real-time factor, % mapped, battery, mode, goal), and when the mission manager
stops the run (or on Ctrl-C) builds ``report.html`` from the bag and prints its
path and a metric summary. The run folder holds ``metrics.json``,
``timeseries.csv``, ``run.bag``, ``report.html`` and ``logs/``.

Exit status (``uav_common.exit_codes``): 0 the run ended on a stop criterion and the report was
built; 1 the run ended early (a node died, nothing was scored) or the report failed; 2 bad
scenario or command line; 3 roslaunch is missing; 130 interrupted (the report is still built).
"""

from __future__ import annotations

import argparse
import contextlib
import datetime as dt
import json
import math
import os
import shutil
import signal
import sys
import threading
import time
from collections.abc import Sequence
from dataclasses import replace
from pathlib import Path
from typing import Any, TextIO

from uav_common.config import ConfigError
from uav_common.errors import ResourceError
from uav_common.exit_codes import ExitCode
from uav_common.paths import config_dir, runs_dir
from uav_common.shell.processes import LoggedProcess, free_port, free_udp_port, wait_for_port
from uav_scenarios.core.config import Scenario, TimeMode, TimeSpec, effective_yaml, load_scenario
from uav_scenarios.core.launch import RunPorts
from uav_scenarios.core.world import world_config_for
from uav_scenarios.errors import ScenarioError
from uav_scenarios.report.data import read_run_bag
from uav_scenarios.report.html import build_report
from uav_scenarios.report.text import headline
from uav_scenarios.shell.environment import check_actors, environment_presets, scenario_environment, with_environment
from uav_scenarios.shell.preflight import check_node_settings
from uav_scenarios.shell.versions import tool_versions
from uav_scenarios.shell.world_store import load_world
from uav_sim_bridge.core.motion import ActorsConfig

__all__ = ["environment_row", "environment_table", "main", "scenario_yaml"]

#: The demo: loiter this many simulated seconds (``make demo``).
DEMO_SECONDS = 90.0


def scenario_yaml(scenario: Scenario) -> str:
    """The effective scenario (with uav-run's overrides) as a self-contained YAML file."""
    return effective_yaml(scenario, ", with uav-run's overrides")


def allocate_ports(fixed: dict[str, str]) -> RunPorts:
    """Free ports for everything this run binds; the GCS and MAVSDK targets stay at 14550/14541."""
    ports = {
        "sitl_tcp": free_port(),
        "sim": free_udp_port(),
        "router_tcp": free_port(),
        "controller": free_udp_port(),
        "odometry": free_udp_port(),
        "adhoc": free_udp_port(),
        "gcs": 14550,
        "mavsdk": 14541,
    }
    ports.update({k: int(v) for k, v in fixed.items() if k in ports})
    return RunPorts.from_mapping({**ports, **fixed})


class Progress:
    """Latest status and metrics from the run (rospy callbacks), rendered as one line."""

    def __init__(self) -> None:
        self.lock = threading.Lock()
        self.status: Any = None
        self.metrics: Any = None
        self.wall_start = time.monotonic()
        #: (wall, sim) seconds at the first status of the running mission and at the stop.
        self.first: tuple[float, float] | None = None
        self.stopped: tuple[float, float] | None = None

    def on_status(self, msg: Any) -> None:
        with self.lock:
            self.status = msg
            now = time.monotonic()
            if self.first is None:
                self.first = (now, float(msg.sim_time_s))
            if msg.stop and self.stopped is None:
                self.stopped = (now, float(msg.sim_time_s))

    def pace(self) -> dict[str, float] | None:
        """Wall and simulated seconds from the first status to the stop, and their ratio (the run's RTF)."""
        with self.lock:
            first, last = self.first, self.stopped
        if first is None or last is None or last[0] <= first[0]:
            return None
        wall_s, sim_s = last[0] - first[0], last[1] - first[1]
        return {"wall_s": round(wall_s, 3), "sim_s": round(sim_s, 3), "real_time_factor": round(sim_s / wall_s, 4)}

    def on_metrics(self, msg: Any) -> None:
        with self.lock:
            self.metrics = msg

    def line(self, limit_s: float) -> str:
        with self.lock:
            st, me = self.status, self.metrics
        wall = time.monotonic() - self.wall_start
        if st is None:
            return f"[{wall:5.0f} s] starting: SITL, router, bridge, map server, autonomy..."

        def num(v: float, fmt: str) -> str:
            return format(v, fmt) if v is not None and math.isfinite(v) else "–"

        mapped = me.mapped_pct if me is not None else st.mapped_pct
        goal = st.goal
        goal_txt = f"({goal.x:.0f}, {goal.y:.0f})" if math.isfinite(goal.x) else "–"
        frac = min(1.0, st.sim_time_s / limit_s) if limit_s > 0 else 0.0
        bar = "#" * int(frac * 20) + "." * (20 - int(frac * 20))
        mode = st.controller_state or "–"
        if st.autopilot_mode:
            mode += f"/{st.autopilot_mode}"
        return (
            f"[{bar}] sim {st.sim_time_s:6.1f}/{limit_s:.0f} s  rtf {num(st.real_time_factor, '.1f')}x  "
            f"mapped {num(mapped, '.2f')} %  battery {num(st.battery_pct, '.0f')} %  {mode}  goal {goal_txt}  "
            f"{st.phase}{' ' + st.stop_reason if st.stop else ''}"
        )


def _tail(path: Path, lines: int = 25) -> str:
    try:
        return "\n".join(path.read_text(errors="replace").splitlines()[-lines:])
    except OSError:
        return ""


def _overrides(scenario: Scenario, args: argparse.Namespace) -> Scenario:
    stop = scenario.stop
    time_spec = scenario.time
    if args.demo:
        stop = replace(stop, time_limit_s=args.time_limit or DEMO_SECONDS, wall_timeout_s=600.0)
    elif args.time_limit:
        stop = replace(stop, time_limit_s=args.time_limit)
    if args.lockstep or args.deterministic:
        time_spec = replace(
            time_spec, mode=TimeMode.LOCKSTEP, deterministic=args.deterministic or time_spec.deterministic
        )
    if args.speed_factor:
        time_spec = TimeSpec(mode=TimeMode.FREE, speed_factor=args.speed_factor, step_s=time_spec.step_s)
    recording = scenario.recording
    if args.no_record or args.record == "none":
        recording = replace(recording, enabled=False)
    elif args.record:
        recording = replace(recording, enabled=True, preset=args.record)
    out = replace(scenario, stop=stop, time=time_spec, recording=recording)
    if args.name:
        out = replace(out, name=args.name)
    return out


def _parse(argv: Sequence[str] | None) -> argparse.Namespace:
    p = argparse.ArgumentParser(
        prog="uav-run", description="Run a scenario (SITL + router + ROS stack), show progress, build the report."
    )
    p.add_argument("scenario", type=Path, help="scenario file, e.g. config/scenarios/loiter.yaml")
    p.add_argument("--demo", action="store_true", help=f"the make-demo run: {DEMO_SECONDS:g} simulated seconds")
    p.add_argument("--time-limit", type=float, help="override stop.time_limit_s (simulated seconds)")
    p.add_argument("--lockstep", action="store_true", help="run in lockstep (time.mode: lockstep)")
    p.add_argument(
        "--deterministic", action="store_true", help="lockstep, and the step master waits for the run to go idle"
    )
    p.add_argument("--speed-factor", type=float, help="free-running at this speed factor")
    p.add_argument(
        "--record",
        choices=("report", "replay", "none"),
        help="what rosbag records: the report's topics, also what a replay needs (big), or nothing",
    )
    p.add_argument("--no-record", action="store_true", help="same as --record none")
    p.add_argument("--name", help="run name (default: the scenario's)")
    p.add_argument(
        "--runs-dir", type=Path, default=runs_dir(), help="parent of the run folder (default: $UAV_RUNS_DIR or ./runs)"
    )
    p.add_argument("--run-dir", type=Path, help="exact run folder (default: RUNS_DIR/<name>-<time>)")
    p.add_argument("--port", action="append", default=[], metavar="NAME=PORT", help="fix a port (see docs)")
    p.add_argument(
        "--stress",
        action="append",
        default=[],
        metavar="PRESET",
        help="lay a stress preset over the scenario (config/stress/PRESET.yaml, or a path); repeatable, in order",
    )
    p.add_argument("--world-cache-dir", default="", help="world cache folder (default: the bridge's)")
    p.add_argument(
        "--environment", metavar="PRESET", help="run under this environment preset (config/environments/PRESET.yaml)"
    )
    p.add_argument(
        "--each-environment",
        nargs="?",
        const="all",
        metavar="PRESETS",
        help="run the scenario once under each preset (comma-separated, default: all of config/environments), "
        "one run folder each, and write a summary of their metrics",
    )
    p.add_argument("--quiet", action="store_true", help="no progress line")
    return p.parse_args(argv)


def _checked(scenario: Scenario, args: argparse.Namespace) -> Scenario:
    """The scenario with its environment resolved (the run folder records every value) and its actors checked
    against its world.

    Raises:
        ScenarioConfigError: an unknown preset or key, a bad value, actors the world cannot carry out.
    """
    if args.environment:
        scenario = with_environment(scenario, args.environment)
    latitude = world_config_for(scenario).latitude_deg
    merged, _ = scenario_environment(scenario, latitude)
    scenario = replace(scenario, environment=merged)
    if scenario.actors != ActorsConfig():
        cache = Path(args.world_cache_dir) if args.world_cache_dir else None
        check_actors(scenario, load_world(scenario, cache))
    return scenario


def main(argv: Sequence[str] | None = None, out: TextIO = sys.stdout) -> int:
    args = _parse(argv)
    try:
        stress = tuple(args.stress)
        scenario = _overrides(load_scenario(args.scenario, stress=stress, stress_dir=config_dir() / "stress"), args)
        check_node_settings(scenario)  # what the bridge and the SITL would refuse, before anything starts
        fixed = dict(item.split("=", 1) for item in args.port)
        allocate_ports(fixed)
        presets: list[str] = []
        if args.each_environment:
            presets = (
                environment_presets()
                if args.each_environment == "all"
                else [p.strip() for p in args.each_environment.split(",") if p.strip()]
            )
            if args.run_dir:
                msg = "--run-dir names one run folder; --each-environment makes one per preset (use --runs-dir)"
                raise ValueError(msg)
            checked = [_checked(scenario, argparse.Namespace(**{**vars(args), "environment": p})) for p in presets]
        else:
            checked = [_checked(scenario, args)]
    except (ConfigError, ScenarioError, ValueError) as err:
        sys.stderr.write(f"uav-run: {err}\n")
        return int(ExitCode.CONFIG)
    if not presets:
        return _run(checked[0], args, allocate_ports(fixed), out)
    stamp = dt.datetime.now().strftime("%Y%m%d-%H%M%S")
    rows = []
    worst = 0
    for preset, sc in zip(presets, checked, strict=True):
        run_dir = (args.runs_dir / f"{sc.name}-{preset}-{stamp}").resolve()
        out.write(f"\n=== environment {preset} ===\n")
        rc = _run(sc, argparse.Namespace(**{**vars(args), "run_dir": run_dir}), allocate_ports(fixed), out)
        worst = worst or rc
        rows.append(environment_row(preset, run_dir, rc))
        if rc == 130:
            break
    summary = (args.runs_dir / f"{scenario.name}-environments-{stamp}.json").resolve()
    summary.write_text(json.dumps(rows, indent=1) + "\n")
    out.write("\n" + "\n".join(environment_table(rows)) + f"\nsummary: {summary}\n")
    return worst


def environment_row(preset: str, run_dir: Path, rc: int) -> dict[str, Any]:
    """One line of the ``--each-environment`` summary: the run's headline metrics (NaN where missing)."""
    metrics: dict[str, Any] = {}
    with contextlib.suppress(OSError, json.JSONDecodeError):
        metrics = json.loads((run_dir / "metrics.json").read_text())
    pace: dict[str, Any] = {}
    with contextlib.suppress(OSError, json.JSONDecodeError):
        pace = json.loads((run_dir / "pace.json").read_text())

    def get(*keys: str) -> Any:
        node: Any = metrics
        for k in keys:
            node = node.get(k) if isinstance(node, dict) else None
        return node

    return {
        "environment": preset,
        "run_dir": str(run_dir),
        "exit_code": rc,
        "stop_reason": get("stop_reason"),
        "mapped_pct": get("coverage", "mapped_pct"),
        "detections": get("detection"),
        "tracking": get("tracking"),
        "real_time_factor": pace.get("real_time_factor"),
    }


def environment_table(rows: list[dict[str, Any]]) -> list[str]:
    """The summary as text: one line per preset."""

    def f(v: Any, fmt: str) -> str:
        return format(v, fmt) if isinstance(v, int | float) and math.isfinite(v) else "-"

    lines = [
        f"{'environment':<14} {'exit':>4} {'stop':<14} {'mapped %':>9} {'det TP/FP/FN':>14} {'MOTA':>6} {'rtf':>5}"
    ]
    for r in rows:
        det = r.get("detections") or {}
        trk = r.get("tracking") or {}
        tp_fp_fn = f"{det.get('tp', '-')}/{det.get('fp', '-')}/{det.get('fn', '-')}" if det else "-"
        lines.append(
            f"{r['environment']:<14} {r['exit_code']:>4} {r.get('stop_reason') or '-'!s:<14} "
            f"{f(r.get('mapped_pct'), '.2f'):>9} {tp_fp_fn:>14} {f(trk.get('mota'), '.3f'):>6} "
            f"{f(r.get('real_time_factor'), '.2f'):>5}"
        )
    return lines


def _run(scenario: Scenario, args: argparse.Namespace, ports: RunPorts, out: TextIO) -> int:  # noqa: PLR0915
    """One run of a checked scenario."""
    stamp = dt.datetime.now().strftime("%Y%m%d-%H%M%S")
    run_dir = (args.run_dir or args.runs_dir / f"{scenario.name}-{stamp}").resolve()
    (run_dir / "logs").mkdir(parents=True, exist_ok=True)
    scenario_path = run_dir / "scenario.yaml"
    scenario_path.write_text(scenario_yaml(scenario))
    try:
        load_scenario(scenario_path)  # the written file must load like the original
    except (ConfigError, ScenarioError) as err:
        sys.stderr.write(f"uav-run: internal error, the effective scenario does not load: {err}\n")
        return int(ExitCode.FAILURE)
    master_port = free_port()
    env = dict(os.environ)
    env.update(
        ROS_MASTER_URI=f"http://127.0.0.1:{master_port}",
        ROS_IP="127.0.0.1",
        ROS_LOG_DIR=str(run_dir / "logs" / "ros"),
        MESA_SHADER_CACHE_DIR=env.get("MESA_SHADER_CACHE_DIR", str(args.runs_dir / ".mesa_cache")),
        PYTHONUNBUFFERED="1",
    )
    env.pop("ROS_HOSTNAME", None)
    launch = f"{scenario.mission.value}.launch"
    cmd = [
        "roslaunch", "-p", str(master_port), "uav_scenarios", launch,
        f"scenario:={scenario_path}", f"run_dir:={run_dir}", f"depth_source:={scenario.depth_source.value}",
        f"detector:={scenario.perception.detector.value}",
        f"pose_source:={scenario.pose_source.value}", f"odometry_port:={ports.odometry}",
        f"record:={'true' if scenario.recording.enabled else 'false'}",
        f"world_cache_dir:={args.world_cache_dir}",
        f"sitl_tcp_port:={ports.sitl_tcp}", f"sim_port:={ports.sim}", f"router_tcp_port:={ports.router_tcp}",
        f"gcs_port:={ports.gcs}", f"controller_port:={ports.controller}", f"mavsdk_port:={ports.mavsdk}",
        f"adhoc_port:={ports.adhoc}",
    ]  # fmt: skip
    if shutil.which("roslaunch") is None:
        sys.stderr.write("uav-run: roslaunch not found; run inside the project environment (scripts/in_env)\n")
        return int(ExitCode.RESOURCE)
    launch_log = run_dir / "logs" / "roslaunch.log"
    out.write(f"run folder: {run_dir}\n")
    out.write(
        f"scenario {scenario.name} ({scenario.mission.value}, {scenario.strategy.value}), "
        f"{scenario.stop.time_limit_s:g} s simulated, time {scenario.time.mode.value}, "
        f"pose from {scenario.pose_source.value}"
        f"{'; stress ' + ', '.join(scenario.stress_applied) if scenario.stress_applied else ''}; "
        f"ROS master :{master_port}, GCS udp:{ports.gcs}\n"
    )
    out.flush()
    # SIGINT to roslaunch if uav-run itself dies (killed, or its campaign worker gone): the run stops cleanly.
    proc = LoggedProcess("roslaunch", cmd, log_path=launch_log, env=env, parent_death_signal=signal.SIGINT)
    interrupted = False

    def on_signal(_sig: int, _frame: Any) -> None:
        nonlocal interrupted
        interrupted = True

    old = signal.signal(signal.SIGINT, on_signal)
    old_term = signal.signal(signal.SIGTERM, on_signal)  # e.g. `timeout`: stop the run, never orphan it
    progress = Progress()
    tty = out.isatty() and not args.quiet
    try:
        try:
            wait_for_port(master_port, timeout_s=60.0, proc=proc)
        except ResourceError:
            sys.stderr.write(f"uav-run: roslaunch did not start (log {launch_log}):\n{_tail(launch_log)}\n")
            return int(ExitCode.FAILURE)
        _listen(progress, env)
        last_print = 0.0
        no_status_deadline = time.monotonic() + 180.0
        while proc.alive() and not interrupted:
            time.sleep(0.5)
            line = progress.line(scenario.stop.time_limit_s)
            if tty:
                out.write("\r" + line[: shutil.get_terminal_size((160, 20)).columns - 1].ljust(40) + "\x1b[K")
                out.flush()
            elif not args.quiet and time.monotonic() - last_print >= 10.0:
                out.write(line + "\n")
                out.flush()
                last_print = time.monotonic()
            if progress.status is None and time.monotonic() > no_status_deadline:
                sys.stderr.write(f"\nuav-run: no scenario status after 180 s; stopping (log {launch_log})\n")
                break
        if tty:
            out.write("\n")
    finally:
        # SIGINT lets roslaunch stop every node and rosbag close the bag; then escalate.
        proc.stop(10.0, int_timeout_s=40.0)
        signal.signal(signal.SIGINT, old)
        signal.signal(signal.SIGTERM, old_term)
    return _finish(run_dir, launch_log, progress, interrupted, out)


def _listen(progress: Progress, env: dict[str, str]) -> None:
    """Subscribe to the run's status and metrics (rospy in this process, on the run's master)."""
    os.environ["ROS_MASTER_URI"] = env["ROS_MASTER_URI"]
    os.environ["ROS_IP"] = env["ROS_IP"]
    import rospy  # noqa: PLC0415

    from uav_msgs.msg import RunMetrics, ScenarioStatus  # noqa: PLC0415

    rospy.init_node("uav_run", anonymous=True, disable_signals=True, disable_rosout=True)
    rospy.Subscriber("/scenario/status", ScenarioStatus, progress.on_status, queue_size=5)
    rospy.Subscriber("/scenario/metrics", RunMetrics, progress.on_metrics, queue_size=5)


def _finish(run_dir: Path, launch_log: Path, progress: Progress, interrupted: bool, out: TextIO) -> int:
    status = progress.status
    stopped = status is not None and status.stop
    if interrupted:
        out.write("interrupted: stopping the run and building the report from what was recorded\n")
    elif not stopped:
        out.write(f"the run ended before a stop criterion; roslaunch log: {launch_log}\n{_tail(launch_log, 15)}\n")
    pace = progress.pace()
    if pace is not None:
        (run_dir / "pace.json").write_text(json.dumps(pace) + "\n")
        out.write(
            f"simulated {pace['sim_s']:.1f} s in {pace['wall_s']:.1f} s wall "
            f"(real-time factor {pace['real_time_factor']:.2f}x)\n"
        )
    bag = run_dir / "run.bag"
    rc = 130 if interrupted else (0 if stopped else 1)
    if not bag.exists():
        out.write(f"no bag in {run_dir} (recording off or the run died early); metrics: {run_dir / 'metrics.json'}\n")
        return rc or (0 if (run_dir / "metrics.json").exists() else 1)
    try:
        run = read_run_bag(bag)
        metrics_path = run_dir / "metrics.json"
        if metrics_path.is_file():
            with contextlib.suppress(json.JSONDecodeError):
                run.summary = json.loads(metrics_path.read_text())
        versions = {f"run: {k}": str(v) for k, v in (run.summary.get("versions") or {}).items()}
        versions.update({f"report: {k}": v for k, v in tool_versions().items()})
        report = build_report(run, run_dir, versions=versions)
    except ScenarioError as err:
        out.write(f"uav-run: the report could not be built: {err}\n")
        return 1
    out.write(f"report: {report.html_path}\n")
    if report.missing:
        out.write(f"  figures without data: {', '.join(report.missing)}\n")
    out.write(f"  stop: {run.stop_reason or (status.stop_reason if status else '') or 'none'}\n")
    out.write("\n".join(headline(run.summary)) + "\n")
    return rc

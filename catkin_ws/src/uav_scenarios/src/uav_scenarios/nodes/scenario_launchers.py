"""Thin launchers that let roslaunch start a run's non-ROS processes from the scenario file.

``nodes/sitl``, ``nodes/mavlink_router`` and ``nodes/scenario_record`` each parse their
arguments (roslaunch's ``__name:=``/``__log:=`` are dropped or passed through), build the
command line from the scenario (:mod:`uav_scenarios.core.launch`) and ``exec``
the real program, so roslaunch's SIGINT reaches ``uav-sitl``, ``uav-mavlink-router`` or
``rosbag record`` directly and each shuts down cleanly (the bag is closed, the router
flushes its log).

    sitl SCENARIO --run-dir DIR --port sitl_tcp=5760 --port sim=4560 [--no-router] [--print]
    mavlink_router --run-dir DIR [--scenario SCENARIO] --port sitl_tcp=5760 --port router_tcp=5790 ... [--print]
    scenario_record SCENARIO --run-dir DIR [--print]
    scenario_play SCENARIO BAG [--rate R] [--print]

``--print`` prints the command (and the router configuration) instead of running it.
A broken scenario file or a bad port exits with status 2 and a message saying what to fix; a program
missing from PATH exits with 3 (docs/architecture.md, exit codes).
"""

from __future__ import annotations

import argparse
import os
import shutil
import sys
from collections.abc import Sequence
from pathlib import Path

from uav_common.config import ConfigError
from uav_common.exit_codes import ExitCode
from uav_scenarios.core.config import Scenario, load_scenario, played_topics, recorded_topics, replay_inputs
from uav_scenarios.core.launch import RunPorts, router_conf, sitl_argv
from uav_scenarios.errors import ScenarioError

__all__ = ["play_main", "record_main", "router_main", "sitl_main"]


def _split_ros_args(argv: Sequence[str]) -> tuple[list[str], list[str]]:
    ours = [a for a in argv if not a.startswith("__")]
    ros = [a for a in argv if a.startswith("__")]
    return ours, ros


def _fail(prog: str, message: str, code: ExitCode = ExitCode.CONFIG) -> None:
    sys.stderr.write(f"{prog}: {message}\n")
    sys.exit(int(code))


def _ports(prog: str, items: Sequence[str]) -> RunPorts:
    """``--port NAME=PORT`` items -> the run's ports; a bad item exits with status 2 and says which."""
    data: dict[str, str] = {}
    for item in items:
        name, sep, value = item.partition("=")
        if not sep:
            _fail(prog, f"--port takes NAME=PORT, got {item!r}")
        data[name.strip()] = value.strip()
    try:
        return RunPorts.from_mapping(data)
    except ScenarioError as err:
        _fail(prog, str(err))
        raise  # unreachable


def _load(prog: str, path: Path) -> Scenario:
    try:
        return load_scenario(path)
    except (ConfigError, ScenarioError) as err:
        _fail(prog, str(err))
        raise  # unreachable


def _exec(prog: str, argv: list[str], print_only: bool) -> None:
    if print_only:
        sys.stdout.write(" ".join(argv) + "\n")
        return
    exe = shutil.which(argv[0])
    if exe is None:
        _fail(
            prog,
            f"{argv[0]} is not on PATH; run inside the project environment (scripts/in_env) or `make setup`",
            ExitCode.RESOURCE,
        )
    sys.stdout.flush()
    sys.stderr.flush()
    os.execv(exe, argv)  # type: ignore[arg-type]


def _parser(prog: str, *, scenario: bool) -> argparse.ArgumentParser:
    p = argparse.ArgumentParser(prog=prog)
    if scenario:
        p.add_argument("scenario", type=Path)
    p.add_argument("--run-dir", type=Path, required=True)
    p.add_argument("--port", action="append", default=[], metavar="NAME=PORT")
    p.add_argument("--print", action="store_true", dest="print_only")
    return p


def sitl_main() -> None:
    prog = "sitl"
    ours, _ros = _split_ros_args(sys.argv[1:])
    p = _parser(prog, scenario=True)
    p.add_argument("--no-router", action="store_true", help="the controller talks to the SITL's API link directly")
    args = p.parse_args(ours)
    scenario = _load(prog, args.scenario)
    ports = _ports(prog, args.port)
    args.run_dir.mkdir(parents=True, exist_ok=True)
    argv = sitl_argv(scenario, ports, params_file=args.run_dir / "sitl_params.json", router=not args.no_router)
    _exec(prog, argv, args.print_only)


def router_main() -> None:
    prog = "mavlink_router"
    ours, _ros = _split_ros_args(sys.argv[1:])
    p = _parser(prog, scenario=False)
    p.add_argument("--scenario", type=Path, help="the run's scenario: its pose_source and lossy links")
    args = p.parse_args(ours)
    ports = _ports(prog, args.port)
    scenario = _load(prog, args.scenario) if args.scenario else None
    args.run_dir.mkdir(parents=True, exist_ok=True)
    conf = args.run_dir / "router.conf"
    text = router_conf(ports, args.run_dir / "router", scenario)
    if args.print_only:
        sys.stdout.write(text)
    conf.write_text(text)
    # An empty -d folder: a system-wide /etc/mavlink-router/config.d never leaks into a run.
    conf_dir = args.run_dir / "router.conf.d"
    conf_dir.mkdir(exist_ok=True)
    _exec(prog, ["uav-mavlink-router", "-c", str(conf), "-d", str(conf_dir)], args.print_only)


def record_main() -> None:
    prog = "scenario_record"
    ours, ros = _split_ros_args(sys.argv[1:])
    p = _parser(prog, scenario=True)
    args = p.parse_args(ours)
    scenario = _load(prog, args.scenario)
    args.run_dir.mkdir(parents=True, exist_ok=True)
    bag = args.run_dir / "run.bag"
    # lz4 chunks: cheap to write, readable by rosbag and by the rosbags library.
    argv = ["rosbag", "record", "--lz4", "--buffsize=512", "-O", str(bag), *recorded_topics(scenario), *ros]
    _exec(prog, argv, args.print_only)


def bag_topics(bag: Path) -> set[str]:
    """Topics of a ROS 1 bag (index only; fast).

    Raises:
        ScenarioError: the bag is missing, unfinished or unreadable (the message says what to do).
    """
    if not bag.is_file():
        hint = (
            " (an unfinished recording is run.bag.active: run `rosbag reindex` on it)"
            if bag.with_suffix(".bag.active").exists()
            else ""
        )
        msg = f"{bag}: no such bag{hint}"
        raise ScenarioError(msg)
    import rosbag  # noqa: PLC0415 - the replay needs ROS anyway

    try:
        with rosbag.Bag(str(bag)) as b:
            return set(b.get_type_and_topic_info().topics)
    except (rosbag.ROSBagException, OSError) as err:
        msg = f"{bag}: cannot read the bag ({err}); if the recording was interrupted, run `rosbag reindex` on it"
        raise ScenarioError(msg) from err


def play_main() -> None:
    """``scenario_play SCENARIO BAG``: ``rosbag play --clock`` of what a replay needs, and nothing else."""
    prog = "scenario_play"
    ours, ros = _split_ros_args(sys.argv[1:])
    p = argparse.ArgumentParser(prog=prog)
    p.add_argument("scenario", type=Path)
    p.add_argument("bag", type=Path)
    p.add_argument("--rate", type=float, default=1.0)
    p.add_argument("--print", action="store_true", dest="print_only")
    args = p.parse_args(ours)
    scenario = _load(prog, args.scenario)
    try:
        present = bag_topics(args.bag)
    except ScenarioError as err:
        _fail(prog, str(err))
        raise
    missing = [t for t in replay_inputs(scenario) if t not in present]
    if missing:
        _fail(
            prog,
            f"{args.bag} lacks {', '.join(missing)}: it was recorded with recording.preset "
            f"'{scenario.recording.preset}'; record with `recording: {{preset: replay}}` to replay the map",
        )
    topics = [t for t in played_topics(scenario) if t in present]
    argv = [
        # every played topic has a reader in the replay: wait for them, then give the others 3 s to connect
        "rosbag", "play", "--clock", "--quiet", f"--rate={args.rate:g}", "--delay=3", "--queue=2000",
        "--wait-for-subscribers",
        str(args.bag), *ros, "--topics", *topics,
    ]  # fmt: skip
    _exec(prog, argv, args.print_only)

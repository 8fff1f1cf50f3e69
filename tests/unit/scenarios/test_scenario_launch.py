"""Scenario -> SITL command line and router configuration, checked by the SITL's and router's own parsers."""

from __future__ import annotations

from dataclasses import replace
from pathlib import Path

import pytest
from helpers.paths import REPO

from mavlink_router.core.config import UdpMode, parse_config_text
from sitl.cli import build_parser, load_from_args
from uav_scenarios.core.config import TimeMode, TimeSpec, load_scenario
from uav_scenarios.core.launch import RunPorts, flatten_settings, router_conf, sitl_argv
from uav_scenarios.errors import ScenarioError

PORTS = RunPorts(sitl_tcp=41000, sim=41001, router_tcp=41002, gcs=41003, controller=41004, mavsdk=41005, adhoc=41006)


def sitl_config(argv: list[str]):  # type: ignore[no-untyped-def]
    assert argv[0] == "uav-sitl"
    return load_from_args(build_parser().parse_args(argv[1:]))


def test_sitl_behind_the_router(tmp_path: Path) -> None:
    s = load_scenario(REPO / "config/scenarios/loiter.yaml")
    cfg = sitl_config(sitl_argv(s, PORTS, params_file=tmp_path / "p.json"))
    assert cfg.links.tcp.port == 41000
    assert cfg.sim_link.port == 41001
    assert not cfg.links.gcs.enabled
    assert not cfg.links.api.enabled
    assert cfg.time.unix_epoch_s == 0  # SYSTEM_TIME does not follow the wall clock
    assert cfg.failsafe.geofence_max_altitude_m == 200.0  # node_params.sitl of the scenario
    assert cfg.time.stream_wall_floor_s == 2.0
    assert cfg.params.file == tmp_path / "p.json"


def test_sitl_without_router_and_in_lockstep(tmp_path: Path) -> None:
    s = load_scenario(REPO / "config/scenarios/loiter.yaml")
    s = replace(s, time=TimeSpec(mode=TimeMode.LOCKSTEP))
    argv = sitl_argv(s, PORTS, params_file=tmp_path / "p.json", router=False)
    cfg = sitl_config(argv)
    assert cfg.time.mode.value == "lockstep"
    assert cfg.links.api.enabled
    assert cfg.links.api.remote_port == 41004  # the controller listens there
    assert cfg.links.api.local_port == 0
    assert cfg.links.gcs.remote_port == 41003
    assert "--reset-params" in argv


def test_router_conf_is_valid_for_the_router(tmp_path: Path) -> None:
    cfg = parse_config_text(router_conf(PORTS, tmp_path / "logs"), source="run")
    assert cfg.general.tcp_server_port == 41002
    assert [(t.address, t.port) for t in cfg.tcp] == [("127.0.0.1", 41000)]
    clients = {u.name: u.port for u in cfg.udp if u.mode is UdpMode.NORMAL}
    assert clients == {"gcs": 41003, "controller": 41004, "mavsdk": 41005}
    servers = [u.port for u in cfg.udp if u.mode is UdpMode.SERVER]
    assert servers == [41006]
    assert cfg.general.log_dir == tmp_path / "logs"


def test_ports_are_checked() -> None:
    assert RunPorts.from_mapping({"sim": "4561"}).sim == 4561
    with pytest.raises(ScenarioError, match="unknown port"):
        RunPorts.from_mapping({"simm": 1})
    with pytest.raises(ScenarioError, match="integers"):
        RunPorts.from_mapping({"sim": "x"})
    with pytest.raises(ScenarioError, match=r"1\.\.65535"):
        RunPorts(sim=70000)


def test_flatten_settings() -> None:
    assert flatten_settings({"a": {"b": 1, "c": {"d": [1, 2]}}, "e": {}}) == [("a.b", 1), ("a.c.d", [1, 2]), ("e", {})]


def test_the_scenario_chooses_the_autopilot_personality(tmp_path: Path) -> None:
    from uav_scenarios.core.config import AutopilotKind  # noqa: PLC0415
    from uav_scenarios.errors import ScenarioConfigError  # noqa: PLC0415

    s = load_scenario(REPO / "config/scenarios/search_and_rescue.yaml")
    assert s.autopilot is AutopilotKind.PX4  # the default
    assert sitl_config(sitl_argv(s, PORTS, params_file=tmp_path / "p.json")).autopilot.value == "px4"
    ardu = replace(s, autopilot=AutopilotKind.ARDUPILOT)
    cfg = sitl_config(sitl_argv(ardu, PORTS, params_file=tmp_path / "p.json"))
    assert cfg.autopilot.value == "ardupilot"
    assert cfg.failsafe.geofence_max_altitude_m == 200.0  # node_params.sitl still applies (FENCE_ALT_MAX)
    bad = tmp_path / "bad.yaml"
    text = (REPO / "config/scenarios/search_and_rescue.yaml").read_text()
    text = text.replace("config: ../worlds/default.yaml", f"config: {REPO / 'config/worlds/default.yaml'}")
    bad.write_text("autopilot: betaflight\n" + text)
    with pytest.raises(ScenarioConfigError, match=r"autopilot.*'px4', 'ardupilot'"):
        load_scenario(bad)


def test_lockstep_runs_put_the_router_in_lockstep_with_the_sitl(tmp_path: Path) -> None:
    """Every lockstep run: the router's lossy links count in simulated time (its clock is the SITL's markers);
    a deterministic run also invites the controller's and the odometry node's endpoints to say HELLO."""
    from mavlink_router.core.config import LockstepRole  # noqa: PLC0415
    from uav_scenarios.core.config import PoseSource  # noqa: PLC0415

    s = load_scenario(REPO / "config/scenarios/loiter.yaml")
    s = replace(s, pose_source=PoseSource.AUTOPILOT)
    roles = {}
    for time in (TimeSpec(), TimeSpec(mode=TimeMode.LOCKSTEP), TimeSpec(mode=TimeMode.LOCKSTEP, deterministic=True)):
        cfg = parse_config_text(router_conf(PORTS, None, replace(s, time=time)), source="run")
        roles[time.mode, time.deterministic] = (
            cfg.general.lockstep,
            {e.name: e.options.lockstep for e in (*cfg.tcp, *cfg.udp)},
        )
    none = dict.fromkeys(("sitl", "gcs", "controller", "mavsdk", "odometry", "adhoc"))
    assert roles[TimeMode.FREE, False] == (False, none)
    assert roles[TimeMode.LOCKSTEP, False] == (True, {**none, "sitl": LockstepRole.AUTOPILOT})
    invited = {"controller": LockstepRole.CLIENT, "odometry": LockstepRole.CLIENT}
    assert roles[TimeMode.LOCKSTEP, True] == (True, {**none, "sitl": LockstepRole.AUTOPILOT, **invited})
    assert not parse_config_text(router_conf(PORTS, None), source="run").general.lockstep


def test_a_deterministic_sitl_has_no_wall_clock_floor_and_a_fixed_epoch(tmp_path: Path) -> None:
    s = load_scenario(REPO / "config/scenarios/loiter.yaml")  # its node_params.sitl set a 2 s stream floor
    plain = sitl_config(sitl_argv(replace(s, time=TimeSpec(mode=TimeMode.LOCKSTEP)), PORTS, params_file=tmp_path / "p"))
    assert (plain.time.datalink_wall_floor_s, plain.time.stream_wall_floor_s) == (3.0, 2.0)
    deterministic = replace(s, time=TimeSpec(mode=TimeMode.LOCKSTEP, deterministic=True))
    cfg = sitl_config(sitl_argv(deterministic, PORTS, params_file=tmp_path / "p.json"))
    assert cfg.time.mode.value == "lockstep"
    assert (cfg.time.datalink_wall_floor_s, cfg.time.stream_wall_floor_s) == (0.0, 0.0)
    assert cfg.time.unix_epoch_s == 0
    own_epoch = replace(deterministic, node_params={**s.node_params, "sitl": {"time": {"unix_epoch_s": 1.7e9}}})
    assert sitl_config(sitl_argv(own_epoch, PORTS, params_file=tmp_path / "p.json")).time.unix_epoch_s == 1.7e9

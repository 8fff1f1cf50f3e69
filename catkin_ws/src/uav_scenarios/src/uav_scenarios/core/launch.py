"""Scenario -> the command lines and files of a run's non-ROS processes (SITL, router).

Pure: functions of the scenario, the ports and the run folder. The launcher nodes
(``nodes/sitl``, ``nodes/mavlink_router``) and ``uav-run`` call them, so a run
started by ``roslaunch`` and one started by ``uav-run`` are the same run.

Ports (every one settable; tests use free ones): the SITL's TCP server (the router
connects), its simulation link (the bridge connects), and the router's endpoints
(GCS, controller, MAVSDK, the autopilot odometry node with ``pose_source: autopilot``,
ad-hoc UDP server, TCP server). With the router, the SITL's own GCS and API UDP links
are switched off (``docs/architecture.md``). The scenario's ``link`` section makes
endpoints lossy (the router's ``LossPercent``... keys).
"""

from __future__ import annotations

import math
from collections.abc import Mapping
from dataclasses import dataclass, fields
from pathlib import Path
from typing import Any

from uav_scenarios.core.config import LOCKSTEP_WALL_FLOOR_S, LinkImpairmentSpec, PoseSource, Scenario, TimeMode
from uav_scenarios.errors import ScenarioError

__all__ = ["RunPorts", "flatten_settings", "router_conf", "sitl_argv", "yaml_scalar"]


@dataclass(frozen=True)
class RunPorts:
    """Every port of one run (defaults: ``docs/architecture.md``)."""

    sitl_tcp: int = 5760
    sim: int = 4560
    router_tcp: int = 5790
    gcs: int = 14550
    controller: int = 14540
    mavsdk: int = 14541
    adhoc: int = 14555
    odometry: int = 14542

    def __post_init__(self) -> None:
        for f in fields(self):
            value = getattr(self, f.name)
            if not isinstance(value, int) or not 0 < value < 65536:
                msg = f"port {f.name} must be an integer in 1..65535, got {value!r}"
                raise ScenarioError(msg)

    @classmethod
    def from_mapping(cls, data: Mapping[str, Any]) -> RunPorts:
        """From ``{name: port}`` (strings allowed, as launch arguments are); unknown names are errors."""
        known = {f.name for f in fields(cls)}
        unknown = sorted(set(data) - known)
        if unknown:
            msg = f"unknown port name(s) {unknown}; known: {sorted(known)}"
            raise ScenarioError(msg)
        try:
            return cls(**{k: int(v) for k, v in data.items()})
        except ValueError as err:
            msg = f"ports must be integers: {dict(data)}"
            raise ScenarioError(msg) from err


def flatten_settings(data: Mapping[str, Any], prefix: str = "") -> list[tuple[str, Any]]:
    """``{a: {b: 1}, c: 2}`` -> ``[("a.b", 1), ("c", 2)]`` (for ``uav-sitl --set KEY=VALUE``)."""
    out: list[tuple[str, Any]] = []
    for key, value in data.items():
        name = f"{prefix}{key}"
        if isinstance(value, Mapping) and value:
            out.extend(flatten_settings(value, name + "."))
        else:
            out.append((name, value))
    return out


def yaml_scalar(value: Any) -> str:
    """A value as ``--set`` parses it (YAML): lists/dicts in flow style, None as null."""
    if value is None:
        return "null"
    if isinstance(value, bool):
        return "true" if value else "false"
    if isinstance(value, float) and not math.isfinite(value):
        msg = f"non-finite SITL setting {value!r}"
        raise ScenarioError(msg)
    if isinstance(value, list | tuple):
        return "[" + ", ".join(yaml_scalar(v) for v in value) + "]"
    if isinstance(value, Mapping):
        return "{" + ", ".join(f"{k}: {yaml_scalar(v)}" for k, v in value.items()) + "}"
    return str(value)


def sitl_argv(scenario: Scenario, ports: RunPorts, *, params_file: Path, router: bool = True) -> list[str]:
    """The ``uav-sitl`` command line of a scenario run.

    * a private parameter file, reset at start (a run never inherits another run's parameters);
    * ``time.unix_epoch_s = 0`` (SYSTEM_TIME does not depend on the wall clock);
    * the scenario's autopilot personality (``--autopilot``);
    * lockstep, or the scenario's speed factor;
    * the scenario's ``wind`` as the SITL's ``wind.*`` settings;
    * ``node_params.sitl`` as ``--set`` overrides (any ``config/sitl.yaml`` key, e.g.
      ``failsafe.geofence_max_altitude_m``);
    * ``time.deterministic``: no wall-clock floor on the SITL's link and stream failsafes
      (``time.datalink_wall_floor_s`` and ``time.stream_wall_floor_s`` 0, after ``node_params``: a floor would
      make the run depend on the machine's speed; docs/lockstep.md). ``time.unix_epoch_s`` is 0 in every run
      unless ``node_params.sitl`` sets it.
    """
    argv = [
        "uav-sitl",
        "--tcp-port", str(ports.sitl_tcp),
        "--sim-port", str(ports.sim),
        "--params-file", str(params_file),
        "--reset-params",
        "--set", "time.unix_epoch_s=0",
        "--autopilot", scenario.autopilot.value,
    ]  # fmt: skip
    if router:
        argv += ["--no-gcs", "--no-api"]
    else:
        # Without the router the controller listens where the API link sends; local ports: any free one.
        argv += [
            "--gcs-port", str(ports.gcs), "--gcs-local-port", "0",
            "--api-port", str(ports.controller), "--api-local-port", "0",
        ]  # fmt: skip
    if scenario.time.mode is TimeMode.LOCKSTEP:
        # the offboard-stream failsafe needs wall-clock silence too (node_params.sitl below may change it)
        argv += ["--lockstep", "--set", f"time.stream_wall_floor_s={LOCKSTEP_WALL_FLOOR_S:g}"]
    else:
        argv += ["--speed-factor", f"{scenario.time.speed_factor:g}"]
    if scenario.wind is not None:
        w = scenario.wind
        for key, value in (
            ("speed_mps", w.speed_mps),
            ("from_deg", w.from_deg),
            ("reference_height_m", w.reference_height_m),
            ("shear_exponent", w.shear_exponent),
            ("turbulence", w.turbulence),
            ("seed", w.seed),
        ):
            argv += ["--set", f"wind.{key}={yaml_scalar(value)}"]
    for key, value in flatten_settings(scenario.node_params.get("sitl", {})):
        argv += ["--set", f"{key}={yaml_scalar(value)}"]
    if scenario.time.deterministic:
        argv += ["--set", "time.datalink_wall_floor_s=0", "--set", "time.stream_wall_floor_s=0"]
    return argv


#: What the autopilot odometry node reads (the router sends it nothing else: no decoding work for it):
#: HEARTBEAT, ATTITUDE_QUATERNION, LOCAL_POSITION_NED, COMMAND_ACK, POSITION_TARGET_LOCAL_NED, TIMESYNC,
#: STATUSTEXT, ODOMETRY.
ODOMETRY_MESSAGES = (0, 31, 32, 77, 85, 111, 253, 331)


def link_lines(spec: LinkImpairmentSpec, seed: int) -> list[str]:
    """A lossy link as router configuration keys (docs/mavlink_router.md)."""
    return [
        f"LossPercent = {spec.loss_pct:g}",
        f"LossBurst = {spec.loss_burst:g}",
        f"DelayMs = {spec.delay_ms:g}",
        f"JitterMs = {spec.jitter_ms:g}",
        f"ReorderPercent = {spec.reorder_pct:g}",
        f"ReorderDelayMs = {spec.reorder_delay_ms:g}",
        f"LinkDirection = {spec.direction}",
        f"LinkSeed = {seed}",
    ]


def router_conf(ports: RunPorts, log_dir: Path | None, scenario: Scenario | None = None) -> str:
    """A ``uav-mavlink-router`` configuration (mavlink-routerd INI) for these ports.

    Same endpoints as ``config/router.conf``: the SITL's TCP server, a GCS, the
    controller and MAVSDK as UDP clients, an ad-hoc UDP server and a TCP server; with
    ``pose_source: autopilot`` also the autopilot odometry node's. The scenario's ``link``
    section makes the endpoints it names lossy.

    ``time.mode: lockstep``: the router runs in lockstep with the SITL (``Lockstep = true``, the SITL's
    endpoint ``Lockstep = autopilot``): its lossy links count in simulated time. ``time.deterministic``: the
    controller's and the odometry node's endpoints are also ``Lockstep = client`` (the router invites them: a
    ``udpin:`` client cannot say HELLO before it has heard from the router). docs/mavlink_router.md, "Lockstep".
    """
    links = scenario.link.endpoints if scenario is not None else {}
    seed = scenario.link.seed if scenario is not None else 0
    odometry = scenario is not None and scenario.pose_source is PoseSource.AUTOPILOT
    lockstep = scenario is not None and scenario.time.mode is TimeMode.LOCKSTEP
    clients = {"controller", "odometry"} if scenario is not None and scenario.time.deterministic else set()
    lines = [
        "# Written by the scenario launcher for one run (see config/router.conf for the defaults).",
        "[General]",
        f"TcpServerPort = {ports.router_tcp}",
        "ReportStats = false",
        "StatsInterval = 10",
        "MavlinkDialect = auto",
        "DebugLogLevel = info",
    ]
    if lockstep:
        lines.append("Lockstep = true")
    if log_dir is not None:
        lines += [f"Log = {log_dir}", "LogMode = always", "LogTelemetry = true"]
    lines += [
        "",
        "[TcpEndpoint sitl]",
        "Address = 127.0.0.1",
        f"Port = {ports.sitl_tcp}",
        "RetryTimeout = 2",
    ]
    if lockstep:
        lines.append("Lockstep = autopilot")
    endpoints = [("gcs", ports.gcs), ("controller", ports.controller), ("mavsdk", ports.mavsdk)]
    if odometry:
        endpoints.append(("odometry", ports.odometry))
    for name, port in endpoints:
        lines += ["", f"[UdpEndpoint {name}]", "Mode = Normal", "Address = 127.0.0.1", f"Port = {port}"]
        if name in clients:
            lines.append("Lockstep = client")
        if name == "odometry":
            lines.append("AllowMsgIdOut = " + ",".join(str(m) for m in ODOMETRY_MESSAGES))
        if name in links:
            lines += link_lines(links[name], seed)
    lines += ["", "[UdpEndpoint adhoc]", "Mode = Server", "Address = 0.0.0.0", f"Port = {ports.adhoc}"]
    if "adhoc" in links:
        lines += link_lines(links["adhoc"], seed)
    return "\n".join([*lines, ""])

"""``uav-sitl`` / ``python -m sitl``: run the simulated vehicle.

Configuration: ``--config`` (default ``$UAV_SITL_CONFIG``, else the repository's
``config/sitl.yaml``, else built-in defaults), then the flags below, then
``--set key=value`` (any config key, YAML value). See docs/sitl.md.
"""

from __future__ import annotations

import argparse
import logging
import os
import signal
import sys
from pathlib import Path
from typing import Any

import yaml

from sitl.config import EstimatorPreset, SitlConfig, load_sitl_config
from sitl.errors import LinkError, SitlConfigError, SitlError
from uav_common.exit_codes import ExitCode

__all__ = ["build_parser", "default_config_path", "main", "overrides_from_args"]

log = logging.getLogger("sitl")

EXIT_CONFIG = int(ExitCode.CONFIG)
EXIT_LINK = int(ExitCode.RESOURCE)
EXIT_ERROR = int(ExitCode.FAILURE)


def default_config_path() -> Path | None:
    """``$UAV_SITL_CONFIG``, else ``config/sitl.yaml`` of the source checkout, else ``None``."""
    env = os.environ.get("UAV_SITL_CONFIG")
    if env:
        return Path(env)
    for parent in Path(__file__).resolve().parents:
        candidate = parent / "config" / "sitl.yaml"
        if candidate.is_file():
            return candidate
    return None


def build_parser() -> argparse.ArgumentParser:
    p = argparse.ArgumentParser(
        prog="uav-sitl",
        description="JSBSim F450 quadrotor behind a PX4- or ArduPilot-compatible MAVLink autopilot (see docs/sitl.md).",
    )
    p.add_argument("--config", type=Path, help="YAML config (default: $UAV_SITL_CONFIG or config/sitl.yaml)")
    p.add_argument("--no-config", action="store_true", help="ignore config files; built-in defaults + flags only")
    p.add_argument(
        "--set",
        action="append",
        default=[],
        metavar="KEY=VALUE",
        help="override any config key, e.g. --set battery.initial_soc=0.5 (repeatable; YAML value)",
    )
    p.add_argument(
        "--autopilot",
        metavar="NAME",
        help="the autopilot personality: px4 (default) or ardupilot (ArduCopter's heartbeat, modes, parameters)",
    )
    p.add_argument("--speed-factor", help="simulation speed: a number (1 = real time) or 'max'")
    p.add_argument("--lockstep", action="store_true", help="advance time only on SIM_STEP grants (sim link)")
    p.add_argument("--home", metavar="LAT,LON,ALT", help="home latitude, longitude (deg) and altitude AMSL (m)")
    p.add_argument("--gcs-port", type=int, help="GCS link remote UDP port (default 14550)")
    p.add_argument("--gcs-local-port", type=int, help="GCS link local UDP port (default 18570)")
    p.add_argument("--api-port", type=int, help="API link remote UDP port (default 14540)")
    p.add_argument("--api-local-port", type=int, help="API link local UDP port (default 14580)")
    p.add_argument("--tcp-port", type=int, help="TCP server port (default 5760)")
    p.add_argument("--sim-port", type=int, help="simulation link UDP port (default 4560)")
    for name, what in (
        ("gcs", "GCS UDP link"),
        ("api", "API UDP link"),
        ("tcp", "TCP server"),
        ("sim-link", "sim link"),
    ):
        p.add_argument(f"--no-{name}", action="store_true", help=f"disable the {what}")
    p.add_argument("--params-file", type=Path, help="persisted parameter file")
    p.add_argument("--no-params-file", action="store_true", help="do not persist parameters")
    p.add_argument("--reset-params", action="store_true", help="delete the parameter file first (back to defaults)")
    p.add_argument("--estimator", choices=("truth", "noisy"), help="report the truth or truth + seeded noise")
    p.add_argument(
        "--estimator-preset",
        choices=tuple(e.value for e in EstimatorPreset),
        help="the noisy estimator with a preset's numbers (RTK fixed, single-band GPS, poor GPS); implies noisy",
    )
    p.add_argument("--seed", type=int, help="estimator noise seed")
    p.add_argument("--wind", metavar="SPEED_MPS,FROM_DEG", help="mean wind at wind.reference_height_m, e.g. 8,270")
    p.add_argument(
        "--turbulence", choices=("none", "light", "moderate", "severe"), help="Dryden turbulence (MIL-F-8785C level)"
    )
    p.add_argument("--duration", type=float, help="stop after this much simulation time (s)")
    p.add_argument("--print-config", action="store_true", help="print the effective configuration and exit")
    p.add_argument("--log-level", default="INFO", choices=("DEBUG", "INFO", "WARNING", "ERROR"))
    return p


def _parse_value(text: str) -> Any:
    try:
        return yaml.safe_load(text)
    except yaml.YAMLError:
        return text


def overrides_from_args(args: argparse.Namespace) -> dict[str, Any]:  # noqa: PLR0912
    """Dotted config overrides from the flags (``--set`` last, so it wins)."""
    out: dict[str, Any] = {}
    if args.autopilot is not None:
        out["autopilot"] = args.autopilot.strip().lower()
    if args.speed_factor is not None:
        out["time.speed_factor"] = "max" if args.speed_factor == "max" else _parse_value(args.speed_factor)
    if args.lockstep:
        out["time.mode"] = "lockstep"
    if args.home is not None:
        parts = args.home.split(",")
        if len(parts) != 3:
            msg = f"--home expects LAT,LON,ALT, got {args.home!r}"
            raise SitlConfigError(msg)
        for key, text in zip(("lat_deg", "lon_deg", "alt_amsl_m"), parts, strict=True):
            out[f"home.{key}"] = _parse_value(text)
    ports = {
        "gcs_port": "links.gcs.remote_port",
        "gcs_local_port": "links.gcs.local_port",
        "api_port": "links.api.remote_port",
        "api_local_port": "links.api.local_port",
        "tcp_port": "links.tcp.port",
        "sim_port": "sim_link.port",
    }
    for attr, key in ports.items():
        value = getattr(args, attr)
        if value is not None:
            out[key] = value
    for flag, key in (
        ("no_gcs", "links.gcs.enabled"),
        ("no_api", "links.api.enabled"),
        ("no_tcp", "links.tcp.enabled"),
        ("no_sim_link", "sim_link.enabled"),
    ):
        if getattr(args, flag):
            out[key] = False
    if args.params_file is not None:
        out["params.file"] = str(args.params_file)
    if args.no_params_file:
        out["params.file"] = None
    if args.estimator_preset is not None:
        out["estimator.preset"] = args.estimator_preset
        out["estimator.mode"] = "noisy"
    if args.estimator is not None:
        out["estimator.mode"] = args.estimator
    if args.seed is not None:
        out["estimator.seed"] = args.seed
    if args.wind is not None:
        parts = args.wind.split(",")
        if len(parts) != 2:
            msg = f"--wind expects SPEED_MPS,FROM_DEG (e.g. 8,270), got {args.wind!r}"
            raise SitlConfigError(msg)
        out["wind.speed_mps"] = _parse_value(parts[0])
        out["wind.from_deg"] = _parse_value(parts[1])
    if args.turbulence is not None:
        out["wind.turbulence"] = args.turbulence
    for item in args.set:
        key, sep, value = item.partition("=")
        if not sep or not key:
            msg = f"--set expects KEY=VALUE, got {item!r}"
            raise SitlConfigError(msg)
        out[key.strip()] = _parse_value(value)
    return out


def load_from_args(args: argparse.Namespace) -> SitlConfig:
    path = None if args.no_config else (args.config or default_config_path())
    return load_sitl_config(path, overrides_from_args(args))


def main(argv: list[str] | None = None) -> int:  # noqa: PLR0911 - one exit per failure kind
    args = build_parser().parse_args(argv)
    logging.basicConfig(
        level=getattr(logging, args.log_level),
        format="%(asctime)s %(levelname)s %(name)s: %(message)s",
        stream=sys.stderr,
    )
    try:
        cfg = load_from_args(args)
    except SitlConfigError as err:
        sys.stderr.write(f"uav-sitl: configuration error: {err}\n")
        return EXIT_CONFIG
    if args.print_config:
        from uav_common.config import to_mapping  # noqa: PLC0415

        sys.stdout.write(yaml.safe_dump(to_mapping(cfg), sort_keys=False))
        return 0
    from sitl.simulator import Simulator  # noqa: PLC0415 - imports JSBSim; keep --help and config errors fast

    try:
        sim = Simulator(cfg, reset_params=args.reset_params)
    except LinkError as err:
        sys.stderr.write(f"uav-sitl: {err}\n")
        return EXIT_LINK
    except SitlConfigError as err:
        sys.stderr.write(f"uav-sitl: configuration error: {err}\n")
        return EXIT_CONFIG
    except SitlError as err:
        sys.stderr.write(f"uav-sitl: {err}\n")
        return EXIT_ERROR

    def _on_signal(signum: int, _frame: object) -> None:
        log.info("signal %d: stopping", signum)
        sim.stop()

    signal.signal(signal.SIGINT, _on_signal)
    signal.signal(signal.SIGTERM, _on_signal)
    try:
        summary = sim.run(max_sim_time_s=args.duration)
    except SitlError as err:
        sys.stderr.write(f"uav-sitl: {err}\n")
        return EXIT_ERROR
    finally:
        sim.log_stats()
        sim.close()
    log.info(
        "stopped after %.1f s simulated in %.1f s wall (%.1fx real time)",
        summary.sim_time_s,
        summary.wall_time_s,
        summary.real_time_factor,
    )
    return 0

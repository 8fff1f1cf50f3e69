"""``uav-mavlink-router``: the command line, compatible with ``mavlink-routerd``.

::

    uav-mavlink-router [OPTIONS...] [<uart>|<udp_address>]...

    <uart>                      serial device <device>[:<baud>] to route
    <udp_address>               <ip>:<port> to bind and route ('Server' mode)
    -e, --endpoint <ip[:port]>  UDP client endpoint ('Normal' mode; port 14550, 14551, ... if omitted)
    -p, --tcp-endpoint <ip:port> TCP client endpoint (reconnects)
    -t, --tcp-port <port>       TCP server port (0 = off; default 5760)
    -c, --conf-file <file>      configuration file (INI, mavlink-routerd format)
    -d, --conf-dir <dir>        directory of more configuration files (alphabetical)
    -l, --log <dir>             write .tlog telemetry logs (and router-stats.json) here
    -T, --telemetry-log         log telemetry (.tlog); on by default whenever -l/Log is set
    -r, --report_msg_statistics print per-endpoint statistics periodically
    -s, --sniffer-sysid <id>    endpoints that saw this system get all traffic
    -g, --debug-log-level <l>   error, warning, info, debug or trace
    -v, --verbose               same as -g debug
    -V, --version               print the version and exit

Extensions: ``--stats-file``, ``--stats-interval``, ``--dialect``. The signing key
is never accepted on the command line: use ``SigningKeyFile`` in a config file.

Without ``-c``, the file named by ``MAVLINK_ROUTERD_CONF_FILE`` or
``/etc/mavlink-router/main.conf`` is read if it exists, then the files of
``-d`` / ``MAVLINK_ROUTERD_CONF_DIR`` / ``/etc/mavlink-router/config.d``, as
mavlink-routerd does. Command-line options override the files.
"""

from __future__ import annotations

import argparse
import dataclasses
import logging
import os
import signal
import stat
import sys
from collections.abc import Sequence
from importlib import metadata
from pathlib import Path
from types import FrameType

from mavlink_router.core.config import (
    DEFAULT_BAUD,
    DEFAULT_RETRY_TIMEOUT_S,
    LOG_LEVELS,
    EndpointOptions,
    GeneralConfig,
    RouterConfig,
    TcpEndpointConfig,
    UartEndpointConfig,
    UdpEndpointConfig,
    UdpMode,
    config_dir_files,
    load_config_files,
    next_udp_client_port,
)
from mavlink_router.errors import ConfigError, EndpointError, RouterError
from mavlink_router.shell.dialect import DIALECTS, load_message_table
from uav_common.exit_codes import ExitCode

__all__ = ["build_config", "main", "parse_args"]

DEFAULT_CONF_FILE = Path("/etc/mavlink-router/main.conf")
DEFAULT_CONF_DIR = Path("/etc/mavlink-router/config.d")
EXIT_USAGE = int(ExitCode.CONFIG)
EXIT_FAILURE = int(ExitCode.FAILURE)
EXIT_RESOURCE = int(ExitCode.RESOURCE)
TRACE = 5

_LOG = logging.getLogger("mavlink_router")


def _version() -> str:
    try:
        return metadata.version("uav-mavlink-router")
    except metadata.PackageNotFoundError:
        return "unknown"


def _parser() -> argparse.ArgumentParser:
    p = argparse.ArgumentParser(
        prog="uav-mavlink-router",
        description="MAVLink router with mavlink-routerd's command line, configuration format and routing rules.",
        epilog="Every configuration key is documented in docs/mavlink_router.md.",
    )
    p.add_argument(
        "positional", nargs="*", metavar="<uart>|<udp_address>", help="device[:baud] or ip:port (UDP server)"
    )
    p.add_argument("-e", "--endpoint", action="append", default=[], metavar="IP[:PORT]", help="UDP client endpoint")
    p.add_argument("-p", "--tcp-endpoint", action="append", default=[], metavar="IP:PORT", help="TCP client endpoint")
    p.add_argument("-t", "--tcp-port", type=int, metavar="PORT", help="TCP server port, 0 = off (default 5760)")
    p.add_argument("-c", "--conf-file", type=Path, metavar="FILE", help="configuration file")
    p.add_argument("-d", "--conf-dir", type=Path, metavar="DIR", help="directory of configuration files")
    p.add_argument("-l", "--log", type=Path, metavar="DIR", help="telemetry log directory")
    p.add_argument("-T", "--telemetry-log", action="store_true", help="log telemetry (.tlog); default with -l")
    p.add_argument("-r", "--report_msg_statistics", action="store_true", help="print statistics periodically")
    p.add_argument("-s", "--sniffer-sysid", type=int, metavar="ID", help="sniffer system ID")
    p.add_argument("-g", "--debug-log-level", choices=LOG_LEVELS, metavar="LEVEL", help=", ".join(LOG_LEVELS))
    p.add_argument("-v", "--verbose", action="store_true", help="same as --debug-log-level debug")
    p.add_argument("-V", "--version", action="version", version=f"uav-mavlink-router {_version()}")
    p.add_argument(
        "--stats-file", type=Path, metavar="FILE", help="JSON statistics file (default LOG/router-stats.json)"
    )
    p.add_argument("--stats-interval", type=float, metavar="S", help="statistics period in seconds (default 5)")
    p.add_argument("--dialect", choices=sorted(DIALECTS), help="message table for CRC and targets (default auto)")
    return p


def parse_args(argv: Sequence[str] | None) -> argparse.Namespace:
    return _parser().parse_args(argv)


def _split_host_port(text: str, option: str, *, port_required: bool) -> tuple[str, int | None]:
    host, sep, port_text = text.rpartition(":")
    if not sep or not host:
        if port_required:
            msg = f"{option} {text!r}: expected <ip>:<port>, e.g. 127.0.0.1:14550"
            raise ConfigError(msg)
        return text, None
    if host.count(":") and not host.startswith("["):
        msg = f"{option} {text!r}: write IPv6 addresses in brackets, e.g. [::1]:14550"
        raise ConfigError(msg)
    try:
        port = int(port_text, 10)
    except ValueError:
        msg = f"{option} {text!r}: the port must be a number from 1 to 65535"
        raise ConfigError(msg) from None
    if not 1 <= port <= 65535:
        msg = f"{option} {text!r}: the port must be from 1 to 65535"
        raise ConfigError(msg)
    return host, port


def _check_ip(host: str, option: str, text: str) -> str:
    import ipaddress  # noqa: PLC0415

    inner = host[1:-1] if host.startswith("[") else host
    try:
        ipaddress.ip_address(inner)
    except ValueError:
        msg = f"{option} {text!r}: {host!r} is not a numeric IP address (e.g. 127.0.0.1, [::1])"
        raise ConfigError(msg) from None
    return host


def _is_char_device(path: str) -> bool:
    try:
        return stat.S_ISCHR(os.stat(path).st_mode)
    except OSError:
        return False


def _config_files(args: argparse.Namespace) -> list[Path]:
    files: list[Path] = []
    if args.conf_file is not None:
        files.append(args.conf_file)
    else:
        env_file = os.environ.get("MAVLINK_ROUTERD_CONF_FILE")
        if env_file:
            files.append(Path(env_file))
        elif DEFAULT_CONF_FILE.is_file():
            files.append(DEFAULT_CONF_FILE)
    conf_dir = args.conf_dir or (
        Path(os.environ["MAVLINK_ROUTERD_CONF_DIR"]) if os.environ.get("MAVLINK_ROUTERD_CONF_DIR") else DEFAULT_CONF_DIR
    )
    if args.conf_dir is not None and not args.conf_dir.is_dir():
        msg = f"-d {args.conf_dir}: not a directory"
        raise ConfigError(msg)
    files.extend(config_dir_files(conf_dir))
    return files


def _general_overrides(general: GeneralConfig, args: argparse.Namespace) -> GeneralConfig:
    checks = (
        (args.tcp_port, 0, 65535, "-t", "the TCP server port must be from 0 (off) to 65535"),
        (args.sniffer_sysid, 0, 255, "-s", "a system ID is from 0 to 255"),
    )
    for value, lo, hi, option, problem in checks:
        if value is not None and not lo <= value <= hi:
            msg = f"{option} {value}: {problem}"
            raise ConfigError(msg)
    if args.stats_interval is not None and not args.stats_interval > 0:
        msg = f"--stats-interval {args.stats_interval}: must be > 0 seconds"
        raise ConfigError(msg)
    level = "debug" if args.verbose else args.debug_log_level
    candidates: dict[str, object] = {
        "tcp_server_port": args.tcp_port,
        "log_dir": args.log,
        "log_telemetry": True if args.telemetry_log else None,
        "report_stats": True if args.report_msg_statistics else None,
        "sniffer_sysid": args.sniffer_sysid,
        "debug_log_level": level,
        "stats_file": args.stats_file,
        "stats_interval_s": args.stats_interval,
        "mavlink_dialect": args.dialect,
    }
    changes = {key: value for key, value in candidates.items() if value is not None}
    return dataclasses.replace(general, **changes)  # type: ignore[arg-type]


def _positional(text: str, options: EndpointOptions) -> UdpEndpointConfig | UartEndpointConfig:
    """mavlink-routerd's positional argument: a serial device[:baud], else a UDP server ip:port."""
    base, _, number = text.rpartition(":")
    if base and _is_char_device(base):
        baud = int(number) if number.isdigit() else DEFAULT_BAUD
        bauds = (baud, DEFAULT_BAUD) if baud != DEFAULT_BAUD else (baud,)
        return UartEndpointConfig(f"cli-uart-{base}", base, bauds, False, options)
    if _is_char_device(text):
        return UartEndpointConfig(f"cli-uart-{text}", text, (DEFAULT_BAUD,), False, options)
    host, port = _split_host_port(text, "argument", port_required=True)
    assert port is not None
    return UdpEndpointConfig(f"cli-udp-server-{port}", _check_ip(host, "argument", text), port, UdpMode.SERVER, options)


def build_config(args: argparse.Namespace) -> tuple[RouterConfig, list[Path]]:
    """Configuration files merged with the command line (the command line wins)."""
    files = _config_files(args)
    config = load_config_files(files) if files else RouterConfig()
    general = _general_overrides(config.general, args)
    udp = list(config.udp)
    tcp = list(config.tcp)
    uart = list(config.uart)
    taken = [(u.address, u.port) for u in udp if u.mode is UdpMode.NORMAL]
    options = EndpointOptions(tx_queue_limit=general.tx_queue_limit)
    for text in args.endpoint:
        host, port = _split_host_port(text, "-e", port_required=False)
        host = _check_ip(host, "-e", text)
        if port is None:
            port = next_udp_client_port(host, taken)
        taken.append((host, port))
        udp.append(UdpEndpointConfig(f"cli-udp-{host}:{port}", host, port, UdpMode.NORMAL, options))
    for text in args.tcp_endpoint:
        host, port = _split_host_port(text, "-p", port_required=True)
        assert port is not None
        host = _check_ip(host, "-p", text)
        tcp.append(TcpEndpointConfig(f"cli-tcp-{host}:{port}", host, port, DEFAULT_RETRY_TIMEOUT_S, options))
    for text in args.positional:
        endpoint = _positional(text, options)
        if isinstance(endpoint, UartEndpointConfig):
            uart.append(endpoint)
        else:
            udp.append(endpoint)
    return RouterConfig(general, tuple(udp), tuple(tcp), tuple(uart)), files


def _setup_logging(level_name: str) -> None:
    logging.addLevelName(TRACE, "TRACE")
    level = {"error": logging.ERROR, "warning": logging.WARNING, "info": logging.INFO, "debug": logging.DEBUG}.get(
        level_name, TRACE
    )
    logging.basicConfig(
        level=level,
        format="%(asctime)s.%(msecs)03d %(levelname)-7s %(name)s: %(message)s",
        datefmt="%H:%M:%S",
        stream=sys.stderr,
        force=True,
    )


def main(argv: Sequence[str] | None = None) -> int:
    """Entry point of ``uav-mavlink-router`` and ``python -m mavlink_router``."""
    args = parse_args(argv)
    _setup_logging(args.debug_log_level or ("debug" if args.verbose else "info"))
    try:
        config, files = build_config(args)
        _setup_logging(config.general.debug_log_level)
        if config.endpoint_count == 0 and not config.general.tcp_server_port:
            msg = "nothing to route: give endpoints (-e, -p, <ip:port>, <device>) or a configuration file (-c)"
            raise ConfigError(msg)
        table = load_message_table(config.general.mavlink_dialect)
        from mavlink_router.shell.mainloop import Router  # noqa: PLC0415 - keep --help fast

        router = Router(config, table)
    except ConfigError as err:
        _LOG.error("configuration error: %s", err)
        return EXIT_USAGE
    except EndpointError as err:
        _LOG.error("%s", err)
        return EXIT_RESOURCE
    except RouterError as err:
        _LOG.error("%s", err)
        return EXIT_FAILURE
    _LOG.info(
        "uav-mavlink-router %s; configuration: %s",
        _version(),
        ", ".join(map(str, files)) if files else "command line only",
    )

    def on_signal(signum: int, frame: FrameType | None) -> None:
        _LOG.info("%s received", signal.Signals(signum).name)
        router.request_stop()

    previous = {sig: signal.signal(sig, on_signal) for sig in (signal.SIGINT, signal.SIGTERM)}
    old_wakeup = signal.set_wakeup_fd(router.wakeup_fd, warn_on_full_buffer=False)
    try:
        router.run()
    except RouterError as err:
        _LOG.error("%s", err)
        return EXIT_FAILURE
    finally:
        signal.set_wakeup_fd(old_wakeup)
        for sig, handler in previous.items():
            signal.signal(sig, handler)
    return 0

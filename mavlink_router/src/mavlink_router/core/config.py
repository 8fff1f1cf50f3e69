"""Configuration: mavlink-routerd's INI format, parsed strictly into frozen dataclasses.

File syntax (as ``mavlink-routerd``'s ``ConfFile``): ``[Section]`` or
``[Section name]`` headers, ``Key = Value`` lines, comment lines starting with
``#`` or ``;``, no inline comments. Section types, section names and keys are
case-insensitive. A section that appears twice is merged; a key that appears
twice keeps its last value. Several files (``-c`` file, then every file of the
``-d`` directory in alphabetical order) are merged the same way.

Unlike mavlink-routerd, an unknown section type or key is an error (a typo must
not silently disable a filter or the signing requirement). Every error names
the file and line, the section, the key, what is wrong and what to do.

Relative paths (``Log``, ``StatsFile``, ``SigningKeyFile``) are relative to the
directory of the file that sets them.

See ``docs/mavlink_router.md`` for every key.
"""

from __future__ import annotations

import difflib
import enum
import ipaddress
import posixpath
from collections.abc import Callable, Iterable, Mapping
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any, TypeVar

from mavlink_router.core.impairment import ImpairmentConfig, LinkDirection
from mavlink_router.core.routing import Filters
from mavlink_router.errors import ConfigError

__all__ = [
    "DEFAULT_BAUD",
    "DEFAULT_RETRY_TIMEOUT_S",
    "DEFAULT_TCP_SERVER_PORT",
    "DEFAULT_TX_QUEUE_LIMIT",
    "EndpointOptions",
    "GeneralConfig",
    "LockstepRole",
    "LogMode",
    "RouterConfig",
    "TcpEndpointConfig",
    "UartEndpointConfig",
    "UdpEndpointConfig",
    "UdpMode",
    "load_config_files",
    "parse_config_text",
]

DEFAULT_TCP_SERVER_PORT = 5760
DEFAULT_RETRY_TIMEOUT_S = 5.0
DEFAULT_BAUD = 115200
DEFAULT_TX_QUEUE_LIMIT = 256
DEFAULT_STATS_INTERVAL_S = 5.0
FIRST_UDP_CLIENT_PORT = 14550

T = TypeVar("T")

#: ``MavlinkDialect`` values and the pymavlink dialect each loads.
DIALECTS = {
    # mavlink-router's "auto" resolves to the ardupilotmega C library, a superset of common.
    "auto": "ardupilotmega",
    "ardupilotmega": "ardupilotmega",
    "common": "common",
    "development": "development",
    "all": "all",
}


class UdpMode(enum.Enum):
    NORMAL = "normal"
    """Client: send to Address:Port; replies go to the last sender (5 s, then back)."""
    SERVER = "server"
    """Bind Address:Port; send to whoever sent the last packet."""


class LogMode(enum.Enum):
    ALWAYS = "always"
    WHILE_ARMED = "while-armed"


LOG_LEVELS = ("error", "warning", "info", "debug", "trace")


class LockstepRole(enum.Enum):
    """An endpoint's part in the lockstep (``Lockstep = ...`` in its section; docs/mavlink_router.md)."""

    AUTOPILOT = "autopilot"
    """Its STEP markers are the router's clock; it gets the router's HELLO on every (re)connect."""
    CLIENT = "client"
    """Invited: it gets the router's HELLO every second until it says HELLO itself (a ``udpin:`` client cannot
    speak first). Any endpoint becomes a lockstep client by saying HELLO; this only invites."""


@dataclass(frozen=True)
class EndpointOptions:
    """Options every endpoint type has (filters, grouping, signing, queue)."""

    in_filter: Filters = field(default_factory=Filters)
    out_filter: Filters = field(default_factory=Filters)
    group: str = ""
    ignore_comp_id: bool = False
    require_signing: bool = False
    signing_key_file: Path | None = None
    tx_queue_limit: int = DEFAULT_TX_QUEUE_LIMIT
    #: A lossy radio link in front of this endpoint (None: a perfect link). See core/impairment.py.
    link: ImpairmentConfig | None = None
    #: Its part in the lockstep (None: none declared; it may still become a client by saying HELLO).
    lockstep: LockstepRole | None = None


@dataclass(frozen=True)
class UdpEndpointConfig:
    name: str
    address: str
    port: int
    mode: UdpMode
    options: EndpointOptions = field(default_factory=EndpointOptions)
    coalesce: bool = True
    """Pack frames routed together to this endpoint into one datagram (up to 1400 bytes)."""


@dataclass(frozen=True)
class TcpEndpointConfig:
    name: str
    address: str
    port: int
    retry_timeout_s: float = DEFAULT_RETRY_TIMEOUT_S
    options: EndpointOptions = field(default_factory=EndpointOptions)


@dataclass(frozen=True)
class UartEndpointConfig:
    name: str
    device: str
    bauds: tuple[int, ...] = (DEFAULT_BAUD,)
    flow_control: bool = False
    options: EndpointOptions = field(default_factory=EndpointOptions)


@dataclass(frozen=True)
class GeneralConfig:
    tcp_server_port: int = DEFAULT_TCP_SERVER_PORT
    report_stats: bool = False
    debug_log_level: str = "info"
    dedup_period_ms: int = 0
    sniffer_sysid: int = 0
    log_dir: Path | None = None
    log_mode: LogMode = LogMode.ALWAYS
    mavlink_dialect: str = "auto"
    min_free_space_bytes: int = 0
    max_log_files: int = 0
    log_system_id: int | None = None
    log_telemetry: bool = True
    stats_file: Path | None = None
    stats_interval_s: float = DEFAULT_STATS_INTERVAL_S
    signing_key_file: Path | None = None
    tcp_server_require_signing: bool = False
    tx_queue_limit: int = DEFAULT_TX_QUEUE_LIMIT
    #: Lockstep with the autopilot's step markers (docs/mavlink_router.md, "Lockstep").
    lockstep: bool = False


@dataclass(frozen=True)
class RouterConfig:
    general: GeneralConfig = field(default_factory=GeneralConfig)
    udp: tuple[UdpEndpointConfig, ...] = ()
    tcp: tuple[TcpEndpointConfig, ...] = ()
    uart: tuple[UartEndpointConfig, ...] = ()

    @property
    def endpoint_count(self) -> int:
        return len(self.udp) + len(self.tcp) + len(self.uart)


# --------------------------------------------------------------------------------------
# Raw INI layer


@dataclass
class _Value:
    key: str
    text: str
    source: str
    line: int
    base_dir: Path


@dataclass
class _Section:
    kind: str  # lower-case section type: general, udpendpoint, tcpendpoint, uartendpoint
    name: str  # as first written ("" for [General])
    source: str
    line: int
    values: dict[str, _Value] = field(default_factory=dict)  # lower-case key -> value


_SECTION_KINDS = {
    "general": "General",
    "udpendpoint": "UdpEndpoint",
    "tcpendpoint": "TcpEndpoint",
    "uartendpoint": "UartEndpoint",
}


def _parse_sections(text: str, source: str, base_dir: Path, into: dict[tuple[str, str], _Section]) -> None:
    current: _Section | None = None
    for number, raw_line in enumerate(text.splitlines(), start=1):
        line = raw_line.strip()
        if not line or line[0] in "#;":
            continue
        where = f"{source}:{number}"
        if line[0] == "[":
            current = _parse_header(line, where, source, number, into)
            continue
        if current is None:
            msg = f"{where}: option {line!r} appears before any section; put it under [General] or an endpoint section"
            raise ConfigError(msg)
        key, sep, value = line.partition("=")
        key, value = key.strip(), value.strip()
        if not sep:
            msg = f"{where}: expected 'Key = Value', got {line!r}"
            raise ConfigError(msg)
        if not key:
            msg = f"{where}: missing key name before '=' in {line!r}"
            raise ConfigError(msg)
        if not value:
            msg = f"{where}: key {key!r} has no value; give one or delete the line"
            raise ConfigError(msg)
        current.values[key.lower()] = _Value(key, value, source, number, base_dir)


def _parse_header(line: str, where: str, source: str, number: int, into: dict[tuple[str, str], _Section]) -> _Section:
    if not line.endswith("]"):
        msg = f"{where}: section header {line!r} must end with ']' (and nothing after it)"
        raise ConfigError(msg)
    inner = line[1:-1]
    if inner != inner.strip() or not inner:
        msg = f"{where}: section header {line!r} must not be empty or start/end with spaces"
        raise ConfigError(msg)
    kind, _, name = inner.partition(" ")
    if " " in name or "\t" in inner:
        msg = f"{where}: section header {line!r}: use '[Type name]' with one space and a name without spaces"
        raise ConfigError(msg)
    kind_key = kind.lower()
    if kind_key not in _SECTION_KINDS:
        hint = _suggest(kind, _SECTION_KINDS.values())
        msg = f"{where}: unknown section type {kind!r}{hint}; known: {', '.join(_SECTION_KINDS.values())}"
        raise ConfigError(msg)
    if kind_key == "general" and name:
        msg = f"{where}: [General] takes no name; write '[General]'"
        raise ConfigError(msg)
    if kind_key != "general" and not name:
        msg = f"{where}: [{_SECTION_KINDS[kind_key]}] needs a name, e.g. '[{_SECTION_KINDS[kind_key]} gcs]'"
        raise ConfigError(msg)
    section_key = (kind_key, name.lower())
    section = into.get(section_key)
    if section is None:
        section = into[section_key] = _Section(kind_key, name, source, number)
    return section


def _suggest(word: str, choices: Iterable[str]) -> str:
    by_lower = {c.lower(): c for c in choices}
    close = difflib.get_close_matches(word.lower(), list(by_lower), n=1, cutoff=0.6)
    return f" (did you mean {by_lower[close[0]]!r}?)" if close else ""


# --------------------------------------------------------------------------------------
# Value parsers: each takes the text and returns the value or raises ValueError("what to do").


def _parse_int(lo: int, hi: int) -> Callable[[str], int]:
    def parse(text: str) -> int:
        try:
            value = int(text, 10)
        except ValueError:
            msg = f"expected a whole number from {lo} to {hi}"
            raise ValueError(msg) from None
        if not lo <= value <= hi:
            msg = f"must be from {lo} to {hi}"
            raise ValueError(msg)
        return value

    return parse


def _parse_float(lo: float, hi: float) -> Callable[[str], float]:
    def parse(text: str) -> float:
        try:
            value = float(text)
        except ValueError:
            msg = f"expected a number from {lo:g} to {hi:g}"
            raise ValueError(msg) from None
        if not lo <= value <= hi:
            msg = f"must be from {lo:g} to {hi:g}"
            raise ValueError(msg)
        return value

    return parse


def _parse_bool(text: str) -> bool:
    lowered = text.lower()
    if lowered in ("true", "1"):
        return True
    if lowered in ("false", "0"):
        return False
    msg = "expected true, false, 1 or 0"
    raise ValueError(msg)


def _parse_int_list(lo: int, hi: int) -> Callable[[str], frozenset[int]]:
    one = _parse_int(lo, hi)

    def parse(text: str) -> frozenset[int]:
        items = [item.strip() for item in text.split(",")]
        if any(not item for item in items):
            msg = f"expected a comma-separated list of whole numbers from {lo} to {hi}, e.g. '0,1,33'"
            raise ValueError(msg)
        try:
            return frozenset(one(item) for item in items)
        except ValueError as err:
            msg = f"every item {err}; write a comma-separated list such as '0,1,33'"
            raise ValueError(msg) from None

    return parse


def _parse_choice(choices: Iterable[str]) -> Callable[[str], str]:
    options = tuple(choices)

    def parse(text: str) -> str:
        lowered = text.lower()
        if lowered not in options:
            msg = f"expected one of {', '.join(options)}"
            raise ValueError(msg)
        return lowered

    return parse


def _parse_udp_mode(text: str) -> UdpMode:
    lowered = text.lower()
    if lowered == "normal":
        return UdpMode.NORMAL
    if lowered in ("server", "eavesdropping"):  # mavlink-routerd accepts the deprecated name
        return UdpMode.SERVER
    msg = "expected Normal (client: send to Address:Port) or Server (bind Address:Port)"
    raise ValueError(msg)


def _parse_address(text: str) -> str:
    inner = text[1:-1] if text.startswith("[") and text.endswith("]") else text
    try:
        parsed = ipaddress.ip_address(inner)
    except ValueError:
        msg = "expected a numeric IPv4 address (e.g. 127.0.0.1) or an IPv6 address in brackets (e.g. [::1])"
        raise ValueError(msg) from None
    if parsed.version == 6 and inner == text:
        msg = "IPv6 addresses must be written in square brackets, e.g. [::1]"
        raise ValueError(msg)
    return text


def _parse_text(text: str) -> str:
    return text


_PORT = _parse_int(1, 65535)
_ID_LIST = _parse_int_list(0, 255)
_MSG_ID_LIST = _parse_int_list(0, 0xFFFFFF)


# --------------------------------------------------------------------------------------
# Section schemas


class _Reader:
    """Pulls typed values out of one section and rejects unknown keys."""

    def __init__(self, section: _Section, known: Iterable[str]) -> None:
        self.section = section
        kind = _SECTION_KINDS[section.kind]
        self.title = f"[{kind} {section.name}]" if section.name else f"[{kind}]"
        self._known = tuple(known)
        self._reject_unknown()

    def get(self, key: str, parse: Callable[[str], T], default: T) -> T:
        value = self._lookup(key)
        if value is None:
            return default
        return self._convert(value, parse)

    def require(self, key: str, parse: Callable[[str], T], what: str) -> T:
        value = self._lookup(key)
        if value is None:
            msg = (
                f"{self.section.source}:{self.section.line}: {self.title} needs '{key} = ...' ({what}); "
                "add the key to the section"
            )
            raise ConfigError(msg)
        return self._convert(value, parse)

    def path(self, key: str) -> Path | None:
        value = self._lookup(key)
        if value is None:
            return None
        path = Path(value.text).expanduser()
        return Path(posixpath.normpath(path if path.is_absolute() else value.base_dir / path))

    def has(self, key: str) -> bool:
        return self._lookup(key) is not None

    def where(self, key: str) -> str:
        value = self.section.values.get(key.lower())
        line = value.line if value is not None else self.section.line
        source = value.source if value is not None else self.section.source
        return f"{source}:{line}: {self.title}"

    def _reject_unknown(self) -> None:
        """An unknown key is reported first: a typo also explains a "missing" key."""
        known_lower = {k.lower() for k in self._known}
        for lowered, value in self.section.values.items():
            if lowered not in known_lower:
                hint = _suggest(value.key, self._known)
                msg = (
                    f"{value.source}:{value.line}: {self.title} has unknown key {value.key!r}{hint}; "
                    f"keys of this section: {', '.join(self._known)}"
                )
                raise ConfigError(msg)

    def _lookup(self, key: str) -> _Value | None:
        lowered = key.lower()
        assert lowered in {k.lower() for k in self._known}, f"schema bug: {key} is read but not declared"
        return self.section.values.get(lowered)

    def _convert(self, value: _Value, parse: Callable[[str], T]) -> T:
        try:
            return parse(value.text)
        except ValueError as err:
            msg = f"{value.source}:{value.line}: {self.title} {value.key} = {value.text!r}: {err}"
            raise ConfigError(msg) from None


_FILTER_KEYS = (
    "AllowMsgIdOut",
    "BlockMsgIdOut",
    "AllowSrcSysOut",
    "BlockSrcSysOut",
    "AllowSrcCompOut",
    "BlockSrcCompOut",
    "AllowMsgIdIn",
    "BlockMsgIdIn",
    "AllowSrcSysIn",
    "BlockSrcSysIn",
    "AllowSrcCompIn",
    "BlockSrcCompIn",
)
_LINK_KEYS = (
    "LossPercent",
    "LossBurst",
    "DelayMs",
    "JitterMs",
    "ReorderPercent",
    "ReorderDelayMs",
    "LinkDirection",
    "LinkSeed",
)
_COMMON_KEYS = (
    *_FILTER_KEYS,
    "Group",
    "IgnoreCompId",
    "RequireSigning",
    "SigningKeyFile",
    "TxQueueLimit",
    "Lockstep",
    *_LINK_KEYS,
)


def _link(reader: _Reader) -> ImpairmentConfig | None:
    """The endpoint's lossy-link keys (an extension); None when the section sets none of them."""
    if not any(reader.has(key) for key in _LINK_KEYS):
        return None
    direction = reader.get("LinkDirection", _parse_choice(d.value for d in LinkDirection), LinkDirection.BOTH.value)
    try:
        return ImpairmentConfig(
            loss_pct=reader.get("LossPercent", _parse_float(0.0, 100.0), 0.0),
            loss_burst=reader.get("LossBurst", _parse_float(0.0, 1e6), 0.0),
            delay_ms=reader.get("DelayMs", _parse_float(0.0, 60_000.0), 0.0),
            jitter_ms=reader.get("JitterMs", _parse_float(0.0, 60_000.0), 0.0),
            reorder_pct=reader.get("ReorderPercent", _parse_float(0.0, 100.0), 0.0),
            reorder_delay_ms=reader.get("ReorderDelayMs", _parse_float(0.0, 60_000.0), 50.0),
            direction=LinkDirection(direction),
            seed=reader.get("LinkSeed", _parse_int(0, 2**63 - 1), 0),
        )
    except ValueError as err:  # the cross-key rule (LossBurst against LossPercent)
        msg = f"{reader.where('LossBurst')} LossBurst: {err}; set LossBurst = 0 for independent losses"
        raise ConfigError(msg) from None


def _filters(reader: _Reader, direction: str, legacy_allow: frozenset[int] = frozenset()) -> Filters:
    empty: frozenset[int] = frozenset()
    return Filters(
        allow_msg_ids=reader.get(f"AllowMsgId{direction}", _MSG_ID_LIST, empty) | legacy_allow,
        block_msg_ids=reader.get(f"BlockMsgId{direction}", _MSG_ID_LIST, empty),
        allow_src_systems=reader.get(f"AllowSrcSys{direction}", _ID_LIST, empty),
        block_src_systems=reader.get(f"BlockSrcSys{direction}", _ID_LIST, empty),
        allow_src_comps=reader.get(f"AllowSrcComp{direction}", _ID_LIST, empty),
        block_src_comps=reader.get(f"BlockSrcComp{direction}", _ID_LIST, empty),
    )


def _options(
    reader: _Reader, general: GeneralConfig, legacy_allow_out: frozenset[int] = frozenset()
) -> EndpointOptions:
    require_signing = reader.get("RequireSigning", _parse_bool, False)
    key_file = reader.path("SigningKeyFile") or general.signing_key_file
    if require_signing and key_file is None:
        msg = (
            f"{reader.where('RequireSigning')} RequireSigning = true needs a key: set SigningKeyFile in this "
            "section or in [General] (the key is never taken from the command line)"
        )
        raise ConfigError(msg)
    return EndpointOptions(
        in_filter=_filters(reader, "In"),
        out_filter=_filters(reader, "Out", legacy_allow_out),
        group=reader.get("Group", _parse_text, ""),
        ignore_comp_id=reader.get("IgnoreCompId", _parse_bool, False),
        require_signing=require_signing,
        signing_key_file=key_file if require_signing else None,
        tx_queue_limit=reader.get("TxQueueLimit", _parse_int(1, 1_000_000), general.tx_queue_limit),
        link=_link(reader),
        lockstep=_lockstep_role(reader, general),
    )


def _lockstep_role(reader: _Reader, general: GeneralConfig) -> LockstepRole | None:
    if not reader.has("Lockstep"):
        return None
    role = LockstepRole(reader.get("Lockstep", _parse_choice(r.value for r in LockstepRole), "autopilot"))
    if not general.lockstep:
        msg = f"{reader.where('Lockstep')} Lockstep = {role.value} needs '[General] Lockstep = true'"
        raise ConfigError(msg)
    return role


_GENERAL_KEYS = (
    "TcpServerPort",
    "ReportStats",
    "DebugLogLevel",
    "DeduplicationPeriod",
    "SnifferSysid",
    "Log",
    "LogMode",
    "MavlinkDialect",
    "MinFreeSpace",
    "MaxLogFiles",
    "LogSystemId",
    "LogTelemetry",
    "StatsFile",
    "StatsInterval",
    "SigningKeyFile",
    "TcpServerRequireSigning",
    "TxQueueLimit",
    "Lockstep",
)


def _general(section: _Section | None) -> GeneralConfig:
    if section is None:
        return GeneralConfig()
    r = _Reader(section, _GENERAL_KEYS)
    log_mode_text = r.get("LogMode", _parse_choice(m.value for m in LogMode), LogMode.ALWAYS.value)
    log_system_id = r.get("LogSystemId", _parse_int(1, 255), 0)
    general = GeneralConfig(
        tcp_server_port=r.get("TcpServerPort", _parse_int(0, 65535), DEFAULT_TCP_SERVER_PORT),
        report_stats=r.get("ReportStats", _parse_bool, False),
        debug_log_level=r.get("DebugLogLevel", _parse_choice(LOG_LEVELS), "info"),
        dedup_period_ms=r.get("DeduplicationPeriod", _parse_int(0, 3_600_000), 0),
        sniffer_sysid=r.get("SnifferSysid", _parse_int(0, 255), 0),
        log_dir=r.path("Log"),
        log_mode=LogMode(log_mode_text),
        mavlink_dialect=r.get("MavlinkDialect", _parse_choice(DIALECTS), "auto"),
        min_free_space_bytes=r.get("MinFreeSpace", _parse_int(0, 2**63 - 1), 0),
        max_log_files=r.get("MaxLogFiles", _parse_int(0, 1_000_000), 0),
        log_system_id=log_system_id or None,
        log_telemetry=r.get("LogTelemetry", _parse_bool, True),
        stats_file=r.path("StatsFile"),
        stats_interval_s=r.get("StatsInterval", _parse_float(0.1, 86400.0), DEFAULT_STATS_INTERVAL_S),
        signing_key_file=r.path("SigningKeyFile"),
        tcp_server_require_signing=r.get("TcpServerRequireSigning", _parse_bool, False),
        tx_queue_limit=r.get("TxQueueLimit", _parse_int(1, 1_000_000), DEFAULT_TX_QUEUE_LIMIT),
        lockstep=r.get("Lockstep", _parse_bool, False),
    )
    if general.lockstep and general.dedup_period_ms:
        msg = (
            f"{r.where('DeduplicationPeriod')} DeduplicationPeriod = {general.dedup_period_ms} cannot be used with "
            "Lockstep = true: a wall-clock window would decide the fate of lockstep frames (every frame is "
            "counted); set DeduplicationPeriod = 0"
        )
        raise ConfigError(msg)
    if general.tcp_server_require_signing and general.signing_key_file is None:
        msg = f"{r.where('TcpServerRequireSigning')} TcpServerRequireSigning = true needs SigningKeyFile in [General]"
        raise ConfigError(msg)
    return general


def _udp(section: _Section, general: GeneralConfig, taken_client_ports: list[tuple[str, int]]) -> UdpEndpointConfig:
    r = _Reader(section, ("Address", "Mode", "Port", "Filter", "Coalesce", *_COMMON_KEYS))
    address = r.require("Address", _parse_address, "the IP to send to (Normal) or to bind (Server)")
    mode = r.require("Mode", _parse_udp_mode, "Normal or Server")
    port = r.get("Port", _PORT, 0)
    if port == 0:
        if mode is UdpMode.SERVER:
            msg = f"{r.where('Mode')} Mode = Server needs 'Port = ...' (the UDP port to bind)"
            raise ConfigError(msg)
        port = next_udp_client_port(address, taken_client_ports)
    if mode is UdpMode.NORMAL:
        taken_client_ports.append((address, port))
    no_ids: frozenset[int] = frozenset()
    legacy = r.get("Filter", _MSG_ID_LIST, no_ids)  # mavlink-routerd's old name of AllowMsgIdOut
    options = _options(r, general, legacy)
    coalesce = r.get("Coalesce", _parse_bool, True)
    return UdpEndpointConfig(section.name, address, port, mode, options, coalesce)


def _tcp(section: _Section, general: GeneralConfig) -> TcpEndpointConfig:
    r = _Reader(section, ("Address", "Port", "RetryTimeout", *_COMMON_KEYS))
    address = r.require("Address", _parse_address, "the IP to connect to")
    port = r.require("Port", _PORT, "the TCP port to connect to")
    retry = r.get("RetryTimeout", _parse_float(0.0, 86400.0), DEFAULT_RETRY_TIMEOUT_S)
    options = _options(r, general)
    return TcpEndpointConfig(section.name, address, port, retry, options)


def _uart(section: _Section, general: GeneralConfig) -> UartEndpointConfig:
    r = _Reader(section, ("Device", "Baud", "FlowControl", *_COMMON_KEYS))
    device = r.require("Device", _parse_text, "the serial device, e.g. /dev/ttyUSB0")
    default_bauds: tuple[int, ...] = (DEFAULT_BAUD,)
    bauds = r.get("Baud", _parse_baud_list, default_bauds)
    flow = r.get("FlowControl", _parse_bool, False)
    options = _options(r, general)
    return UartEndpointConfig(section.name, device, bauds, flow, options)


def _parse_baud_list(text: str) -> tuple[int, ...]:
    one = _parse_int(50, 20_000_000)
    items = [item.strip() for item in text.split(",")]
    try:
        return tuple(one(item) for item in items)
    except ValueError as err:
        msg = f"expected a baud rate or a comma-separated list of them (tried in turn), e.g. 57600,115200; {err}"
        raise ValueError(msg) from None


def next_udp_client_port(address: str, taken: list[tuple[str, int]]) -> int:
    """mavlink-routerd's default port for a UDP client: 14550, or 14551 if that is taken."""
    port = FIRST_UDP_CLIENT_PORT
    while (address, port) in taken:
        port += 1
    return port


# --------------------------------------------------------------------------------------
# Entry points


def _build(sections: Mapping[tuple[str, str], _Section]) -> RouterConfig:
    general = _general(sections.get(("general", "")))
    udp: list[UdpEndpointConfig] = []
    tcp: list[TcpEndpointConfig] = []
    uart: list[UartEndpointConfig] = []
    taken: list[tuple[str, int]] = []
    for (kind, _), section in sorted(sections.items(), key=lambda item: (item[1].source, item[1].line)):
        if kind == "udpendpoint":
            udp.append(_udp(section, general, taken))
        elif kind == "tcpendpoint":
            tcp.append(_tcp(section, general))
        elif kind == "uartendpoint":
            uart.append(_uart(section, general))
    config = RouterConfig(general, tuple(udp), tuple(tcp), tuple(uart))
    _check_lockstep(config, sections)
    return config


def _check_lockstep(config: RouterConfig, sections: Mapping[tuple[str, str], _Section]) -> None:
    """``[General] Lockstep = true`` needs exactly one ``Lockstep = autopilot`` endpoint, without a lossy link."""
    if not config.general.lockstep:
        return
    endpoints: list[UdpEndpointConfig | TcpEndpointConfig | UartEndpointConfig] = [
        *config.udp,
        *config.tcp,
        *config.uart,
    ]
    autopilots = [e for e in endpoints if e.options.lockstep is LockstepRole.AUTOPILOT]
    general = sections.get(("general", ""))
    where = f"{general.source}:{general.line}: [General]" if general is not None else "[General]"
    if not autopilots:
        msg = (
            f"{where} Lockstep = true needs one endpoint with 'Lockstep = autopilot' (the autopilot's link, whose "
            "STEP markers are the router's clock); add it to that endpoint's section"
        )
        raise ConfigError(msg)
    if len(autopilots) > 1:
        names = ", ".join(e.name for e in autopilots)
        msg = f"{where} Lockstep = true: only one endpoint may be 'Lockstep = autopilot', got {names}"
        raise ConfigError(msg)
    autopilot = autopilots[0]
    if autopilot.options.link is not None and autopilot.options.link.active:
        msg = (
            f"{where} Lockstep = true: the autopilot endpoint {autopilot.name} cannot have a lossy link "
            "(LossPercent, DelayMs, ...): its frames carry the router's clock; put the link on the client endpoints"
        )
        raise ConfigError(msg)


def parse_config_text(text: str, *, source: str = "<config>", base_dir: Path | None = None) -> RouterConfig:
    """Parse one configuration text (tests, tools). Raises :class:`ConfigError`."""
    sections: dict[tuple[str, str], _Section] = {}
    _parse_sections(text, source, base_dir or Path.cwd(), sections)
    return _build(sections)


def load_config_files(files: Iterable[Path]) -> RouterConfig:
    """Read and merge configuration files in order (later files override keys)."""
    sections: dict[tuple[str, str], _Section] = {}
    for path in files:
        try:
            text = path.read_text(encoding="utf-8")
        except FileNotFoundError:
            msg = f"{path}: configuration file not found; pass an existing file with -c (see config/router.conf)"
            raise ConfigError(msg) from None
        except (OSError, UnicodeDecodeError) as err:
            msg = f"{path}: cannot read the configuration file ({err})"
            raise ConfigError(msg) from err
        _parse_sections(text, str(path), path.resolve().parent, sections)
    return _build(sections)


def config_dir_files(directory: Path) -> list[Path]:
    """The regular files of a ``-d`` configuration directory, in alphabetical order."""
    if not directory.is_dir():
        return []
    return sorted(p for p in directory.iterdir() if p.is_file())


def as_dict(config: RouterConfig) -> dict[str, Any]:
    """A JSON-friendly view of the effective configuration (for logs and stats)."""

    def plain(value: object) -> object:
        if isinstance(value, enum.Enum):
            return value.value
        if isinstance(value, Path):
            return str(value)
        if isinstance(value, frozenset):
            return sorted(value)
        if isinstance(value, tuple):
            return [plain(v) for v in value]
        if hasattr(value, "__dataclass_fields__"):
            return {k: plain(getattr(value, k)) for k in value.__dataclass_fields__}
        return value

    result = plain(config)
    assert isinstance(result, dict)
    return result

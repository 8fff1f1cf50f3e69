"""Configuration: mavlink-routerd's INI format, strict validation, clear errors; the CLI merge."""

from __future__ import annotations

from pathlib import Path

import pytest
from helpers.paths import REPO

from mavlink_router.cli import build_config, parse_args
from mavlink_router.core.config import (
    LogMode,
    UdpMode,
    load_config_files,
    parse_config_text,
)
from mavlink_router.errors import ConfigError

# examples/config.sample from mavlink-router (minus its long comment block), verbatim.
UPSTREAM_SAMPLE = """
[General]
#Mavlink-router serves on this TCP port
TcpServerPort=5760
ReportStats=false
MavlinkDialect=auto

[UdpEndpoint alfa]
Mode = Eavesdropping
Address = 0.0.0.0
Port = 10000

[UartEndpoint bravo]
Device = /dev/tty0
Baud = 52000

[UdpEndpoint charlie]
Mode = Normal
Address = 127.0.0.1
Port = 11000

#Mavlink-router will connect to this TCP address
[TcpEndpoint delta]
Address = 127.0.0.1
Port = 25790
RetryTimeout=10
"""


def test_upstream_sample_parses() -> None:
    cfg = parse_config_text(UPSTREAM_SAMPLE)
    assert cfg.general.tcp_server_port == 5760
    assert [(u.name, u.mode, u.address, u.port) for u in cfg.udp] == [
        ("alfa", UdpMode.SERVER, "0.0.0.0", 10000),
        ("charlie", UdpMode.NORMAL, "127.0.0.1", 11000),
    ]
    [uart] = cfg.uart
    assert (uart.name, uart.device, uart.bauds) == ("bravo", "/dev/tty0", (52000,))
    [tcp] = cfg.tcp
    assert (tcp.name, tcp.address, tcp.port, tcp.retry_timeout_s) == ("delta", "127.0.0.1", 25790, 10.0)


def test_shipped_router_conf_wires_the_architecture_ports() -> None:
    cfg = load_config_files([REPO / "config" / "router.conf"])
    assert cfg.general.tcp_server_port == 5790
    [sitl] = cfg.tcp
    assert (sitl.address, sitl.port) == ("127.0.0.1", 5760)
    udp = {u.name: (u.mode, u.port) for u in cfg.udp}
    assert udp == {
        "gcs": (UdpMode.NORMAL, 14550),
        "controller": (UdpMode.NORMAL, 14540),
        "mavsdk": (UdpMode.NORMAL, 14541),
        "adhoc": (UdpMode.SERVER, 14555),
    }
    assert cfg.general.log_dir == (REPO / "artifacts" / "router")


def test_keys_and_sections_are_case_insensitive_and_merge() -> None:
    cfg = parse_config_text(
        """
[general]
tcpserverport = 0
[UDPENDPOINT gcs]
MODE = normal
address = 127.0.0.1
[udpendpoint GCS]
port = 15000
blockmsgidout = 1, 2
"""
    )
    assert cfg.general.tcp_server_port == 0
    [gcs] = cfg.udp
    assert gcs.port == 15000
    assert gcs.options.out_filter.block_msg_ids == frozenset({1, 2})


def test_later_value_wins_and_files_merge(tmp_path: Path) -> None:
    first = tmp_path / "a.conf"
    second = tmp_path / "b.conf"
    first.write_text("[General]\nReportStats = false\nReportStats = true\n[TcpEndpoint v]\nAddress=127.0.0.1\nPort=1\n")
    second.write_text("[tcpendpoint V]\nPort = 5760\n")
    cfg = load_config_files([first, second])
    assert cfg.general.report_stats
    assert cfg.tcp[0].port == 5760


def test_udp_client_default_ports_increase_from_14550() -> None:
    cfg = parse_config_text(
        "[UdpEndpoint a]\nMode=Normal\nAddress=127.0.0.1\n[UdpEndpoint b]\nMode=Normal\nAddress=127.0.0.1\n"
    )
    assert [u.port for u in cfg.udp] == [14550, 14551]


def test_filters_signing_and_extension_keys(tmp_path: Path) -> None:
    cfg = parse_config_text(
        """
[General]
SigningKeyFile = keys/router.key
StatsInterval = 2.5
TxQueueLimit = 64
DeduplicationPeriod = 100
LogMode = while-armed
Log = logs
[UdpEndpoint gcs]
Mode = Server
Address = [::1]
Port = 14555
AllowMsgIdIn = 0,76
BlockSrcSysOut = 7
AllowSrcCompOut = 1
RequireSigning = true
Group = ground
IgnoreCompId = 1
Filter = 0
Coalesce = false
""",
        base_dir=tmp_path,
    )
    g = cfg.general
    assert (g.stats_interval_s, g.tx_queue_limit, g.dedup_period_ms, g.log_mode) == (
        2.5,
        64,
        100,
        LogMode.WHILE_ARMED,
    )
    assert g.log_dir == tmp_path / "logs"
    [gcs] = cfg.udp
    o = gcs.options
    assert gcs.address == "[::1]"
    assert o.in_filter.allow_msg_ids == frozenset({0, 76})
    assert o.out_filter.block_src_systems == frozenset({7})
    assert o.out_filter.allow_src_comps == frozenset({1})
    assert o.out_filter.allow_msg_ids == frozenset({0})  # legacy Filter = AllowMsgIdOut
    assert o.require_signing
    assert o.signing_key_file == tmp_path / "keys" / "router.key"
    assert (o.group, o.ignore_comp_id, o.tx_queue_limit) == ("ground", True, 64)
    assert not gcs.coalesce


@pytest.mark.parametrize(
    ("text", "expected"),
    [
        ("Port = 1\n", r"<config>:1: option 'Port = 1' appears before any section"),
        (
            "[General]\nTcpServerPrt = 1\n",
            r"<config>:2: \[General\] has unknown key 'TcpServerPrt' \(did you mean 'TcpServerPort'\?\)",
        ),
        ("[UdpEndpnt x]\n", r"<config>:1: unknown section type 'UdpEndpnt' \(did you mean 'UdpEndpoint'\?\)"),
        ("[UdpEndpoint]\n", r"needs a name"),
        (
            "[General]\nTcpServerPort = 70000\n",
            r"<config>:2: \[General\] TcpServerPort = '70000': must be from 0 to 65535",
        ),
        ("[General]\nReportStats = yes\n", r"expected true, false, 1 or 0"),
        ("[UdpEndpoint g]\nMode = Normal\n", r"<config>:1: \[UdpEndpoint g\] needs 'Address = \.\.\.'"),
        ("[UdpEndpoint g]\nMode = Client\nAddress = 1.2.3.4\n", r"expected Normal .* or Server"),
        ("[UdpEndpoint g]\nMode = Server\nAddress = 0.0.0.0\n", r"Mode = Server needs 'Port = \.\.\.'"),
        ("[UdpEndpoint g]\nMode = Normal\nAddress = localhost\n", r"numeric IPv4 address"),
        ("[UdpEndpoint g]\nMode = Normal\nAddress = ::1\n", r"square brackets"),
        ("[TcpEndpoint t]\nAddress = 127.0.0.1\n", r"needs 'Port = \.\.\.'"),
        ("[UartEndpoint u]\nDevice = /dev/x\nBaud = fast\n", r"Baud = 'fast'"),
        ("[UdpEndpoint g]\nMode=Normal\nAddress=1.2.3.4\nAllowMsgIdOut = 1,,2\n", r"comma-separated list"),
        ("[UdpEndpoint g]\nMode=Normal\nAddress=1.2.3.4\nRequireSigning = true\n", r"needs a key: set SigningKeyFile"),
        ("[General]\nLog\n", r"<config>:2: expected 'Key = Value'"),
        ("[General]\nLog =\n", r"key 'Log' has no value"),
        ("[General x]\n", r"\[General\] takes no name"),
        ("[General]\nMavlinkDialect = px4\n", r"expected one of"),
    ],
)
def test_errors_name_the_place_and_the_fix(text: str, expected: str) -> None:
    with pytest.raises(ConfigError, match=expected):
        parse_config_text(text)


def test_missing_file_error_says_what_to_do(tmp_path: Path) -> None:
    with pytest.raises(ConfigError, match=r"configuration file not found; pass an existing file with -c"):
        load_config_files([tmp_path / "nope.conf"])


def test_cli_like_mavlink_routerd(tmp_path: Path) -> None:
    conf = tmp_path / "r.conf"
    conf.write_text("[UdpEndpoint gcs]\nMode=Normal\nAddress=127.0.0.1\n")
    empty = tmp_path / "conf.d"
    empty.mkdir()
    endpoints = ["-e", "127.0.0.1", "-e", "10.0.0.2:14600", "-p", "127.0.0.1:5760", "0.0.0.0:14555"]
    general = ["-t", "0", "-l", str(tmp_path / "logs"), "-r", "-s", "42", "--stats-interval", "1"]
    args = parse_args(["-c", str(conf), "-d", str(empty), *endpoints, *general])
    cfg, files = build_config(args)
    assert files == [conf]
    assert [(u.address, u.port, u.mode) for u in cfg.udp] == [
        ("127.0.0.1", 14550, UdpMode.NORMAL),  # from the file
        ("127.0.0.1", 14551, UdpMode.NORMAL),  # -e without a port: the next free one
        ("10.0.0.2", 14600, UdpMode.NORMAL),
        ("0.0.0.0", 14555, UdpMode.SERVER),  # positional ip:port is a server
    ]
    assert [(t.address, t.port) for t in cfg.tcp] == [("127.0.0.1", 5760)]
    g = cfg.general
    assert (g.tcp_server_port, g.log_dir, g.report_stats, g.sniffer_sysid, g.stats_interval_s) == (
        0,
        tmp_path / "logs",
        True,
        42,
        1.0,
    )


def test_cli_positional_char_device_is_a_uart(tmp_path: Path) -> None:
    args = parse_args(["-d", str(tmp_path), "/dev/null:57600"])
    cfg, _ = build_config(args)
    [uart] = cfg.uart
    assert (uart.device, uart.bauds) == ("/dev/null", (57600, 115200))


@pytest.mark.parametrize(
    ("argv", "expected"),
    [
        (["-e", "localhost:14550"], r"-e 'localhost:14550': 'localhost' is not a numeric IP address"),
        (["-p", "127.0.0.1"], r"-p '127.0.0.1': expected <ip>:<port>"),
        (["-e", "127.0.0.1:99999"], r"the port must be from 1 to 65535"),
        (["-t", "-1"], r"-t -1: the TCP server port must be from 0 \(off\) to 65535"),
        (["1.2.3.4"], r"expected <ip>:<port>"),
    ],
)
def test_cli_errors(argv: list[str], expected: str, tmp_path: Path) -> None:
    with pytest.raises(ConfigError, match=expected):
        build_config(parse_args(["-d", str(tmp_path), *argv]))


def test_cli_has_no_option_for_the_signing_key() -> None:
    with pytest.raises(SystemExit):
        parse_args(["--signing-key", "secret"])

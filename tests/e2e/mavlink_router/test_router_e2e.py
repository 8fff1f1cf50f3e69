"""The real ``uav-mavlink-router`` process with pymavlink peers over UDP, TCP and a pty "serial" line."""

from __future__ import annotations

import contextlib
import hashlib
import os
import random
import shutil
import signal
import socket
import statistics
import struct
import subprocess
import sys
import time
import tty
from pathlib import Path

import pytest
from helpers.procs import Proc, free_port, free_udp_port, wait_for_port
from mr_harness import Peer, drain, encoder, endpoint_stats, read_stats, router, udp_sink, v2, wait_until
from pymavlink import mavutil

HERE = Path(__file__).resolve().parent
pytestmark = pytest.mark.timeout(60)


def decode_all(data: bytes) -> list[object]:
    parser = v2.MAVLink(None)
    parser.robust_parsing = True
    return [m for m in parser.parse_buffer(data) or [] if m.get_type() != "BAD_DATA"]


def test_routing_scenario_of_mavlink_router(artifacts: Path) -> None:
    """Port of mavlink-router's tests/routing_test.py (broadcast vs targeted PING)."""
    src_port, r100_port, r101_port = free_udp_port(), free_udp_port(), free_udp_port()
    args = [f"127.0.0.1:{src_port}", "-e", f"127.0.0.1:{r100_port}", "-e", f"127.0.0.1:{r101_port}"]
    with router("router_routing_scenario", args):
        senders = Peer(f"udpout:127.0.0.1:{src_port}", 1, 1)  # carries systems 1/1 and 2/1
        s1, s2 = encoder(1, 1), encoder(2, 1)
        receivers = {
            100: Peer(f"udpin:127.0.0.1:{r100_port}", 100, 1),
            101: Peer(f"udpin:127.0.0.1:{r101_port}", 101, 1),
        }
        got: dict[int, list[object]] = {100: [], 101: []}
        replies: list[object] = []
        for i in range(10):
            s2.seq = s1.seq = i
            senders.conn.write(s2.pack(v2.MAVLink_ping_message(i, i, 100, 1)))
            senders.conn.write(s1.pack(v2.MAVLink_ping_message(i, i, 0, 0)))
            expected = {100: 2 if i else 1, 101: 1}
            for sysid, peer in receivers.items():
                new = []
                wait_until(lambda p=peer, n=new, e=expected[sysid]: n.extend(p.poll(0.05)) or len(n) >= e, 5, "pings")
                for msg in new:
                    got[sysid].append(msg)
                    peer.mav.ping_send(msg.time_usec, msg.seq, msg.get_srcSystem(), msg.get_srcComponent())
            wait_until(lambda n=3 * i + 2: replies.extend(senders.poll(0.05)) or len(replies) >= n, 5, "replies")
        replies += senders.poll(0.3)
    assert len(got[101]) == 10, "receiver 101 gets only the broadcasts"
    assert all(m.target_system == 0 for m in got[101])
    assert len(got[100]) == 19, "receiver 100 misses the first targeted ping (system 100 was unknown)"
    to_1 = [m for m in replies if m.target_system == 1]
    to_2 = [m for m in replies if m.target_system == 2]
    assert (len(to_1), len(to_2)) == (20, 9)
    assert all(m.get_srcSystem() in (100, 101) for m in replies), "nothing is echoed back to its source"


def test_tcp_client_reconnects_and_tcp_server_serves_many(artifacts: Path) -> None:
    vehicle_port, gcs_port = free_port(), free_udp_port()
    stats_file = artifacts / "stats.json"
    args = ["-p", f"127.0.0.1:{vehicle_port}", "-e", f"127.0.0.1:{gcs_port}", "--stats-file", str(stats_file)]
    args += ["--stats-interval", "0.2"]
    with router("router_tcp", args) as (proc, server_port):
        gcs = Peer(f"udpin:127.0.0.1:{gcs_port}", 255, 190)
        veh = encoder(1, 1)
        time.sleep(0.6)  # the router is already retrying: the vehicle comes up late
        for round_ in range(2):
            listener = socket.create_server(("127.0.0.1", vehicle_port))
            listener.settimeout(10)
            conn, _ = listener.accept()
            conn.sendall(veh.pack(v2.MAVLink_heartbeat_message(2, 12, 1, 0, 4, 3)))
            gcs.wait_for(lambda m: m.get_type() == "HEARTBEAT" and m.get_srcSystem() == 1, 5, "vehicle heartbeat")
            gcs.mav.command_long_send(1, 1, 400, 0, 1, round_, 0, 0, 0, 0, 0)
            conn.settimeout(5)
            got = decode_all(conn.recv(4096))
            assert any(m.get_type() == "COMMAND_LONG" and m.param2 == round_ for m in got), got
            conn.close()  # the vehicle restarts
            listener.close()
        assert f"connection to 127.0.0.1:{vehicle_port} lost" in proc.log_text()

        # TCP server: two clients; the ACK goes to the one that commanded.
        listener = socket.create_server(("127.0.0.1", vehicle_port))
        listener.settimeout(10)
        conn, _ = listener.accept()
        conn.settimeout(5)
        a = Peer(f"tcp:127.0.0.1:{server_port}", 200, 1)
        b = Peer(f"tcp:127.0.0.1:{server_port}", 201, 1)
        wait_until(
            lambda: len(read_stats(stats_file)["endpoints"]) == 4 if stats_file.exists() else False, 5, "2 clients"
        )
        a.mav.heartbeat_send(6, 8, 0, 0, 4)
        b.mav.heartbeat_send(6, 8, 0, 0, 4)
        conn.sendall(veh.pack(v2.MAVLink_heartbeat_message(2, 12, 1, 0, 4, 3)))
        for peer in (a, b):
            peer.wait_for(
                lambda m: m.get_type() == "HEARTBEAT" and m.get_srcSystem() == 1, 5, "heartbeat via TCP server"
            )
        a.mav.command_long_send(1, 1, 400, 0, 1, 0, 0, 0, 0, 0, 0)
        data = b""
        while not any(m.get_type() == "COMMAND_LONG" for m in decode_all(data)):
            data += conn.recv(4096)
        conn.sendall(veh.pack(v2.MAVLink_command_ack_message(400, 0, 0, 0, 200, 1)))
        a.wait_for(lambda m: m.get_type() == "COMMAND_ACK", 5, "ACK to client A")
        time.sleep(0.3)
        assert not [m for m in b.poll() if m.get_type() == "COMMAND_ACK"], "client B must not get A's ACK"
        # B vanishes abruptly (RST); the router drops it and carries on.
        b.conn.port.setsockopt(socket.SOL_SOCKET, socket.SO_LINGER, struct.pack("ii", 1, 0))
        b.close()
        wait_until(lambda: read_stats(stats_file)["closed_endpoints"], 5, "B removed")
        conn.sendall(veh.pack(v2.MAVLink_command_ack_message(400, 0, 0, 0, 200, 1)))
        a.wait_for(lambda m: m.get_type() == "COMMAND_ACK", 5, "router still routing after B vanished")
        conn.close()
        listener.close()


def test_flooding_and_stalled_clients_do_not_delay_others(artifacts: Path) -> None:
    """A UDP flood and a TCP client that never reads, while a GCS commands a vehicle."""
    flood_port, gcs_port, sink_port = free_udp_port(), free_udp_port(), free_udp_port()
    stats_file = artifacts / "stats.json"
    conf = artifacts / "router.conf"
    conf.write_text(
        "[General]\nStatsInterval = 0.5\n"
        f"StatsFile = {stats_file}\n"
        f"[UdpEndpoint flood]\nMode = Server\nAddress = 127.0.0.1\nPort = {flood_port}\n"
        f"[UdpEndpoint gcs]\nMode = Server\nAddress = 127.0.0.1\nPort = {gcs_port}\n"
        f"[UdpEndpoint sink]\nMode = Server\nAddress = 127.0.0.1\nPort = {sink_port}\n"
    )
    with router("router_flood", ["-c", str(conf)]) as (_, server_port):
        vehicle = socket.create_connection(("127.0.0.1", server_port))
        vehicle.setblocking(False)
        veh = encoder(1, 1)
        sink = socket.socket(socket.AF_INET, socket.SOCK_DGRAM)
        sink.setsockopt(socket.SOL_SOCKET, socket.SO_RCVBUF, 4096)
        sink.sendto(encoder(50, 1).pack(v2.MAVLink_heartbeat_message(6, 8, 0, 0, 4, 3)), ("127.0.0.1", sink_port))
        staller = socket.socket(socket.AF_INET, socket.SOCK_STREAM)
        staller.setsockopt(socket.SOL_SOCKET, socket.SO_RCVBUF, 4096)
        staller.connect(("127.0.0.1", server_port))  # never reads
        gcs = Peer(f"udpout:127.0.0.1:{gcs_port}", 255, 190)
        gcs.mav.heartbeat_send(6, 8, 0, 0, 4)
        vehicle.send(veh.pack(v2.MAVLink_heartbeat_message(2, 12, 1, 0, 4, 3)))
        gcs.wait_for(lambda m: m.get_type() == "HEARTBEAT" and m.get_srcSystem() == 1, 5, "vehicle heartbeat")
        odometry = veh.pack(
            v2.MAVLink_odometry_message(1, 1, 0, 1, 2, 3, [1, 0, 0, 0], 0, 0, 0, 0, 0, 0, [0] * 21, [0] * 21)
        )
        vehicle_parser = v2.MAVLink(None)
        vehicle_parser.robust_parsing = True

        def run_phase(seconds: float) -> tuple[list[float], int, int]:
            sent: dict[int, float] = {}
            rtts: list[float] = []
            heartbeats = 0
            next_cmd = next_hb = time.monotonic()
            end = next_cmd + seconds
            while time.monotonic() < end + 0.5:
                now = time.monotonic()
                if now < end and now >= next_cmd:
                    ident = len(sent) + 1
                    sent[ident] = now
                    gcs.mav.command_long_send(1, 1, 31001, 0, ident, 0, 0, 0, 0, 0, 0)
                    next_cmd += 0.02
                if now < end and now >= next_hb:
                    vehicle.send(veh.pack(v2.MAVLink_heartbeat_message(2, 12, 1, 0, 4, 3)) + odometry * 10)
                    next_hb += 0.02
                try:
                    data = vehicle.recv(65536)
                except BlockingIOError:
                    data = b""
                for msg in vehicle_parser.parse_buffer(data) or [] if data else []:
                    if msg.get_type() == "COMMAND_LONG" and msg.command == 31001:
                        vehicle.send(veh.pack(v2.MAVLink_command_ack_message(31001, 0, 0, int(msg.param1), 255, 190)))
                for msg in gcs.poll():
                    if msg.get_type() == "COMMAND_ACK" and msg.result_param2 in sent:
                        rtts.append(time.monotonic() - sent.pop(msg.result_param2))
                    elif msg.get_type() == "HEARTBEAT" and msg.get_srcSystem() == 1:
                        heartbeats += 1
                time.sleep(0.001)
            return rtts, len(sent), heartbeats

        calm_rtts, calm_lost, calm_hb = run_phase(1.5)
        flooder = Proc(
            "router_flood_flooder",
            [sys.executable, str(HERE / "mr_flood.py"), "127.0.0.1", str(flood_port), "77", "50", "4.5"],
        )
        try:
            time.sleep(0.5)
            flood_rtts, flood_lost, flood_hb = run_phase(4.0)
        finally:
            flooder.stop()
        time.sleep(0.6)
        stats = read_stats(stats_file)
        staller.close()
        vehicle.close()
    p95 = lambda xs: statistics.quantiles(xs, n=20)[-1] * 1000  # noqa: E731
    report = (
        f"calm: {len(calm_rtts)} acks, lost {calm_lost}, p95 {p95(calm_rtts):.1f} ms, hb {calm_hb}; "
        f"flood: {len(flood_rtts)} acks, lost {flood_lost}, p95 {p95(flood_rtts):.1f} ms, "
        f"max {max(flood_rtts) * 1000:.1f} ms, hb {flood_hb}; "
        f"flood rx {endpoint_stats(stats, 'flood')['rx_msgs']}, "
        f"staller drops {[e['tx_drops'] for e in stats['endpoints'] if e['type'] == 'tcp']}"
    )
    (artifacts / "report.txt").write_text(report + "\n")
    print(report)
    assert endpoint_stats(stats, "flood")["rx_msgs"] > 20_000, report  # the flood really happened
    tcp = [e for e in stats["endpoints"] if e["type"] == "tcp"]
    assert max(e["tx_drops"] for e in tcp) > 0, "the stalled client's bounded queue must overflow (and be counted)"
    assert endpoint_stats(stats, "gcs")["tx_drops"] == 0
    assert flood_lost <= 0.05 * (len(flood_rtts) + flood_lost), report
    assert p95(flood_rtts) < 150, report
    assert flood_hb >= 0.8 * 4.0 / 0.02, report


def test_garbage_is_skipped_and_streams_resync(artifacts: Path) -> None:
    gcs_port, udp_in = free_udp_port(), free_udp_port()
    stats_file = artifacts / "stats.json"
    args = ["-e", f"127.0.0.1:{gcs_port}", f"127.0.0.1:{udp_in}", "--stats-file", str(stats_file)]
    with router("router_garbage", [*args, "--stats-interval", "0.2"]) as (_, server_port):
        gcs = udp_sink(gcs_port)
        rng = random.Random(4)
        veh = encoder(1, 1)
        frames = []
        for i in range(200):
            veh.seq = i & 0xFF
            frames.append(veh.pack(v2.MAVLink_system_time_message(1_000_000 + i, i)))
        stream = b"".join(bytes(rng.randrange(256) for _ in range(rng.randrange(30))) + f for f in frames)
        with socket.create_connection(("127.0.0.1", server_port)) as tcp:
            pos = 0
            while pos < len(stream):
                step = rng.randrange(1, 200)
                tcp.sendall(stream[pos : pos + step])
                pos += step
                time.sleep(0.0005)
            # UDP: garbage around a frame in one datagram
            udp = socket.socket(socket.AF_INET, socket.SOCK_DGRAM)
            udp.sendto(
                b"\x00\xfe\x13garbage" + encoder(9, 9).pack(v2.MAVLink_system_time_message(7, 7)) + b"\xfd",
                ("127.0.0.1", udp_in),
            )
            received: list[object] = []
            wait_until(
                lambda: received.extend(m for d in drain(gcs) for m in decode_all(d)) or len(received) >= 201,
                10,
                "frames",
            )
            time.sleep(0.5)
            received += [m for d in drain(gcs) for m in decode_all(d)]
        stats = read_stats(stats_file)
    from_vehicle = [m.time_unix_usec - 1_000_000 for m in received if m.get_srcSystem() == 1]
    assert from_vehicle == list(range(200)), "every valid frame arrives, in order, exactly once"
    assert [m.time_unix_usec for m in received if m.get_srcSystem() == 9] == [7]
    tcp_stats = next(e for e in stats["endpoints"] + stats["closed_endpoints"] if e["type"] == "tcp")
    assert tcp_stats["garbage_bytes"] > 1000


def test_sigterm_and_sigint_flush_the_log_and_stats(artifacts: Path) -> None:
    for sig in (signal.SIGTERM, signal.SIGINT):
        log_dir = artifacts / sig.name
        shutil.rmtree(log_dir, ignore_errors=True)
        in_port = free_udp_port()
        port = free_port()
        proc = Proc(
            f"router_signal_{sig.name}",
            ["uav-mavlink-router", f"127.0.0.1:{in_port}", "-t", str(port), "-l", str(log_dir)],
        )
        try:
            wait_for_port(port, timeout_s=20, proc=proc)
            gcs = Peer(f"udpout:127.0.0.1:{in_port}", 255, 190)
            for i in range(500):
                gcs.mav.system_time_send(i, i)
            time.sleep(0.5)  # frames may still sit in the log buffer: the shutdown must flush them
            proc.signal(sig)
            assert proc.wait(10) == 0
        finally:
            proc.stop()
        [tlog] = log_dir.glob("*.tlog")
        reader = mavutil.mavlink_connection(str(tlog))
        times = []
        while (msg := reader.recv_match(type="SYSTEM_TIME")) is not None:
            times.append(msg.time_unix_usec)
        assert times == list(range(500))
        dump = subprocess.run(
            ["mavlogdump.py", "--types", "SYSTEM_TIME", str(tlog)],
            capture_output=True,
            text=True,
            timeout=60,
            check=True,
        )
        assert dump.stdout.count("SYSTEM_TIME {") == 500, "pymavlink's mavlogdump.py (MAVProxy's log tools) reads it"
        stats = read_stats(log_dir / "router-stats.json")
        assert stats["endpoints"][0]["rx_msgs"] == 500
        assert "shutting down" in proc.log_path.read_text()


def test_signing_required_on_an_endpoint(artifacts: Path) -> None:
    key_file = artifacts / "signing.key"
    key_file.write_text("range secret passphrase\n")
    key_file.chmod(0o600)
    gcs_port = free_udp_port()
    stats_file = artifacts / "stats.json"
    conf = artifacts / "router.conf"
    conf.write_text(
        f"[General]\nSigningKeyFile = {key_file}\nStatsFile = {stats_file}\nStatsInterval = 0.2\n"
        f"[UdpEndpoint gcs]\nMode = Server\nAddress = 127.0.0.1\nPort = {gcs_port}\nRequireSigning = true\n"
    )
    with router("router_signing", ["-c", str(conf)]) as (_, server_port):
        vehicle = Peer(f"tcp:127.0.0.1:{server_port}", 1, 1)
        gcs = Peer(f"udpout:127.0.0.1:{gcs_port}", 255, 190)
        gcs.mav.heartbeat_send(6, 8, 0, 0, 4)  # telemetry needs no signature
        vehicle.wait_for(lambda m: m.get_type() == "HEARTBEAT" and m.get_srcSystem() == 255, 5, "GCS heartbeat")
        vehicle.mav.heartbeat_send(2, 12, 1, 0, 4)
        gcs.wait_for(lambda m: m.get_type() == "HEARTBEAT" and m.get_srcSystem() == 1, 5, "vehicle heartbeat")
        gcs.mav.command_long_send(1, 1, 400, 0, 1, 0, 0, 0, 0, 0, 0)
        gcs.mav.command_long_send(1, 1, 400, 0, 1, 0, 0, 0, 0, 0, 0)
        time.sleep(0.5)
        assert not [m for m in vehicle.poll() if m.get_type() == "COMMAND_LONG"], "unsigned command must be dropped"
        gcs.conn.setup_signing(hashlib.sha256(b"range secret passphrase").digest(), sign_outgoing=True)
        gcs.mav.command_long_send(1, 1, 400, 0, 1, 0, 0, 0, 0, 0, 0)
        cmd = vehicle.wait_for(lambda m: m.get_type() == "COMMAND_LONG", 5, "signed command")
        raw = bytes(cmd.get_msgbuf())
        assert raw[2] & 0x01, "the signed frame is forwarded untouched (SIGNED flag)"
        assert len(raw) == 10 + raw[1] + 2 + 13, "with its 13-byte signature block"
        wait_until(lambda: endpoint_stats(read_stats(stats_file), "gcs")["unsigned_drops"] == 2, 5, "drops counted")


def test_serial_endpoint_over_a_pty(artifacts: Path) -> None:
    master, slave = os.openpty()
    tty.setraw(slave)
    os.set_blocking(master, False)
    device = os.ttyname(slave)
    gcs_port = free_udp_port()
    conf = artifacts / "router.conf"
    conf.write_text(
        f"[UartEndpoint fc]\nDevice = {device}\nBaud = 57600\n"
        f"[UdpEndpoint gcs]\nMode = Normal\nAddress = 127.0.0.1\nPort = {gcs_port}\n"
    )
    try:
        with router("router_serial", ["-c", str(conf)]) as (proc, _):
            wait_until(
                lambda: "opened /dev/" in proc.log_text() or f"opened {device}" in proc.log_text(), 10, "serial open"
            )
            gcs = Peer(f"udpin:127.0.0.1:{gcs_port}", 255, 190)
            fc = encoder(1, 1)
            os.write(master, fc.pack(v2.MAVLink_heartbeat_message(2, 12, 1, 0, 4, 3)))
            gcs.wait_for(lambda m: m.get_type() == "HEARTBEAT" and m.get_srcSystem() == 1, 5, "heartbeat over serial")
            gcs.mav.command_long_send(1, 1, 400, 0, 1, 0, 0, 0, 0, 0, 0)
            data = b""

            def command_arrived() -> bool:
                nonlocal data
                with contextlib.suppress(BlockingIOError):
                    data += os.read(master, 4096)
                return any(m.get_type() == "COMMAND_LONG" for m in decode_all(data))

            wait_until(command_arrived, 5, "command over serial")
    finally:
        os.close(master)
        os.close(slave)


def test_bad_config_exits_2_with_a_useful_message(tmp_path: Path) -> None:
    conf = tmp_path / "bad.conf"
    (tmp_path / "conf.d").mkdir()
    conf.write_text("[General]\nTcpServerPort = 5790\n[UdpEndpoint gcs]\nMode = Normal\nAdress = 127.0.0.1\n")
    out = subprocess.run(
        ["uav-mavlink-router", "-c", str(conf), "-d", str(tmp_path / "conf.d")],
        capture_output=True,
        text=True,
        timeout=30,
        check=False,
    )
    assert out.returncode == 2
    assert f"{conf}:5: [UdpEndpoint gcs] has unknown key 'Adress' (did you mean 'Address'?)" in out.stderr


def test_python_dash_m_entry_point() -> None:
    out = subprocess.run(
        [sys.executable, "-m", "mavlink_router", "--version"], capture_output=True, text=True, timeout=30, check=False
    )
    assert out.returncode == 0
    assert out.stdout.startswith("uav-mavlink-router ")

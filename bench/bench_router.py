"""Router benchmark: messages/s forwarded from one UDP endpoint to three, and added latency.

Setup (all on loopback, every process separate):

* sender (this process) -> relay -> 3 UDP receivers (one child process, 3 sockets);
* relay = ``uav-mavlink-router`` (no log), and, as the baseline measured in the
  same run, a direct pymavlink relay (``recv_match`` + ``write(get_msgbuf())`` to
  three ``udpout`` connections).

Each frame is a MAVLink 2 SYSTEM_TIME carrying the sender's CLOCK_MONOTONIC in µs
and a phase/sequence tag; receivers take the one-way latency on arrival.

* Throughput: offered rates in steps (2 s each); the result is the highest rate
  every receiver got with loss <= 1 % ("sustained, loss-free", messages in per
  second; each is written three times).
* Added latency: at 1000 msg/s, one-way latency through the relay minus the
  direct sender -> receiver latency measured in the same run (p50 - p50 and, to
  charge the whole tail to the relay, p99 - p50).

The machine has 2 shared cores and other work may be running: numbers are
pessimistic and noisy; the load average is recorded in the notes.
"""

from __future__ import annotations

import contextlib
import json
import os
import selectors
import socket
import struct
import subprocess
import sys
import tempfile
import time
from collections.abc import Callable
from pathlib import Path
from typing import Any

HERE = Path(__file__).resolve().parent
import benchlib  # noqa: E402, F401 - puts tests/ (the shared harness) on sys.path
from benchlib import percentile, record  # noqa: E402
from helpers.procs import artifacts_dir, free_port, free_udp_port, wait_for_port  # noqa: E402

from mavlink_router.core.frames import x25_crc  # noqa: E402
from mavlink_router.shell.dialect import load_message_table  # noqa: E402

SYSTEM_TIME = 2
CRC_EXTRA = load_message_table()[SYSTEM_TIME].crc_extra
PAYLOAD = struct.Struct("<QI")
HEADER = struct.Struct("<BBBBBBBBBB")
STEP_S = 2.0
RATES_ROUTER = (10_000, 20_000, 30_000, 40_000, 50_000, 60_000)
RATES_BASELINE = (2_000, 5_000, 10_000, 15_000, 20_000)
LATENCY_RATE = 1000
LATENCY_S = 3.0
TARGET_RATE = 20_000
TARGET_P99_MS = 2.0


def frame(seq: int, tag: int, t_us: int) -> bytes:
    payload = PAYLOAD.pack(t_us, tag)
    head = HEADER.pack(0xFD, len(payload), 0, 0, seq & 0xFF, 1, 1, SYSTEM_TIME, 0, 0)
    crc = x25_crc(bytes((CRC_EXTRA,)), x25_crc(head[1:] + payload))
    return head + payload + struct.pack("<H", crc)


# --------------------------------------------------------------------------------------
# child roles


def role_receiver(ports: list[int]) -> None:
    """Count frames per (phase, socket) and collect latencies until 'report' on stdin."""
    sel = selectors.DefaultSelector()
    for index, port in enumerate(ports):
        sock = socket.socket(socket.AF_INET, socket.SOCK_DGRAM)
        sock.setsockopt(socket.SOL_SOCKET, socket.SO_RCVBUF, 4 << 20)
        sock.bind(("127.0.0.1", port))
        sock.setblocking(False)
        sel.register(sock, selectors.EVENT_READ, index)
    sel.register(sys.stdin, selectors.EVENT_READ, -1)
    counts: dict[str, list[int]] = {}
    lat: dict[str, list[int]] = {}
    mono = time.monotonic_ns
    print("ready", flush=True)
    while True:
        for key, _ in sel.select(1.0):
            if key.data == -1:
                sys.stdin.readline()
                print(json.dumps({"counts": counts, "lat_us": lat}), flush=True)
                return
            sock = key.fileobj
            for _ in range(256):
                try:
                    data = sock.recv(2048)  # type: ignore[union-attr]
                except BlockingIOError:
                    break
                now_us = mono() // 1000
                offset = 0
                while offset < len(data):  # a datagram may carry several whole frames
                    t_us, tag = PAYLOAD.unpack_from(data, offset + 10)
                    offset += data[offset + 1] + 12
                    phase = str(tag >> 24)
                    per = counts.setdefault(phase, [0, 0, 0])
                    per[key.data] += 1
                    lat.setdefault(phase, []).append(now_us - t_us)


def role_relay(in_port: int, out_ports: list[int]) -> None:
    """The baseline: a direct pymavlink UDP relay, one input to three outputs."""
    os.environ["MAVLINK20"] = "1"
    from pymavlink import mavutil  # noqa: PLC0415

    mavutil.set_dialect("ardupilotmega")
    src = mavutil.mavlink_connection(f"udpin:127.0.0.1:{in_port}")
    outs = [mavutil.mavlink_connection(f"udpout:127.0.0.1:{port}") for port in out_ports]
    print("ready", flush=True)
    while True:
        msg = src.recv_match(blocking=True, timeout=1.0)
        if msg is None:
            continue
        buf = msg.get_msgbuf()
        for out in outs:
            out.write(buf)


# --------------------------------------------------------------------------------------
# driver


def send_paced(sock: socket.socket, addr: tuple[str, int], rate: int, seconds: float, phase: int) -> int:
    """Send ``rate`` msg/s for ``seconds`` in 1 ms slices; returns the number sent."""
    per_ms = max(1, rate // 1000)
    slices = int(seconds * 1000)
    start = time.perf_counter()
    sent = 0
    mono = time.monotonic_ns
    for i in range(slices):
        due = start + i / 1000
        while time.perf_counter() < due:
            pass
        for _ in range(per_ms):
            tag = phase << 24 | (sent & 0xFFFFFF)
            with contextlib.suppress(BlockingIOError):
                sock.sendto(frame(sent, tag, mono() // 1000), addr)
            sent += 1
    return sent


class Receivers:
    def __init__(self, ports: list[int]) -> None:
        self.proc = subprocess.Popen(
            [sys.executable, __file__, "receiver", *map(str, ports)],
            stdin=subprocess.PIPE,
            stdout=subprocess.PIPE,
            text=True,
        )
        assert self.proc.stdout is not None
        assert self.proc.stdout.readline().strip() == "ready"

    def report(self) -> dict[str, Any]:
        assert self.proc.stdin is not None
        assert self.proc.stdout is not None
        self.proc.stdin.write("report\n")
        self.proc.stdin.flush()
        data: dict[str, Any] = json.loads(self.proc.stdout.readline())
        self.proc.wait(10)
        return data


def start(argv: list[str], ready_port: int | None = None) -> subprocess.Popen[str]:
    """Start a relay; its output goes to artifacts/logs/ (an unread pipe could fill and block it)."""
    log_dir = artifacts_dir() / "logs"
    log_dir.mkdir(parents=True, exist_ok=True)
    with (log_dir / f"bench_router_{Path(argv[0]).name}.log").open("w") as log:
        stdout = log if ready_port is not None else subprocess.PIPE
        proc = subprocess.Popen(argv, stdout=stdout, stderr=log, text=True)
    if ready_port is not None:
        wait_for_port(ready_port, timeout_s=20)
    else:
        assert proc.stdout is not None
        assert proc.stdout.readline().strip() == "ready"
    return proc


def stop(proc: subprocess.Popen[str]) -> None:
    proc.terminate()
    try:
        proc.wait(10)
    except subprocess.TimeoutExpired:
        proc.kill()
        proc.wait(10)


def cpu_seconds(pid: int) -> float:
    """User + system CPU time a process has used (from /proc)."""
    fields = Path(f"/proc/{pid}/stat").read_text().rsplit(")", 1)[1].split()
    return (int(fields[11]) + int(fields[12])) / os.sysconf("SC_CLK_TCK")


def router_counts(stats_file: Path | None) -> tuple[int, int]:
    """(messages in, messages out) from the router's stats file (0, 0 for the baseline)."""
    if stats_file is None or not stats_file.exists():
        return 0, 0
    endpoints = json.loads(stats_file.read_text())["endpoints"]
    return sum(e["rx_msgs"] for e in endpoints), sum(e["tx_msgs"] for e in endpoints)


def run_relay(
    make_argv: Callable[[list[int]], list[str]],
    in_port: int,
    ready_port: int | None,
    rates: tuple[int, ...],
    stats_file: Path | None = None,
) -> dict[str, Any]:
    """Throughput steps and a latency run through one relay; returns per-phase results."""
    out_ports = [free_udp_port() for _ in range(3)]
    receivers = Receivers(out_ports)
    relay = start(make_argv(out_ports), ready_port)
    sock = socket.socket(socket.AF_INET, socket.SOCK_DGRAM)
    sock.setsockopt(socket.SOL_SOCKET, socket.SO_SNDBUF, 4 << 20)
    addr = ("127.0.0.1", in_port)
    sent: dict[int, int] = {}
    cpu: dict[int, float] = {}
    relay_io: dict[int, tuple[int, int]] = {}
    try:
        send_paced(sock, addr, 1000, 0.5, 99)  # warm-up (phase 99 is ignored)
        time.sleep(0.3)
        sent[0] = send_paced(sock, addr, LATENCY_RATE, LATENCY_S, 0)
        for phase, rate in enumerate(rates, start=1):
            time.sleep(0.6)
            before_cpu, before_io = cpu_seconds(relay.pid), router_counts(stats_file)
            sent[phase] = send_paced(sock, addr, rate, STEP_S, phase)
            time.sleep(0.6)  # drain, and let the stats file catch up
            after_io = router_counts(stats_file)
            cpu[phase] = cpu_seconds(relay.pid) - before_cpu
            relay_io[phase] = (after_io[0] - before_io[0], after_io[1] - before_io[1])
        time.sleep(0.5)
    finally:
        data = receivers.report()
        stop(relay)
    results: dict[str, Any] = {"latency": None, "steps": []}
    counts, lat = data["counts"], data["lat_us"]
    results["latency"] = lat.get("0", [])
    results["latency_loss"] = 1 - min(counts.get("0", [0, 0, 0])) / sent[0]
    for phase, rate in enumerate(rates, start=1):
        got = min(counts.get(str(phase), [0, 0, 0]))
        loss = 1 - got / sent[phase]
        step_lat = lat.get(str(phase), [])
        results["steps"].append(
            {
                "offered": rate,
                "sent_per_s": sent[phase] / STEP_S,
                "delivered_per_s": got / STEP_S,
                "loss": loss,
                "p99_ms": percentile(step_lat, 99) / 1000 if step_lat else float("nan"),
                "relay_cpu_s": cpu[phase],
                "relay_in": relay_io[phase][0],
                "relay_out": relay_io[phase][1],
                "msgs_per_cpu_s": got / cpu[phase] if cpu[phase] > 0 else float("nan"),
            }
        )
    return results


def direct_latency() -> list[int]:
    port = free_udp_port()
    receivers = Receivers([port, free_udp_port(), free_udp_port()])
    sock = socket.socket(socket.AF_INET, socket.SOCK_DGRAM)
    send_paced(sock, ("127.0.0.1", port), 1000, 0.3, 99)
    send_paced(sock, ("127.0.0.1", port), LATENCY_RATE, LATENCY_S, 0)
    time.sleep(0.5)
    lat: list[int] = receivers.report()["lat_us"].get("0", [])
    return lat


def sustained(steps: list[dict[str, Any]]) -> float:
    ok = [s["delivered_per_s"] for s in steps if s["loss"] <= 0.01]
    return max(ok) if ok else 0.0


def main() -> int:
    load = os.getloadavg()
    conf_dir = Path(tempfile.mkdtemp(prefix="bench-router-conf.d-"))
    in_port, tcp_port = free_udp_port(), free_port()

    stats_file = conf_dir.parent / f"{conf_dir.name}-stats.json"

    def router_argv(out_ports: list[int]) -> list[str]:
        argv = ["uav-mavlink-router", f"127.0.0.1:{in_port}", "-t", str(tcp_port), "-d", str(conf_dir), "-g", "warning"]
        argv += ["--stats-file", str(stats_file), "--stats-interval", "0.25"]
        for port in out_ports:
            argv += ["-e", f"127.0.0.1:{port}"]
        return argv

    direct = direct_latency()
    router = run_relay(router_argv, in_port, tcp_port, RATES_ROUTER, stats_file)
    stats_file.unlink(missing_ok=True)
    base_in = free_udp_port()

    def relay_argv(out_ports: list[int]) -> list[str]:
        return [sys.executable, __file__, "relay", str(base_in), *map(str, out_ports)]

    baseline = run_relay(relay_argv, base_in, None, RATES_BASELINE)
    conf_dir.rmdir()

    for name, res in (("router", router), ("pymavlink relay", baseline)):
        print(f"{name}: latency loss {res['latency_loss']:.3%}")
        for step in res["steps"]:
            print(
                f"  offered {step['offered']:>6} msg/s: sent {step['sent_per_s']:8.0f}/s, "
                f"delivered to each of 3 {step['delivered_per_s']:8.0f}/s, loss {step['loss']:6.2%}, "
                f"p99 {step['p99_ms']:7.2f} ms, relay CPU {step['relay_cpu_s']:.2f} s "
                f"({step['msgs_per_cpu_s']:.0f} msg per CPU-second)"
            )
            if step["relay_in"]:
                print(
                    f"      router read {step['relay_in']} of {step['sent_per_s'] * STEP_S:.0f} sent, "
                    f"wrote {step['relay_out']} (3 x {step['relay_out'] / 3:.0f})"
                )
    direct_p50 = percentile(direct, 50) / 1000
    direct_p99 = percentile(direct, 99) / 1000
    r_p50 = percentile(router["latency"], 50) / 1000 - direct_p50
    r_p99 = percentile(router["latency"], 99) / 1000 - direct_p50
    b_p50 = percentile(baseline["latency"], 50) / 1000 - direct_p50
    b_p99 = percentile(baseline["latency"], 99) / 1000 - direct_p50
    print(f"direct sender->receiver latency: p50 {direct_p50:.3f} ms, p99 {direct_p99:.3f} ms")
    notes = (
        f"2 shared cores, load average {load[0]:.2f}/{load[1]:.2f} at start (other work running; pessimistic); "
        f"direct path p50 {direct_p50:.3f} ms p99 {direct_p99:.3f} ms"
    )
    rate = sustained(router["steps"])
    base_rate = sustained(baseline["steps"])
    at_target = next((s for s in router["steps"] if s["offered"] == TARGET_RATE), None)
    capacity = percentile([s["msgs_per_cpu_s"] for s in router["steps"]], 50)
    base_capacity = percentile([s["msgs_per_cpu_s"] for s in baseline["steps"]], 50)
    record(
        "router.forward_1to3.sustained_rate",
        rate,
        "msg/s",
        base_rate,
        target=f">= {TARGET_RATE}",
        met=rate >= TARGET_RATE,
        notes="highest offered rate with <= 1% loss at every one of 3 receivers; baseline = pymavlink relay; " + notes,
    )
    record(
        "router.forward_1to3.per_cpu_second",
        capacity,
        "msg/CPU-s",
        base_capacity,
        target=f">= {TARGET_RATE}",
        met=capacity >= TARGET_RATE,
        notes="messages delivered to all 3 outputs per second of relay CPU time (median over the rate steps): "
        "the rate one free core would sustain, independent of the other load; " + notes,
    )
    record(
        "router.latency.added_p99",
        r_p99,
        "ms",
        b_p99,
        target=f"< {TARGET_P99_MS}",
        met=r_p99 < TARGET_P99_MS,
        notes=f"at {LATENCY_RATE} msg/s, 1 -> 3: p99(via relay) - p50(direct); baseline = pymavlink relay; " + notes,
    )
    record(
        "router.latency.added_p50",
        r_p50,
        "ms",
        b_p50,
        notes=f"at {LATENCY_RATE} msg/s: p50(via relay) - p50(direct); baseline = pymavlink relay; " + notes,
    )
    if at_target is not None:
        record(
            "router.latency.p99_at_20k",
            at_target["p99_ms"],
            "ms",
            direct_p99,
            notes=f"one-way p99 through the router at {TARGET_RATE} msg/s offered (loss {at_target['loss']:.2%}); "
            "baseline = direct path p99 at 1000 msg/s; " + notes,
        )
    return 0


if __name__ == "__main__":
    if len(sys.argv) > 1 and sys.argv[1] == "receiver":
        role_receiver([int(p) for p in sys.argv[2:]])
        sys.exit(0)
    if len(sys.argv) > 1 and sys.argv[1] == "relay":
        role_relay(int(sys.argv[2]), [int(p) for p in sys.argv[3:]])
        sys.exit(0)
    sys.exit(main())

"""End to end: the real waypoint_controller and path_planner fly the real ``uav-sitl``.

Processes: a real roscore, ``uav-sitl`` (speed factor 3, TCP and simulation links off, GCS link to
this test's monitor, API link through a relay this test can cut), ``autonomy.launch`` with only the
path planner and the controller (goals come from the test; the planner's start is the controller's
own ``/uav/controller/odom``), and a small ROS client process that relays services and topics.

Time: there is no simulator bridge, hence no ``/clock``: ``use_sim_time`` stays false and the nodes
run on wall time while the SITL runs 3x faster. The controller streams setpoints at 40 Hz wall
(> 13 per simulated second, PX4's rule is > 2 Hz; we require >= 10), the SITL judges stream and
link losses against wall-time floors as well (docs/sitl.md), so nothing times out falsely.

Every assertion on the vehicle uses the SITL's own telemetry on the GCS link (position, mode, armed,
landed state, the echoed active setpoint), never what the controller believes.

A third test puts the real ``uav-mavlink-router`` between the relay and the SITL (its TCP link), with a lossy
downlink on the controller's endpoint (the telemetry fades, as a radio at the edge of its range does).
"""

from __future__ import annotations

import math
import sys
import time
from collections.abc import Iterator
from contextlib import ExitStack, contextmanager
from dataclasses import dataclass
from pathlib import Path

import pytest
from e2e.autonomy.autonomy_e2e_rig import (
    PX4_LOITER,
    PX4_OFFBOARD,
    PX4_RTL,
    MavRelay,
    RosClient,
    SitlMonitor,
    dist_m,
    horizontal_m,
    wait_for,
)
from e2e.sitl.harness import SitlPorts, run_sitl
from helpers.procs import REPO, Proc, free_port, free_udp_port, roscore, wait_for_port

pytestmark = pytest.mark.slow

LAUNCH = REPO / "catkin_ws" / "src" / "uav_autonomy" / "launch" / "autonomy.launch"
CLIENT = Path(__file__).resolve().parent / "autonomy_e2e_ros_client.py"
SPEED = "3"
CRUISE_Z_M = 15.0  # goal_height_m over unknown terrain (unknown_elevation_m = 0)
LINK_TIMEOUT_S = 2.0
# Quicker RTL than the defaults (60 m return altitude, slow final descent) so the test stays short.
SITL_PARAMS = "params.defaults={RTL_RETURN_ALT: 20.0, RTL_DESCEND_ALT: 12.0, MPC_LAND_SPEED: 1.5, COM_DISARM_LAND: 1.0}"
CONTROLLER = (
    f"{{setpoint_rate_hz: 40.0, state_rate_hz: 10.0, link_timeout_s: {LINK_TIMEOUT_S}, reconnect_after_s: 4.0}}"
)
PLANNER = f"{{algorithm: straight, goal_height_m: {CRUISE_Z_M}, cruise_buffer_m: {CRUISE_Z_M}}}"
MAV_LANDED_STATE_ON_GROUND = 1


@dataclass
class Rig:
    monitor: SitlMonitor
    relay: MavRelay
    client: RosClient
    procs: list[Proc]

    def check(self) -> None:
        for p in self.procs:
            assert p.alive(), f"{p.name} died:\n{p.tail()}"

    def position(self) -> tuple[float, float, float] | None:
        return self.monitor.view().position_enu_m

    def state(self) -> dict[str, object]:
        return self.client.state()


@contextmanager
def rig(name: str, tmp_path: Path, *, router_link: str = "") -> Iterator[Rig]:
    """The rig; with ``router_link`` (router configuration keys) the controller's MAVLink goes through the relay
    and then ``uav-mavlink-router`` (its ``controller`` endpoint, with those keys) to the SITL's TCP link."""
    with ExitStack() as stack:
        env = stack.enter_context(roscore(f"roscore_{name}"))
        controller_port = free_udp_port()
        relay = MavRelay(controller_port)
        stack.callback(relay.close)
        api_port = free_udp_port() if router_link else relay.sitl_port
        ports = SitlPorts(free_udp_port(), free_udp_port(), api_port, free_udp_port(), free_port(), free_udp_port())
        links = ["--no-sim-link"] if router_link else ["--no-tcp", "--no-sim-link"]
        sitl = stack.enter_context(
            run_sitl(f"sitl_{name}", tmp_path, speed=SPEED, ports=ports, extra=[*links, "--set", SITL_PARAMS])
        )
        procs = [sitl.proc]
        if router_link:
            conf = tmp_path / "router.conf"
            conf.write_text(
                f"[General]\nLog = {tmp_path / 'router'}\nStatsInterval = 1\n"
                f"[TcpEndpoint sitl]\nAddress = 127.0.0.1\nPort = {ports.tcp}\n"
                f"[UdpEndpoint controller]\nMode = Normal\nAddress = 127.0.0.1\nPort = {relay.sitl_port}\n"
                f"{router_link}\n"
            )
            (tmp_path / "conf.d").mkdir(exist_ok=True)
            tcp_server = free_port()
            router = Proc(
                f"router_{name}",
                ["uav-mavlink-router", "-c", str(conf), "-d", str(tmp_path / "conf.d"), "-t", str(tcp_server)],
            )
            stack.callback(router.stop)
            wait_for_port(tcp_server, timeout_s=20.0, proc=router)
            procs.append(router)
        monitor = SitlMonitor(ports.gcs)
        stack.callback(monitor.close)
        launch = Proc(
            f"autonomy_{name}",
            [
                "roslaunch", str(LAUNCH), "feature_evaluator:=false", "goal_selector:=false", "output:=screen",
                f"connection_url:=udpin:127.0.0.1:{controller_port}", "odom_topic:=/uav/controller/odom",
                f"controller_overrides:={CONTROLLER}", f"planner_overrides:={PLANNER}",
            ],
            env=env,
        )  # fmt: skip
        stack.callback(launch.stop)
        client = RosClient()
        stack.callback(client.close)
        client_proc = Proc(
            f"autonomy_client_{name}",
            [sys.executable, str(CLIENT), str(client.listen_port), str(client.report_port)],
            env=env,
        )
        stack.callback(client_proc.stop)
        r = Rig(monitor, relay, client, [*procs, launch, client_proc])
        wait_for("the ROS client", lambda: client.ready, bool, 90.0, r.check)
        wait_for("the controller's MAVLink link", r.state, lambda s: bool(s.get("link_ok")), 60.0, r.check)
        try:
            yield r
        finally:
            logs = "\n".join(f"--- {p.name}\n{p.tail(25)}" for p in r.procs)
            print(logs)  # shown by pytest on failure


def take_off(r: Rig) -> tuple[float, float, float]:
    reply = r.client.set_state("TAKEOFF")
    assert reply["success"], reply
    assert reply["state"] == "TAKEOFF"
    wait_for("HOLD after the takeoff", r.state, lambda s: s.get("state") == "HOLD", 60.0, r.check)
    view = r.monitor.view()
    assert view.armed, "the controller's takeoff armed the vehicle"
    assert view.custom_mode == PX4_OFFBOARD, view.custom_mode
    pos = wait_for("10 m up", r.position, lambda p: p is not None and p[2] > 9.0, 20.0, r.check)
    assert pos is not None
    return pos


def fly_to_goal(r: Rig, goal_xy: tuple[float, float]) -> float:
    """Publish a goal; the planner's path must end above it and the SITL must get there. Returns wall s."""
    t0 = time.monotonic()
    n = r.client.n_paths()
    target = (goal_xy[0], goal_xy[1], CRUISE_Z_M)
    r.client.goal(*goal_xy)
    path = wait_for(
        f"a path to {goal_xy}", r.client.last_path, lambda p: r.client.n_paths() > n and len(p) >= 2, 20.0, r.check
    )
    assert dist_m(tuple(path[-1]), target) < 1e-3, path  # type: ignore[arg-type]
    wait_for(f"the vehicle at {target}", r.position, lambda p: dist_m(p, target) < 2.0, 60.0, r.check)
    assert r.state().get("state") == "AUTONOMOUS"
    return time.monotonic() - t0


def wait_landed_disarmed(r: Rig) -> None:
    wait_for(
        "landed and disarmed",
        r.monitor.view,
        lambda v: not v.armed and v.landed_state == MAV_LANDED_STATE_ON_GROUND,
        90.0,
        r.check,
    )
    state = wait_for("the controller back in IDLE", r.state, lambda s: s.get("state") == "IDLE", 10.0, r.check)
    assert "landed and disarmed" in str(state.get("last_event")), state


def test_takeoff_autonomous_goals_manual_override_and_rtl(tmp_path: Path) -> None:
    with rig("autonomy_mission", tmp_path) as r:
        take_off(r)
        reply = r.client.set_state("AUTONOMOUS")
        assert reply["success"], reply
        assert reply["state"] == "AUTONOMOUS", reply
        goals = [(40.0, 0.0), (40.0, 40.0), (0.0, 40.0)]
        times = [fly_to_goal(r, g) for g in goals]
        print(f"goals reached after {[round(t, 1) for t in times]} s (wall)")

        # MANUAL override while the autonomy is flying somewhere else: the autopilot follows the
        # operator's setpoint at once, and later autonomy output is ignored.
        r.client.goal(40.0, 40.0)
        wait_for(
            "leaving towards the next goal",
            r.position,
            lambda p: horizontal_m(p, (0.0, 40.0, 0.0)) > 4.0,
            30.0,
            r.check,
        )
        manual = (10.0, 25.0, 20.0)
        t_manual = time.monotonic()
        r.client.manual(*manual)
        view = wait_for(
            "the autopilot following the manual setpoint",
            r.monitor.view,
            lambda v: v.target_s > t_manual and dist_m(v.target_enu_m, manual) < 0.05,
            10.0,
            r.check,
        )
        latency = view.target_s - t_manual
        print(f"manual setpoint in force after {latency:.2f} s (wall, incl. ROS and the 20 Hz echo)")
        assert latency < 1.5, latency
        assert r.state().get("state") == "MANUAL"
        n_paths = r.client.n_paths()
        r.client.goal(-30.0, 0.0)  # the planner still plans ...
        wait_for("a new path during MANUAL", r.client.n_paths, lambda n: n > n_paths, 20.0, r.check)
        wait_for("the vehicle at the manual setpoint", r.position, lambda p: dist_m(p, manual) < 1.5, 60.0, r.check)
        t_hold = time.monotonic()
        time.sleep(2.0)  # ... but the controller ignores it: it stays on the operator's point
        assert dist_m(r.position(), manual) < 1.5, r.position()
        sent = r.relay.setpoints_since(t_hold)
        assert len(sent) > 40, len(sent)
        assert all(dist_m(s.position_enu_m, manual) < 1e-3 for s in sent), sent[-1]
        assert r.state().get("state") == "MANUAL"

        # RTL: the controller asks the autopilot, stops streaming, and ends landed and disarmed.
        reply = r.client.set_state("RTL")
        assert reply["success"], reply
        wait_for("AUTO.RTL", r.monitor.view, lambda v: v.custom_mode == PX4_RTL, 10.0, r.check)
        t_rtl = time.monotonic()
        assert r.state().get("state") == "RTL"
        wait_landed_disarmed(r)
        late = r.relay.setpoints_since(t_rtl + 0.3)
        assert late == [], f"{len(late)} setpoints sent during RTL"
        assert horizontal_m(r.position(), (0.0, 0.0, 0.0)) < 3.0, r.position()


def test_link_drop_and_autopilot_failsafe(tmp_path: Path) -> None:
    with rig("autonomy_faults", tmp_path) as r:
        take_off(r)
        # Fly east under MANUAL, then lose the link half way.
        far = (80.0, 0.0, CRUISE_Z_M)
        r.client.manual(*far)
        wait_for("half way east", r.position, lambda p: p is not None and p[0] > 25.0, 40.0, r.check)
        t_cut = time.monotonic()
        r.relay.cut(True)
        wait_for("link lost", r.state, lambda s: not s.get("link_ok"), 10.0, r.check)
        assert r.state().get("state") == "IDLE"
        # The autopilot's offboard-loss failsafe holds the vehicle where it is.
        wait_for("AUTO.LOITER (offboard loss)", r.monitor.view, lambda v: v.custom_mode == PX4_LOITER, 10.0, r.check)
        time.sleep(max(0.0, t_cut + 7.0 - time.monotonic()))  # past reconnect_after_s: the socket is reopened
        t_restore = time.monotonic()
        silent = r.relay.setpoints_since(t_cut + LINK_TIMEOUT_S + 0.7)
        assert silent == [], f"{len(silent)} setpoints sent without a link"
        r.relay.cut(False)
        wait_for("link up again", r.state, lambda s: bool(s.get("link_ok")), 15.0, r.check)
        time.sleep(1.5)
        assert r.relay.setpoints_since(t_restore) == [], "setpoints sent after reconnecting without a request"
        assert r.state().get("state") == "IDLE"
        held = r.position()
        assert held is not None
        assert 20.0 < held[0] < 70.0, held

        # Take control again: the first setpoints are where the vehicle is now, not the old target.
        t_hold = time.monotonic()
        reply = r.client.set_state("HOLD")
        assert reply["success"], reply
        assert reply["state"] == "HOLD", reply
        wait_for("OFFBOARD again", r.monitor.view, lambda v: v.custom_mode == PX4_OFFBOARD, 20.0, r.check)
        first = r.relay.setpoints_since(t_hold)
        assert first, "no setpoints after HOLD"
        assert dist_m(first[0].position_enu_m, held) < 3.0, (first[0], held)
        assert all(dist_m(s.position_enu_m, far) > 10.0 for s in first), "a stale setpoint was sent"

        # Autopilot failsafe: a geofence smaller than where the vehicle is sends it home by itself.
        t_fence = time.monotonic()
        r.monitor.set_param("GF_MAX_HOR_DIST", 15.0)
        wait_for("the geofence RTL", r.monitor.view, lambda v: v.custom_mode == PX4_RTL, 15.0, r.check)
        state = wait_for("the controller yielding", r.state, lambda s: s.get("state") == "RTL", 10.0, r.check)
        events = r.client.events_since(t_fence)
        assert any("yielded control" in e and "AUTO.RTL" in e for e in events), events
        assert any("Geofence" in t for t in r.monitor.view().texts), r.monitor.view().texts[-5:]
        t_yield = time.monotonic()
        print(f"controller state after the failsafe: {state}")
        wait_landed_disarmed(r)
        late = r.relay.setpoints_since(t_yield + 0.3)
        assert late == [], f"{len(late)} setpoints sent after yielding to the failsafe"
        assert math.hypot(*(r.position() or (99.0, 99.0, 0.0))[:2]) < 3.0


#: The controller's downlink (telemetry) through the router fades: 20 % of the frames lost, in bursts of 1500
#: frames on average (~1.5 s at the ~1000 frames a second the SITL's onboard streams send at 3x).
FADING_DOWNLINK = "LossPercent = 20\nLossBurst = 1500\nLinkDirection = out\nLinkSeed = 2"


def test_fading_telemetry_through_the_router_is_detected_and_the_autopilot_holds(tmp_path: Path) -> None:
    """Stale telemetry is detected (the controller stops its setpoints at once and says why) and the autopilot's
    offboard-loss failsafe (COM_OF_LOSS_T) holds the vehicle, as a real PX4 would."""
    with rig("autonomy_lossy", tmp_path, router_link=FADING_DOWNLINK) as r:
        for attempt in range(6):  # a fade during the takeoff makes the controller give up: ask again
            reply = r.client.set_state("TAKEOFF" if not r.monitor.view().armed else "HOLD")
            try:
                wait_for("HOLD", r.state, lambda s: s.get("state") == "HOLD", 30.0, r.check)
                break
            except AssertionError:
                print(f"takeoff attempt {attempt} interrupted: {reply}, {r.state()}")
        wait_for("airborne", r.position, lambda p: p is not None and p[2] > 5.0, 30.0, r.check)
        # hold in the air until a fade: the controller must notice the telemetry going stale
        t0 = time.monotonic()
        stale = ("position telemetry stale", "MAVLink link lost")
        wait_for(
            "the controller noticing stale telemetry",
            lambda: r.client.events_since(t0),
            lambda events: any(any(s in e for s in stale) for e in events),
            90.0,
            r.check,
        )
        t_stale = time.monotonic()
        assert r.state().get("state") == "IDLE", r.state()
        # no setpoint after it noticed (the router forwards what it sends: the relay sees everything)
        time.sleep(1.5)
        late = r.relay.setpoints_since(t_stale + 0.3)
        assert late == [], f"{len(late)} setpoints sent on stale telemetry"
        # the autopilot, no longer receiving setpoints, holds by itself (offboard loss, COM_OF_LOSS_T)
        wait_for("AUTO.LOITER (offboard loss)", r.monitor.view, lambda v: v.custom_mode == PX4_LOITER, 15.0, r.check)
        assert any("Offboard setpoints lost" in t for t in r.monitor.view().texts), r.monitor.view().texts[-5:]
        # the router made those losses, downlink only
        import json  # noqa: PLC0415

        stats = json.loads((tmp_path / "router" / "router-stats.json").read_text())
        link = next(e for e in stats["endpoints"] if e["name"] == "controller")["link"]
        assert set(link) == {"out"}, link
        assert link["out"]["dropped"] > 1000, link

"""The controller's state machine, driven step by step against a small PX4-like model.

The model (``Px4Model``) accepts OFFBOARD only while setpoints arrive faster than
2 Hz, confirms modes only through its heartbeat fields, moves toward position
setpoints at a fixed speed, flies RTL home and lands, and disarms on the ground.
"""

from __future__ import annotations

import itertools
import math
from dataclasses import dataclass, field, replace

import numpy as np
import pytest

from uav_autonomy.core.controller import (
    ControllerConfig,
    ControllerState,
    PoseCheck,
    RequestArm,
    RequestMode,
    RequestTakeoff,
    SendSetpoint,
    Telemetry,
    WaypointController,
)
from uav_autonomy.core.patterns import expanding_square
from uav_autonomy.errors import InvalidInputError, InvalidTransitionError
from uav_common.autopilot_modes import Autopilot, FlightMode
from uav_common.config import ConfigError, from_mapping

DT = 0.05


@dataclass
class Px4Model:
    mode: FlightMode = FlightMode.AUTO_LOITER
    armed: bool = False
    pos: np.ndarray = field(default_factory=lambda: np.zeros(3))
    speed_mps: float = 8.0
    setpoint: np.ndarray | None = None
    setpoint_times: list[float] = field(default_factory=list)
    reject_offboard: int = 0
    link_up: bool = True
    last_heartbeat_s: float | None = None
    autopilot: Autopilot = Autopilot.PX4
    requests: list[object] = field(default_factory=list)
    heard: Telemetry = field(default_factory=Telemetry)

    def handle(self, now: float, actions: list[object]) -> None:
        for a in actions:
            self.requests.append((now, a))
            if isinstance(a, SendSetpoint):
                self.setpoint = np.asarray(a.position_enu_m)
                self.setpoint_times.append(now)
            elif isinstance(a, RequestMode):
                if a.mode is FlightMode.OFFBOARD:
                    recent = [t for t in self.setpoint_times if now - t <= 0.5]
                    if self.reject_offboard > 0 or len(recent) < 2:
                        self.reject_offboard -= 1
                        continue
                self.mode = a.mode
            elif isinstance(a, RequestArm):
                self.armed = a.arm

    def physics(self, now: float) -> None:
        target = None
        if self.mode is FlightMode.OFFBOARD and self.armed and self.setpoint is not None:
            if not self.setpoint_times or now - self.setpoint_times[-1] > 0.5:
                self.mode = FlightMode.AUTO_LOITER  # offboard loss failsafe (COM_OF_LOSS_T)
            else:
                target = self.setpoint
        elif self.mode is FlightMode.AUTO_RTL and self.armed:
            target = np.array([0.0, 0.0, self.pos[2]]) if np.linalg.norm(self.pos[:2]) > 0.5 else np.zeros(3)
        elif self.mode is FlightMode.AUTO_LAND and self.armed:
            target = np.array([self.pos[0], self.pos[1], 0.0])
        if target is not None:
            delta = target - self.pos
            dist = float(np.linalg.norm(delta))
            step = self.speed_mps * DT
            self.pos = target.copy() if dist <= step else self.pos + delta / dist * step
        if self.armed and self.pos[2] < 0.05 and self.mode in (FlightMode.AUTO_RTL, FlightMode.AUTO_LAND):
            self.armed = False
        if self.link_up:
            self.last_heartbeat_s = now

    def telemetry(self) -> Telemetry:
        """What the shell holds: while the link is down, the last messages heard, with their old stamps."""
        if not self.link_up:
            return self.heard
        self.heard = Telemetry(
            heartbeat_s=self.last_heartbeat_s,
            custom_mode=self.mode.custom_mode,
            autopilot=self.autopilot,
            armed=self.armed,
            in_air=bool(self.pos[2] > 0.5),
            position_enu_m=(float(self.pos[0]), float(self.pos[1]), float(self.pos[2])),
            position_s=self.last_heartbeat_s,
            yaw_enu_rad=0.0,
        )
        return self.heard


class Rig:
    """The controller against the model, stepped every ``DT`` simulated seconds.

    ``wall_per_tick_s``: also pass a wall clock that advances this much per step (None: no wall clock).
    0.005 is a simulation running 10x faster than real time; the model's messages are stamped on both.
    """

    def __init__(self, *, wall_per_tick_s: float | None = None, **cfg: object) -> None:
        self.ctl = WaypointController(from_mapping(ControllerConfig, cfg, source="test"))
        self.ap = Px4Model()
        self.now = 0.0
        self.wall_per_tick_s = wall_per_tick_s
        self.wall_s: float | None = None if wall_per_tick_s is None else 1000.0
        self.heard_wall_s: float | None = None
        self.log: list[tuple[float, object]] = []
        self.pose: PoseCheck | None = None  # the watched pose estimate's state (None: not watched)
        self.position_invalid = ""  # the autopilot's LOCAL_POSITION_NED turned NaN

    def tick(self) -> list[object]:
        self.now = round(self.now + DT, 6)
        self.ap.physics(self.now)
        telemetry = self.ap.telemetry()
        if self.wall_s is not None and self.wall_per_tick_s is not None:
            self.wall_s = round(self.wall_s + self.wall_per_tick_s, 9)
            if self.ap.link_up:
                self.heard_wall_s = self.wall_s
            wall_position = self.heard_wall_s if telemetry.position_s is not None else None
            telemetry = replace(telemetry, heartbeat_wall_s=self.heard_wall_s, position_wall_s=wall_position)
        if self.position_invalid:
            telemetry = replace(telemetry, position_invalid=self.position_invalid)
        actions = self.ctl.step(self.now, telemetry, self.wall_s, self.pose)
        self.log.extend((self.now, a) for a in actions)
        self.ap.handle(self.now, actions)
        return actions

    def run(self, seconds: float) -> None:
        for _ in range(round(seconds / DT)):
            self.tick()

    def run_until(self, predicate, timeout_s: float) -> None:  # type: ignore[no-untyped-def]
        end = self.now + timeout_s
        while not predicate():
            assert self.now < end, f"timed out; state {self.ctl.state}, events {self.ctl.pop_events()}"
            self.tick()

    def flying_east(self) -> None:
        """Airborne, AUTONOMOUS on a 100 m path east, 0.5 s into it."""
        self.airborne()
        self.ctl.request(ControllerState.AUTONOMOUS, self.now)
        self.ctl.set_path([[0, 0, 10], [100, 0, 10]])
        self.run(0.5)

    def airborne(self, height: float = 10.0) -> None:
        self.run(0.2)
        self.ctl.request(ControllerState.TAKEOFF, self.now)
        self.run_until(lambda: self.ctl.state is ControllerState.HOLD, 20.0)
        assert self.ap.pos[2] == pytest.approx(height, abs=1.0)


def test_takeoff_streams_before_offboard_then_arms_and_climbs() -> None:
    rig = Rig(prestream_s=1.0)
    rig.run(0.2)
    assert rig.log == []  # IDLE sends nothing
    rig.ctl.request(ControllerState.TAKEOFF, rig.now)
    rig.run_until(lambda: rig.ctl.state is ControllerState.HOLD, 20.0)
    setpoints = [t for t, a in rig.log if isinstance(a, SendSetpoint)]
    first_mode = next(t for t, a in rig.log if isinstance(a, RequestMode))
    first_arm = next(t for t, a in rig.log if isinstance(a, RequestArm))
    streamed = [t for t in setpoints if t <= first_mode]
    assert first_mode - setpoints[0] >= 1.0 - 1e-9
    assert len(streamed) >= 10 * (first_mode - setpoints[0])  # >= 10 Hz
    assert first_arm > first_mode  # armed only after OFFBOARD was confirmed
    assert rig.ap.mode is FlightMode.OFFBOARD
    assert rig.ap.pos[2] == pytest.approx(10.0, abs=1.0)
    status = rig.ctl.status()
    assert status.state is ControllerState.HOLD
    assert status.autopilot_mode == "OFFBOARD"
    assert status.armed
    assert "takeoff complete" in status.last_event


def test_offboard_rejection_is_retried_from_the_heartbeat() -> None:
    rig = Rig(mode_retry_s=0.5)
    rig.ap.reject_offboard = 2
    rig.airborne()
    mode_requests = [t for t, a in rig.log if isinstance(a, RequestMode) and a.mode is FlightMode.OFFBOARD]
    assert len(mode_requests) == 3
    assert all(b - a >= 0.5 - 1e-9 for a, b in itertools.pairwise(mode_requests))


def test_offboard_gives_up_after_max_attempts() -> None:
    rig = Rig(max_mode_attempts=2, mode_retry_s=0.5)
    rig.ap.reject_offboard = 100
    rig.run(0.1)
    rig.ctl.request(ControllerState.TAKEOFF, rig.now)
    rig.run(5.0)
    assert rig.ctl.state is ControllerState.IDLE
    assert "did not enter OFFBOARD after 2" in rig.ctl.status().last_event
    assert not rig.ap.armed
    n = len(rig.log)
    rig.run(1.0)
    assert len(rig.log) == n  # nothing more is sent


def test_autonomous_follows_paths_and_takes_new_ones_at_once() -> None:
    rig = Rig(acceptance_radius_m=1.0, lookahead_m=0.0)
    rig.airborne()
    rig.ctl.request(ControllerState.AUTONOMOUS, rig.now)
    rig.ctl.set_path([[0, 0, 10], [0, 0, 30], [40, 0, 30], [40, 0, 20]])
    rig.run_until(lambda: np.linalg.norm(rig.ap.pos - [40, 0, 20]) < 0.5, 30.0)
    rig.ctl.set_path([[40, 0, 20], [40, 30, 20]])
    rig.tick()
    last = [a for _, a in rig.log if isinstance(a, SendSetpoint)][-1]
    assert last.position_enu_m == (40.0, 30.0, 20.0)
    assert last.yaw_enu_rad == pytest.approx(math.pi / 2, abs=0.05)  # facing north, along the leg
    rig.run_until(lambda: np.linalg.norm(rig.ap.pos - [40, 30, 20]) < 0.5, 30.0)
    assert rig.ctl.state is ControllerState.AUTONOMOUS


def test_lookahead_caps_the_setpoint_lead() -> None:
    rig = Rig(lookahead_m=5.0)
    rig.airborne()
    rig.ctl.request(ControllerState.AUTONOMOUS, rig.now)
    rig.ctl.set_path([[0, 0, 10], [100, 0, 10]])
    for _ in range(20):
        rig.tick()
        sp = [a for _, a in rig.log if isinstance(a, SendSetpoint)][-1]
        assert np.linalg.norm(np.asarray(sp.position_enu_m) - rig.ap.pos) <= 5.0 + rig.ap.speed_mps * DT + 1e-6


def test_manual_override_takes_effect_on_the_next_setpoint() -> None:
    rig = Rig()
    rig.airborne()
    rig.ctl.request(ControllerState.AUTONOMOUS, rig.now)
    rig.ctl.set_path([[0, 0, 10], [200, 0, 10]])
    rig.run(1.0)
    rig.ctl.set_manual_setpoint([5.0, -5.0, 12.0], 1.0, rig.now)
    assert rig.ctl.state is ControllerState.MANUAL
    rig.tick()
    sp = [a for _, a in rig.log if isinstance(a, SendSetpoint)][-1]
    assert sp.position_enu_m == (5.0, -5.0, 12.0)
    assert sp.yaw_enu_rad == 1.0
    rig.ctl.set_path([[0, 0, 10], [-50, 0, 10]])  # autonomy keeps planning: ignored in MANUAL
    rig.run(3.0)
    assert np.linalg.norm(rig.ap.pos - [5, -5, 12]) < 0.5


def test_nan_setpoints_and_paths_are_rejected_and_nothing_changes() -> None:
    rig = Rig(lookahead_m=0.0)
    rig.airborne()
    rig.ctl.request(ControllerState.AUTONOMOUS, rig.now)
    rig.ctl.set_path([[0, 0, 10], [10, 0, 10]])
    with pytest.raises(InvalidInputError, match="finite"):
        rig.ctl.set_path([[0, 0, 10], [math.nan, 0, 10]])
    with pytest.raises(InvalidInputError, match="manual setpoint"):
        rig.ctl.set_manual_setpoint([0.0, math.inf, 10.0], None, rig.now)
    with pytest.raises(InvalidInputError, match="manual yaw"):
        rig.ctl.set_manual_setpoint([0.0, 0.0, 10.0], math.nan, rig.now)
    with pytest.raises(InvalidInputError, match="stare_at"):
        rig.ctl.request(ControllerState.HOLD, rig.now, stare_at_enu_m=[0.0, math.nan, 0.0])
    assert rig.ctl.state is ControllerState.AUTONOMOUS
    rig.tick()
    sp = [a for _, a in rig.log if isinstance(a, SendSetpoint)][-1]
    assert sp.position_enu_m == (10.0, 0.0, 10.0)
    assert all(math.isfinite(v) for _, a in rig.log if isinstance(a, SendSetpoint) for v in a.position_enu_m)


def test_failsafe_mode_change_yields_at_once() -> None:
    rig = Rig()
    rig.airborne()
    rig.ctl.request(ControllerState.AUTONOMOUS, rig.now)
    rig.run(0.5)
    rig.ap.mode = FlightMode.AUTO_RTL  # the autopilot's own failsafe (e.g. low battery)
    failsafe_s = rig.now
    actions = rig.tick()
    assert not any(isinstance(a, SendSetpoint) for a in actions)
    assert rig.ctl.state is ControllerState.RTL
    assert "yielded" in rig.ctl.status().last_event
    rig.run_until(lambda: rig.ctl.state is ControllerState.IDLE, 30.0)
    assert not rig.ap.armed
    assert "landed and disarmed" in rig.ctl.status().last_event
    assert [a for t, a in rig.log if t > failsafe_s] == []  # it never fought the autopilot


def test_failsafe_while_offboard_is_being_requested_is_not_overridden() -> None:
    """Taking control back (HOLD from AUTO.LOITER): the autopilot accepts OFFBOARD but a geofence RTL
    replaces it before the heartbeat shows OFFBOARD. A retry would cancel the failsafe: yield instead."""
    rig = Rig(mode_retry_s=0.5)
    rig.airborne()
    rig.ap.mode = FlightMode.AUTO_LOITER  # e.g. after an offboard-loss failsafe
    rig.run_until(lambda: rig.ctl.state is ControllerState.IDLE, 5.0)
    rig.ctl.request(ControllerState.HOLD, rig.now)
    rig.run_until(lambda: any(isinstance(a, RequestMode) for t, a in rig.log if t >= rig.now), 5.0)
    rig.ap.mode = FlightMode.AUTO_RTL  # the failsafe, between our request and the next heartbeat
    failsafe_s = rig.now
    rig.tick()
    assert rig.ctl.state is ControllerState.RTL
    assert "yielded" in rig.ctl.status().last_event
    rig.run_until(lambda: rig.ctl.state is ControllerState.IDLE, 30.0)  # mirrors RTL until landed
    assert "landed and disarmed" in rig.ctl.status().last_event
    assert [a for t, a in rig.log if t > failsafe_s] == []  # no retry, no setpoint: the failsafe ran


def test_offboard_requested_from_rtl_by_the_user_is_still_retried() -> None:
    """The vehicle was already in RTL when the user asked for HOLD: retrying that request is right."""
    rig = Rig(mode_retry_s=0.5)
    rig.airborne()
    rig.ap.mode = FlightMode.AUTO_RTL
    rig.run_until(lambda: rig.ctl.state is ControllerState.RTL, 5.0)
    rig.ap.reject_offboard = 1
    rig.ctl.request(ControllerState.HOLD, rig.now)
    rig.run_until(lambda: rig.ap.mode is FlightMode.OFFBOARD, 10.0)
    rig.run(0.2)
    assert rig.ctl.state is ControllerState.HOLD


def test_pilot_mode_change_yields_to_idle() -> None:
    rig = Rig()
    rig.airborne()
    rig.ap.mode = FlightMode.POSCTL
    assert rig.tick() == []
    assert rig.ctl.state is ControllerState.IDLE
    rig.run(2.0)
    assert not any(isinstance(a, RequestMode) for t, a in rig.log if t > rig.now - 2.0)


def test_link_drop_stops_setpoints_and_reconnect_sends_nothing_stale() -> None:
    rig = Rig(link_timeout_s=0.5)
    rig.flying_east()
    rig.ap.link_up = False
    drop = rig.now
    rig.run(2.0)
    sent_after = [t for t, a in rig.log if isinstance(a, SendSetpoint) and t > drop + 0.5 + 1e-9]
    assert sent_after == []
    assert rig.ctl.state is ControllerState.IDLE
    assert not rig.ctl.status().link_ok
    rig.ap.link_up = True
    back = rig.now
    rig.run(1.0)
    assert rig.ctl.status().link_ok
    assert [a for t, a in rig.log if t > back] == []  # nothing until asked again
    rig.ctl.request(ControllerState.HOLD, rig.now)
    rig.tick()
    sp = [a for _, a in rig.log if isinstance(a, SendSetpoint)][-1]
    assert np.linalg.norm(np.asarray(sp.position_enu_m) - rig.ap.pos) < 1.0  # fresh: where it is now


def test_a_simulation_running_ahead_of_its_messages_is_not_a_lost_link() -> None:
    # 10x real time; the autopilot's messages stop arriving for 2.5 simulated seconds (0.25 wall s: a router
    # or this process starved of CPU), longer than both timeouts: the controller keeps flying.
    rig = Rig(wall_per_tick_s=DT / 10, link_timeout_s=2.0, position_timeout_s=1.0, wall_floor_s=0.5)
    rig.flying_east()
    rig.ap.link_up = False
    silent = rig.now
    rig.run(2.5)
    rig.ap.link_up = True
    assert rig.ctl.state is ControllerState.AUTONOMOUS
    assert rig.ctl.status().link_ok
    assert all(isinstance(a, SendSetpoint) for t, a in rig.log if t > silent)
    assert len([a for t, a in rig.log if t > silent]) == round(2.5 / DT)  # not one setpoint missed
    rig.run(1.0)
    assert rig.ap.pos[0] > 20.0  # still flying the path
    # Silence of more than the wall floor as well is a lost link, at any speed.
    rig.ap.link_up = False
    silent = rig.now
    rig.run(10.0)  # 1 wall s
    assert rig.ctl.state is ControllerState.IDLE
    assert not rig.ctl.status().link_ok
    stopped = max(t for t, a in rig.log if isinstance(a, SendSetpoint))
    # Position is stale after 1 simulated s and the 0.5 wall s floor (5 simulated s at 10x), not before.
    assert stopped == pytest.approx(silent + 5.0, abs=DT + 1e-9)


@pytest.mark.parametrize("wall_per_tick_s", [None, DT], ids=["no wall clock", "real time"])
def test_without_a_wall_clock_or_at_real_time_timeouts_are_unchanged(wall_per_tick_s: float | None) -> None:
    rig = Rig(wall_per_tick_s=wall_per_tick_s, position_timeout_s=1.0, wall_floor_s=0.5)
    rig.airborne()
    rig.ap.link_up = False
    silent = rig.now
    rig.run(2.0)
    assert rig.ctl.state is ControllerState.IDLE
    stopped = max(t for t, a in rig.log if isinstance(a, SendSetpoint))
    assert stopped == pytest.approx(silent + 1.0, abs=DT + 1e-9)


def test_giving_up_waits_for_the_wall_floor_but_retries_do_not() -> None:
    def mode_requests(rig: Rig) -> list[float]:
        return [t for t, a in rig.log if isinstance(a, RequestMode)]

    plain = Rig(max_mode_attempts=2, mode_retry_s=0.5)
    frozen = Rig(max_mode_attempts=2, mode_retry_s=0.5, wall_per_tick_s=0.0, wall_floor_s=0.5)
    for rig in (plain, frozen):
        rig.ap.reject_offboard = 100
        rig.run(0.1)
        rig.ctl.request(ControllerState.TAKEOFF, rig.now)
        rig.run(5.0)
    # Retries are on simulated time alone (lockstep runs stay deterministic) ...
    assert mode_requests(frozen) == mode_requests(plain)
    assert len(mode_requests(plain)) == 2
    assert plain.ctl.state is ControllerState.IDLE
    # ... but while the wall clock stands still, the controller does not give up: it keeps streaming.
    assert frozen.ctl.state is ControllerState.TAKEOFF
    assert isinstance(frozen.tick()[0], SendSetpoint)
    frozen.wall_per_tick_s = DT
    frozen.run(0.6)
    assert frozen.ctl.state is ControllerState.IDLE
    assert "did not enter OFFBOARD after 2" in frozen.ctl.status().last_event


def test_rtl_and_land_requests_use_autopilot_modes() -> None:
    rig = Rig()
    rig.airborne()
    rig.ctl.request(ControllerState.RTL, rig.now)
    actions = rig.tick()
    assert RequestMode(FlightMode.AUTO_RTL) in actions
    assert not any(isinstance(a, SendSetpoint) for a in actions)
    rig.run_until(lambda: rig.ctl.state is ControllerState.IDLE, 40.0)
    assert rig.ap.pos[2] < 0.1
    with pytest.raises(InvalidTransitionError, match="not armed"):
        rig.ctl.request(ControllerState.LAND, rig.now)


def test_scripted_pattern_then_hold_with_stare() -> None:
    rig = Rig(lookahead_m=0.0, acceptance_radius_m=1.0)
    rig.run(0.1)
    with pytest.raises(InvalidTransitionError, match="needs waypoints"):
        rig.ctl.request(ControllerState.SCRIPTED, rig.now)
    pattern = expanding_square((0.0, 0.0), 10.0, 15.0, max_radius_m=15.0)
    assert rig.ctl.request(ControllerState.SCRIPTED, rig.now, waypoints_enu_m=pattern) is ControllerState.TAKEOFF
    rig.run_until(lambda: rig.ctl.state is ControllerState.SCRIPTED, 20.0)
    rig.run_until(lambda: rig.ctl.state is ControllerState.HOLD, 60.0)
    assert np.linalg.norm(rig.ap.pos - pattern[-1]) < 1.5
    rig.ctl.request(ControllerState.HOLD, rig.now, stare_at_enu_m=[-10.0, 40.0, 0.0])
    rig.tick()
    sp = [a for _, a in rig.log if isinstance(a, SendSetpoint)][-1]
    assert sp.yaw_enu_rad == pytest.approx(math.atan2(40.0 - rig.ap.pos[1], -10.0 - rig.ap.pos[0]), abs=0.05)


def test_requests_need_a_link_and_takeoff_only_from_the_ground() -> None:
    ctl = WaypointController(ControllerConfig())
    with pytest.raises(InvalidTransitionError, match="no MAVLink link"):
        ctl.request(ControllerState.TAKEOFF, 0.0)
    rig = Rig()
    rig.airborne()
    with pytest.raises(InvalidTransitionError, match="already in the air"):
        rig.ctl.request(ControllerState.TAKEOFF, rig.now)


def test_idle_request_in_flight_hands_over_to_autopilot_hold() -> None:
    rig = Rig()
    rig.airborne()
    rig.ctl.request(ControllerState.IDLE, rig.now)
    actions = rig.tick()
    assert actions == [RequestMode(FlightMode.AUTO_LOITER)]
    assert rig.tick() == []


def test_ardupilot_guided_takeoff_command_after_arming() -> None:
    ctl = WaypointController(ControllerConfig())
    t = Telemetry(
        heartbeat_s=0.0,
        custom_mode=4,
        autopilot=Autopilot.ARDUPILOT,
        armed=False,
        in_air=False,
        position_enu_m=(0.0, 0.0, 0.0),
        position_s=0.0,
    )
    ctl.step(0.0, t)
    ctl.request(ControllerState.TAKEOFF, 0.0)
    out = ctl.step(0.05, Telemetry(**{**t.__dict__, "heartbeat_s": 0.05, "position_s": 0.05}))
    assert RequestArm(True) in out  # GUIDED (4) already: confirmed, so arm
    armed = Telemetry(**{**t.__dict__, "heartbeat_s": 0.1, "position_s": 0.1, "armed": True})
    assert RequestTakeoff(10.0) in ctl.step(0.1, armed)


def test_controller_config_validation() -> None:
    with pytest.raises(ConfigError, match="setpoint_rate_hz"):
        from_mapping(ControllerConfig, {"setpoint_rate_hz": 5.0}, source="t")
    with pytest.raises(ConfigError, match="prestream_s"):
        from_mapping(ControllerConfig, {"prestream_s": 0.5}, source="t")
    with pytest.raises(ConfigError, match="wall_floor_s"):
        from_mapping(ControllerConfig, {"wall_floor_s": -1.0}, source="t")
    with pytest.raises(ConfigError, match="unknown key"):
        from_mapping(ControllerConfig, {"setpoint_hz": 20.0}, source="t")


@pytest.mark.parametrize(
    ("what", "reason"),
    [("stale", "no fresh estimate for 1.2 s (timeout 1 s)"), ("nan", "a message with NaN/inf at 12.00 s")],
)
def test_a_stale_or_nan_pose_stops_commanding_and_says_so(what: str, reason: str) -> None:
    """The pose the planner and the map use goes bad in flight: no more setpoints, the autopilot is asked to
    hold, the controller says why, and it refuses to fly again until the pose is fit."""
    rig = Rig()
    rig.pose = PoseCheck(True, source="pose estimate on /uav/autopilot/odom")
    rig.flying_east()
    assert rig.ctl.state is ControllerState.AUTONOMOUS
    rig.pose = PoseCheck(False, reason, "pose estimate on /uav/autopilot/odom")
    actions = rig.tick()
    assert not any(isinstance(a, SendSetpoint) for a in actions)
    assert RequestMode(FlightMode.AUTO_LOITER) in actions
    status = rig.ctl.status()
    assert status.state is ControllerState.IDLE
    assert (
        f"pose estimate on /uav/autopilot/odom cannot be flown on ({reason}): stopped commanding" in status.last_event
    )
    assert rig.ap.mode is FlightMode.AUTO_LOITER  # the autopilot holds on its own
    n = len(rig.log)
    rig.run(2.0)
    assert len(rig.log) == n  # silence: never a setpoint on the bad pose
    with pytest.raises(
        InvalidTransitionError, match=r"cannot enter AUTONOMOUS: the pose estimate .* cannot be flown on"
    ):
        rig.ctl.request(ControllerState.AUTONOMOUS, rig.now)
    rig.pose = PoseCheck(True, source="pose estimate on /uav/autopilot/odom")
    rig.tick()
    rig.ctl.request(ControllerState.AUTONOMOUS, rig.now)  # fit again: it may fly
    rig.run(3.0)
    assert rig.ctl.state is ControllerState.AUTONOMOUS
    assert rig.ap.mode is FlightMode.OFFBOARD


def test_a_pose_going_stale_after_a_failsafe_took_over_is_reported() -> None:
    """GPS lost: the autopilot's failsafe lands first (the controller yields), then the estimate goes stale; the
    controller was not commanding, and says why it will not."""
    rig = Rig()
    rig.pose = PoseCheck(True, source="pose estimate on /uav/autopilot/odom")
    rig.flying_east()
    rig.ap.mode = FlightMode.AUTO_LAND  # the position-estimate failsafe (PX4's Descend)
    rig.run(0.3)
    assert rig.ctl.state is ControllerState.LAND
    n = len(rig.log)
    rig.pose = PoseCheck(False, "no fresh estimate for 1.2 s (timeout 1 s)", "pose estimate on /uav/autopilot/odom")
    rig.tick()
    status = rig.ctl.status()
    assert status.state is ControllerState.LAND  # still following the autopilot's landing
    assert status.last_event == (
        "pose estimate on /uav/autopilot/odom cannot be flown on (no fresh estimate for 1.2 s (timeout 1 s)): "
        "not commanding on it"
    )
    rig.run(1.0)
    assert not any(isinstance(a, SendSetpoint) for _, a in rig.log[n:])
    assert rig.ctl.pop_events().count(status.last_event) == 1  # said once, not every step


def test_a_nan_autopilot_position_stops_commanding_at_once() -> None:
    rig = Rig()
    rig.flying_east()
    rig.position_invalid = "LOCAL_POSITION_NED with non-finite position [nan, nan, nan]"
    actions = rig.tick()
    assert not any(isinstance(a, SendSetpoint) for a in actions)
    assert RequestMode(FlightMode.AUTO_LOITER) in actions
    assert rig.ctl.state is ControllerState.IDLE
    assert (
        "the autopilot's position estimate is invalid (LOCAL_POSITION_NED with non-finite"
        in rig.ctl.status().last_event
    )
    with pytest.raises(InvalidTransitionError, match="position estimate is invalid"):
        rig.ctl.request(ControllerState.HOLD, rig.now)


def test_the_takeoff_waits_for_a_pose_estimate() -> None:
    rig = Rig()
    rig.pose = PoseCheck(False, "no valid estimate yet", "pose estimate on /uav/autopilot/odom")
    rig.run(0.2)
    with pytest.raises(InvalidTransitionError, match="no valid estimate yet"):
        rig.ctl.request(ControllerState.TAKEOFF, rig.now)

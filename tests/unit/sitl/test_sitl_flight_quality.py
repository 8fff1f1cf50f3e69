"""Flight quality of the real cascade on the real JSBSim F450 (in process, simulation time)."""

from __future__ import annotations

import math

from unit.sitl.sitl_builders import make_vehicle, pos, run, take_off

from sitl.core.control import Setpoint
from sitl.core.faults import FailureType, FailureUnit
from sitl.core.modes import FlightMode
from sitl.core.protocol import LandedState, MavResult


def test_hover_holds_within_30_cm() -> None:
    v = make_vehicle()
    take_off(v, 10.0, settle_s=5.0)
    worst = 0.0
    for _ in range(round(30.0 / v.dt_s)):
        v.step(v.t_s)
        n, e, d = pos(v)
        worst = max(worst, math.dist((n, e, d), (0.0, 0.0, -10.0)))
    assert worst < 0.3, f"hover wandered {worst:.3f} m"


def test_hover_holds_with_noisy_estimator() -> None:
    v = make_vehicle(**{"estimator.mode": "noisy", "estimator.seed": 7, "estimator.horizontal_bias_m": 0.0,
                        "estimator.vertical_bias_m": 0.0})  # fmt: skip
    take_off(v, 10.0, settle_s=5.0)
    worst = 0.0
    for _ in range(round(20.0 / v.dt_s)):
        v.step(v.t_s)
        worst = max(worst, math.dist(pos(v), (0.0, 0.0, -10.0)))
    assert worst < 0.6, f"hover with estimator noise wandered {worst:.3f} m"


def test_ten_metre_step_overshoots_less_than_20_percent() -> None:
    v = make_vehicle()
    take_off(v, 10.0)
    ap = v.autopilot
    sp = Setpoint(pos=(10.0, 0.0, -10.0), yaw_rad=0.0)
    ap.offboard_setpoint(sp, v.t_s, v.t_s)
    assert ap.set_mode(FlightMode.OFFBOARD) is MavResult.ACCEPTED
    peak = 0.0
    t0 = v.t_s
    reached_at = None
    while v.t_s - t0 < 20.0:
        ap.offboard_setpoint(sp, v.t_s, v.t_s)
        run(v, 0.05)
        n = pos(v)[0]
        peak = max(peak, n)
        if reached_at is None and n >= 9.0:
            reached_at = v.t_s - t0
    overshoot = (peak - 10.0) / 10.0
    assert overshoot < 0.20, f"overshoot {100 * overshoot:.1f} %"
    assert reached_at is not None
    assert reached_at < 8.0, "the step is too slow"
    assert abs(pos(v)[0] - 10.0) < 0.1


def test_takeoff_land_and_auto_disarm() -> None:
    v = make_vehicle()
    ap = v.autopilot
    run(v, 0.5)
    assert ap.landed
    assert ap.landed_state is LandedState.ON_GROUND
    take_off(v, 5.0, settle_s=2.0)
    assert not ap.landed
    assert ap.landed_state is LandedState.IN_AIR
    assert abs(-pos(v)[2] - 5.0) < 0.3
    assert ap.land(lat_deg=math.nan, lon_deg=math.nan) is MavResult.ACCEPTED
    run(v, 3.0)
    assert ap.landed_state is LandedState.LANDING
    run(v, 40.0, until=lambda x: not x.autopilot.armed)
    assert ap.landed
    assert not ap.armed
    assert any("auto disarm" in t for _, t in ap.statustexts)
    assert abs(pos(v)[2]) < 0.3


def test_battery_drain_matches_the_pack() -> None:
    """Coulomb counting agrees with the integrated current, and hover endurance is 10-20 minutes."""
    v = make_vehicle()
    take_off(v, 10.0, settle_s=2.0)
    b0 = v.battery_reading
    integrated_mah = 0.0
    currents = []
    for _ in range(round(60.0 / v.dt_s)):
        v.step(v.t_s)
        current = v.battery_reading.current_a
        integrated_mah += current * v.dt_s / 3.6
        currents.append(current)
    b1 = v.battery_reading
    used_mah = b1.consumed_mah - b0.consumed_mah
    assert abs(used_mah - integrated_mah) < 0.01 * used_mah
    capacity = v.cfg.battery.capacity_mah
    assert abs((b0.remaining - b1.remaining) * capacity - used_mah) < 0.01 * used_mah
    hover_current = sum(currents) / len(currents)
    assert 8.0 < hover_current < 20.0, hover_current
    endurance_min = capacity / 1000.0 / hover_current * 60.0
    assert 10.0 <= endurance_min <= 20.0, f"hover endurance {endurance_min:.1f} min"
    # the power drawn is the motors' electrical power through the ESCs plus avionics
    motors_w = v.fdm.motor_electrical_power_w()
    expected_w = motors_w / v.cfg.battery.esc_efficiency + v.cfg.battery.avionics_power_w
    assert abs(b1.power_w - expected_w) < 0.05 * expected_w
    assert b1.voltage_v < b0.voltage_v


def test_a_half_turn_while_setting_off_keeps_the_vehicle_level() -> None:
    """Offboard: a new position setpoint 60 m behind the vehicle with the heading reversed at once
    (what a waypoint follower sends). PX4 turns about the thrust axis (roll and pitch first); the
    tilt must stay within what the acceleration needs, never a roll-over towards the horizon."""
    v = make_vehicle()
    take_off(v, 20.0, settle_s=3.0)
    ap = v.autopilot
    sp = Setpoint(pos=(-60.0, 0.0, -20.0), yaw_rad=math.pi)  # heading 0 now: behind, facing back
    ap.offboard_setpoint(sp, v.t_s, v.t_s)
    assert ap.set_mode(FlightMode.OFFBOARD) is MavResult.ACCEPTED
    worst_tilt_deg = 0.0
    t0 = v.t_s
    while v.t_s - t0 < 6.0:
        ap.offboard_setpoint(sp, v.t_s, v.t_s)
        run(v, 0.02)
        q, _ = v.fdm.attitude_and_rates()
        w, x, y, z = q
        tilt = math.degrees(math.acos(max(-1.0, min(1.0, 1.0 - 2.0 * (x * x + y * y)))))
        worst_tilt_deg = max(worst_tilt_deg, tilt)
    max_tilt = ap.params["MPC_TILTMAX_AIR"]
    assert worst_tilt_deg <= max_tilt, f"tilted {worst_tilt_deg:.0f} deg during the turn (limit {max_tilt:g})"
    yaw = math.atan2(2 * (w * z + x * y), 1 - 2 * (y * y + z * z))
    assert abs(abs(yaw) - math.pi) < math.radians(5), f"heading {math.degrees(yaw):.0f} deg after 6 s"


def test_a_level_vehicle_coasts_to_a_stop_on_rotor_drag_and_stays_where_it_lands() -> None:
    """PX4's position-loss Descend holds the attitude level with no position control: the vehicle coasts.
    Rotor drag (linear in the airspeed, as measured on real multicopters) stops it within seconds, not the
    hundreds of metres quadratic body drag alone allowed; and once down it stays put on its skids."""
    v = make_vehicle(**{"params.defaults": {"SYS_FAILURE_EN": 1, "MPC_LAND_SPEED": 2.0}})
    take_off(v, 30.0, settle_s=2.0)
    ap = v.autopilot
    sp = Setpoint(pos=(500.0, 0.0, -30.0), yaw_rad=0.0)
    ap.offboard_setpoint(sp, v.t_s, v.t_s)
    assert ap.set_mode(FlightMode.OFFBOARD) is MavResult.ACCEPTED
    t0 = v.t_s
    while v.t_s - t0 < 12.0:
        ap.offboard_setpoint(sp, v.t_s, v.t_s)
        run(v, 0.05)
    gps_off = ap.inject_failure(FailureUnit.SENSOR_GPS, FailureType.OFF, 0)
    assert gps_off is MavResult.ACCEPTED  # Descend after EKF2_NOAID_TOUT
    while ap.mode is FlightMode.OFFBOARD and v.t_s - t0 < 20.0:  # the setpoints go on while it dead-reckons
        ap.offboard_setpoint(sp, v.t_s, v.t_s)
        run(v, 0.05)
    assert ap.mode is FlightMode.AUTO_LAND
    north0 = pos(v)[0]
    run(v, 1.0)
    speed0 = pos(v)[0] - north0
    assert speed0 > 5.0, f"the test needs the vehicle moving when the descent starts ({speed0:.1f} m/s)"
    run(v, 4.0)
    north4 = pos(v)[0]
    run(v, 1.0)
    speed5 = pos(v)[0] - north4
    # time constant 3-6 s: the speed falls to exp(-4.5 / tau) of itself between the two 1 s windows
    assert 0.2 * speed0 < speed5 < 0.5 * speed0, f"{speed0:.2f} m/s slowed to {speed5:.2f} m/s in 4.5 s"
    run(v, 60.0, until=lambda x: x.autopilot.landed)
    assert ap.landed
    assert pos(v)[0] - north0 < 10.0 * speed0, "coasted too far before touchdown"
    at_touchdown = pos(v)
    run(v, 5.0)
    assert math.dist(pos(v)[:2], at_touchdown[:2]) < 0.3, "the landed vehicle slid or rolled on"

"""One simulated vehicle: JSBSim physics, battery, estimator and the autopilot, stepped together.

No sockets and no clock here: :meth:`Vehicle.step` advances the simulation by
one physics step; the caller decides when (free-running pacing or lockstep
grants) and passes the wall-clock time in for the link-loss checks.
"""

from __future__ import annotations

import math

from sitl.config import EstimatorMode, SitlConfig
from sitl.core.autopilot import Autopilot
from sitl.core.battery import BatteryModel, BatteryReading, BatterySpec
from sitl.core.control import Mixer
from sitl.core.estimator import Estimator, NoiseModel
from sitl.core.params import ParamTable
from sitl.core.state import LocalState, VehicleState
from sitl.fdm import JsbsimQuad
from uav_common.geo import GeoPoint, LocalProjection

__all__ = ["Vehicle", "params_for_config"]


def params_for_config(cfg: SitlConfig) -> ParamTable:
    """The parameter table with defaults from the config (failsafe section, ``params.defaults``).

    Raises:
        ValueError: a default names an unknown parameter or is out of range.
    """
    fs = cfg.failsafe
    action_codes = {"disabled": 0, "hold": 1, "return": 2, "land": 3}
    obl_codes = {"hold": 5, "return": 3, "land": 4}
    gf_codes = {"disabled": 0, "warn": 1, "hold": 2, "return": 3, "land": 5}
    if fs.datalink_loss_action.value not in action_codes:
        msg = f"failsafe.datalink_loss_action cannot be {fs.datalink_loss_action.value!r}"
        raise ValueError(msg)
    defaults: dict[str, float] = {
        "BAT_LOW_THR": fs.battery_low_remaining,
        "BAT_CRIT_THR": fs.battery_critical_remaining,
        "COM_LOW_BAT_ACT": 3 if fs.battery_action == "return_land" else 0,
        "NAV_DLL_ACT": action_codes[fs.datalink_loss_action.value],
        "COM_DL_LOSS_T": fs.datalink_loss_timeout_s,
        "COM_OBL_RC_ACT": obl_codes[fs.offboard_loss_action.value],
        "COM_OF_LOSS_T": fs.offboard_loss_timeout_s,
        "GF_ACTION": gf_codes[fs.geofence_action.value],
        "GF_MAX_HOR_DIST": fs.geofence_radius_m,
        "GF_MAX_VER_DIST": fs.geofence_max_altitude_m,
        "BAT1_N_CELLS": cfg.battery.cells,
        "BAT1_CAPACITY": cfg.battery.capacity_mah,
        "MAV_SYS_ID": cfg.mavlink.system_id,
    }
    defaults.update(cfg.params.defaults)
    return ParamTable(defaults=defaults)


class Vehicle:
    """Physics + autopilot; the unit the simulation loop steps."""

    def __init__(self, cfg: SitlConfig, params: ParamTable) -> None:
        self.cfg = cfg
        home = GeoPoint(cfg.home.lat_deg, cfg.home.lon_deg, cfg.home.alt_amsl_m)
        self.home = home
        self.projection = LocalProjection(home)
        phys = cfg.physics
        self.dt_s = phys.dt_s
        self.divider = phys.outer_loop_divider
        yaw = math.radians(cfg.home.yaw_deg)
        self.fdm = JsbsimQuad(
            aircraft=phys.aircraft,
            dt_s=self.dt_s,
            lat_deg=home.lat_deg,
            lon_deg=home.lon_deg,
            ground_alt_amsl_m=home.alt_amsl_m,
            yaw_rad=yaw,
            motor_max_voltage_v=phys.motor_max_voltage_v,
            aircraft_dir=phys.aircraft_dir,
        )
        b = cfg.battery
        self.battery = BatteryModel(
            BatterySpec(b.cells, b.capacity_mah, b.internal_resistance_ohm, b.ocv_curve), initial_soc=b.initial_soc
        )
        e = cfg.estimator
        noise = None
        if e.mode is EstimatorMode.NOISY:
            noise = NoiseModel(
                e.horizontal_noise_m,
                e.vertical_noise_m,
                e.velocity_noise_mps,
                e.attitude_noise_rad,
                e.noise_correlation_s,
                e.horizontal_bias_m,
                e.vertical_bias_m,
                e.gps_dropouts_per_hour,
                e.gps_dropout_duration_s,
                e.dropout_drift_mps,
            )
        self.estimator = Estimator(self.projection, noise, seed=e.seed)
        self.params = params
        self.autopilot = Autopilot(
            params=params,
            home=home,
            home_yaw_rad=yaw,
            mixer=Mixer(phys.thrust_curve_exponent, phys.idle_thrust),
            outer_dt_s=self.dt_s * self.divider,
            datalink_floor_s=cfg.time.datalink_wall_floor_s,
            offboard_floor_s=cfg.time.stream_wall_floor_s,
            manual_floor_s=cfg.time.stream_wall_floor_s,
        )
        self.steps = 0
        self.t_s = 0.0
        self.duty: tuple[float, float, float, float] = (0.0, 0.0, 0.0, 0.0)
        self._truth: VehicleState | None = None
        self._truth_step = -1
        self._truth_pos: tuple[float, float, float] | None = None
        self._truth_pos_step = -1
        self.est: LocalState = self.estimator.update(self.truth(), self.pos_ned_truth_m)
        self._esc_eff = b.esc_efficiency
        self._avionics_w = b.avionics_power_w
        self._vmax = phys.motor_max_voltage_v
        self._power_sum_w = 0.0

    def truth(self) -> VehicleState:
        """Ground truth at the present step (cached)."""
        if self._truth_step != self.steps or self._truth is None:
            self._truth = self.fdm.state(self.t_s)
            self._truth_step = self.steps
        return self._truth

    @property
    def battery_reading(self) -> BatteryReading:
        return self.battery.reading

    @property
    def pos_ned_truth_m(self) -> tuple[float, float, float]:
        """True position in LOCAL_NED (cached per step, like :meth:`truth`)."""
        if self._truth_pos_step != self.steps or self._truth_pos is None:
            s = self.truth()
            self._truth_pos = self.projection.to_ned(GeoPoint(s.lat_deg, s.lon_deg, s.alt_amsl_m))
            self._truth_pos_step = self.steps
        return self._truth_pos

    def step(self, wall_s: float) -> None:
        """Advance one physics step (``dt_s``)."""
        ap = self.autopilot
        battery = self.battery
        if self.steps % self.divider == 0:
            self.est = self.estimator.update(self.truth(), self.pos_ned_truth_m)
            ap.outer_update(self.t_s, wall_s, self.est, battery.soc)
        q, rates = self.fdm.attitude_and_rates()
        voltage = battery.terminal_voltage_v
        duty = ap.inner_update(q, rates, self.dt_s, self._vmax / max(voltage, 1.0))
        self.duty = duty
        self.fdm.step(duty, voltage)
        # the electrical power of every step is integrated; the battery state (and its terminal
        # voltage) advances once per outer-loop period with the mean power of those steps
        self._power_sum_w += self.fdm.motor_electrical_power_w()
        self.steps += 1
        self.t_s = self.steps * self.dt_s
        if self.steps % self.divider == 0:
            mean_w = self._power_sum_w / self.divider / self._esc_eff + self._avionics_w
            battery.step(mean_w, self.dt_s * self.divider)
            self._power_sum_w = 0.0

    TERRAIN_PENETRATION_M = 0.01

    def set_terrain_amsl(self, elevation_m: float) -> bool:
        """Ground height under the vehicle from the bridge (returns False if it had to be clamped).

        JSBSim has one flat ground height; a report that would put the ground
        above the landing gear (the vehicle is over a roof edge, or inside an
        obstacle, which the bridge reports as a COLLISION) is clamped to the gear
        so the contact model never sees a deep penetration.
        """
        s = self.truth()
        gear_bottom_amsl = s.alt_amsl_m - self.fdm.ground_clearance_m + self.TERRAIN_PENETRATION_M
        clamped = min(elevation_m, gear_bottom_amsl)
        self.fdm.set_terrain_amsl(clamped)
        self._truth_step = -1
        self._truth_pos_step = -1
        return clamped == elevation_m

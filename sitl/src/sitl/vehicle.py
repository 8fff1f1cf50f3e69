"""One simulated vehicle: JSBSim physics, battery, estimator and the autopilot, stepped together.

No sockets and no clock here: :meth:`Vehicle.step` advances the simulation by
one physics step; the caller decides when (free-running pacing or lockstep
grants) and passes the wall-clock time in for the link-loss checks.
"""

from __future__ import annotations

import dataclasses
import math

import numpy as np

from sitl.config import SitlConfig, params_for_config
from sitl.core.autopilot import Autopilot
from sitl.core.battery import BatteryModel, BatteryReading, BatterySpec
from sitl.core.control import Mixer
from sitl.core.estimator import Estimator
from sitl.core.params import ParamTable
from sitl.core.protocol import MavSeverity
from sitl.core.state import LocalState, VehicleState
from sitl.core.wind import WindModel, WindSpec
from sitl.fdm import JsbsimQuad
from uav_common.geo import GeoPoint, LocalProjection

__all__ = ["Vehicle", "params_for_config"]


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
        self.estimator = Estimator(self.projection, e.noise_model(), seed=e.seed)
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
            personality=cfg.personality,
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
        w = cfg.wind
        self.wind: WindModel | None = None
        if w.enabled:
            spec = WindSpec(w.speed_mps, w.from_deg, w.reference_height_m, w.shear_exponent, w.turbulence.value)
            self.wind = WindModel(spec, np.random.default_rng(w.seed))
            self._update_wind()

    def _update_wind(self) -> None:
        """The wind at the vehicle's height for the next outer-loop period (only with ``wind`` configured)."""
        assert self.wind is not None
        s = self.truth()
        self.fdm.set_wind_ned(self.wind.update(s.height_above_ground_m, s.vel_ned_mps, self.dt_s * self.divider))

    def truth(self) -> VehicleState:
        """Ground truth at the present step (cached)."""
        if self._truth_step != self.steps or self._truth is None:
            self._truth = self.fdm.state(self.t_s)
            self._truth_step = self.steps
        return self._truth

    @property
    def battery_reading(self) -> BatteryReading:
        reading = self.battery.reading
        if self.autopilot.faults.battery_off:
            return dataclasses.replace(reading, remaining=0.0)
        return reading

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
        fdm = self.fdm
        divider = self.divider
        faults = ap.faults
        if self.steps % divider == 0:
            if self.wind is not None and self.steps:
                self._update_wind()
            estimator = self.estimator
            estimator.gps_fault = int(faults.gps)
            estimator.mag_fault = int(faults.mag)
            estimator.baro_fault = int(faults.baro)
            self.est = estimator.update(self.truth(), self.pos_ned_truth_m)
            if estimator.messages:  # EKF2 stopped fusing a sensor: say so (PX4 reports it as a warning)
                for text in estimator.messages:
                    ap.say(MavSeverity.WARNING, text)
                estimator.messages.clear()
            soc = 0.0 if faults.battery_off else battery.soc  # PX4's battery simulator: forced empty
            ap.outer_update(self.t_s, wall_s, self.est, soc, battery.terminal_voltage_v)
        q, rates = fdm.attitude_and_rates()
        voltage = battery.terminal_voltage_v
        # max(voltage, 1.0) written out (this runs every step)
        duty = ap.inner_update(q, rates, self.dt_s, self._vmax / (1.0 if voltage < 1.0 else voltage))
        self.duty = duty  # what the autopilot commands (HIL_ACTUATOR_CONTROLS)
        if faults.motors_degraded:  # a failed motor delivers less than it is commanded
            f = faults.motor_factors
            duty = (duty[0] * f[0], duty[1] * f[1], duty[2] * f[2], duty[3] * f[3])
        fdm.step(duty, voltage)
        # the electrical power of every step is integrated; the battery state (and its terminal
        # voltage) advances once per outer-loop period with the mean power of those steps
        self._power_sum_w += fdm.motor_electrical_power_w()
        steps = self.steps + 1
        self.steps = steps
        self.t_s = steps * self.dt_s
        if steps % divider == 0:
            mean_w = self._power_sum_w / divider / self._esc_eff + self._avionics_w
            battery.step(mean_w, self.dt_s * divider)
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

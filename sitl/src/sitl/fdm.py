"""JSBSim in-process: the F450 quadrotor stepped at a fixed ``dt``.

This is the only module that imports :mod:`jsbsim` and the only place where
JSBSim's imperial units become SI: everything leaving it is metres, seconds,
radians, newtons, volts and amperes, in NED / FRD frames.

Motor commands are written every step into the F450's external ESC inputs
(``fcs/cmd??_ext_nd``); the bundled model's flight control is a pass-through
(see ``sitl/aircraft/README.md``), so the autopilot's mixer alone drives the
four motors.
"""

from __future__ import annotations

import contextlib
import ctypes
import io
import math
import os
import sys
from collections.abc import Iterator
from dataclasses import dataclass
from pathlib import Path

import jsbsim

from sitl.core.state import VehicleState
from sitl.errors import FdmError

__all__ = ["FT_TO_M", "JsbsimQuad", "MotorReading"]

FT_TO_M = 0.3048
LBF_TO_N = 4.4482216152605
FTLBF_TO_NM = 1.3558179483314

BUNDLED_AIRCRAFT = Path(__file__).resolve().parent / "aircraft"

# F450 engine order = PX4 quad-X motor order: front right, aft left, front left, aft right.
_ESC_INPUTS = ("fcs/cmdFR_ext_nd", "fcs/cmdAL_ext_nd", "fcs/cmdFL_ext_nd", "fcs/cmdAR_ext_nd")


@dataclass(frozen=True)
class MotorReading:
    """One motor after the last step."""

    throttle: float
    rpm: float
    thrust_n: float
    current_a: float
    applied_voltage_v: float

    @property
    def electrical_power_w(self) -> float:
        return self.applied_voltage_v * self.current_a


def _flush_c_stdio() -> None:
    """Flush C stdio buffers (JSBSim writes through them) before fds are swapped back."""
    with contextlib.suppress(OSError, AttributeError):
        ctypes.CDLL(None).fflush(None)


@contextlib.contextmanager
def _quiet_stdio() -> Iterator[None]:
    """Silence JSBSim's banner and loader chatter on the C-level stdout/stderr."""
    try:
        sys.stdout.flush()
        sys.stderr.flush()
        saved = os.dup(1), os.dup(2)
    except (OSError, ValueError):
        yield
        return
    devnull = os.open(os.devnull, os.O_WRONLY)
    sink = io.StringIO()  # the jsbsim module may route C++ std::cout into Python's sys.stdout
    try:
        os.dup2(devnull, 1)
        os.dup2(devnull, 2)
        with contextlib.redirect_stdout(sink), contextlib.redirect_stderr(sink):
            yield
    finally:
        _flush_c_stdio()
        os.dup2(saved[0], 1)
        os.dup2(saved[1], 2)
        for fd in (*saved, devnull):
            os.close(fd)


class JsbsimQuad:
    """The F450 in JSBSim, with SI accessors.

    Args:
        aircraft: JSBSim model name (``F450``).
        dt_s: physics step.
        lat_deg, lon_deg: start position (home).
        ground_alt_amsl_m: terrain elevation under the start position.
        yaw_rad: initial heading.
        motor_max_voltage_v: the JSBSim motor's ``maxvolts`` (its throttle is
            ``applied volts / maxvolts``).
        aircraft_dir: folder holding aircraft folders; default: ``sitl/aircraft``
            (the F450 with extra structural contacts), then the ``jsbsim``
            package's own aircraft. Engines and systems always come from the
            ``jsbsim`` package.
    """

    def __init__(
        self,
        *,
        aircraft: str,
        dt_s: float,
        lat_deg: float,
        lon_deg: float,
        ground_alt_amsl_m: float,
        yaw_rad: float,
        motor_max_voltage_v: float,
        aircraft_dir: Path | None = None,
    ) -> None:
        data_root = str(jsbsim.get_default_root_dir())
        folder = aircraft_dir if aircraft_dir is not None else BUNDLED_AIRCRAFT
        if not (folder / aircraft).is_dir():
            folder = Path(data_root) / "aircraft"
        if not (folder / aircraft / f"{aircraft}.xml").is_file():
            msg = f"no JSBSim aircraft {aircraft!r} in {folder}"
            raise FdmError(msg)
        with _quiet_stdio():
            fdm = jsbsim.FGFDMExec(data_root)
            fdm.set_debug_level(0)
            fdm.set_aircraft_path(str(folder))
            loaded = fdm.load_model(aircraft)
        if not loaded:
            msg = f"JSBSim could not load aircraft {aircraft!r} from {folder}"
            raise FdmError(msg)
        self._fdm = fdm
        self.dt_s = dt_s
        self.motor_max_voltage_v = motor_max_voltage_v
        fdm.set_dt(dt_s)
        fdm["simulation/randomseed"] = 0
        self.ground_clearance_m = _ground_clearance_m(fdm, aircraft)
        self._terrain_amsl_m = ground_alt_amsl_m
        _set_initial_conditions(fdm, lat_deg, lon_deg, ground_alt_amsl_m, self.ground_clearance_m, yaw_rad)
        pm = fdm.get_property_manager()

        def node(name: str) -> jsbsim.FGPropertyNode:
            found = pm.get_node(name, False)
            if found is None:
                msg = f"aircraft {aircraft!r} has no property {name}"
                raise FdmError(msg)
            return found

        self._esc = [node(name) for name in _ESC_INPUTS]
        # per-step reads go through property nodes (a string lookup costs several times more)
        self._att = [node(n) for n in ("attitude/phi-rad", "attitude/theta-rad", "attitude/psi-rad")]
        self._rates = [node(n) for n in ("velocities/p-rad_sec", "velocities/q-rad_sec", "velocities/r-rad_sec")]
        self._current = [node(f"propulsion/engine[{i}]/current-amperes") for i in range(4)]
        self._state_nodes = [
            node(n)
            for n in (
                "position/lat-geod-deg",
                "position/long-gc-deg",
                "position/h-sl-ft",
                "velocities/v-north-fps",
                "velocities/v-east-fps",
                "velocities/v-down-fps",
                "accelerations/a-pilot-x-ft_sec2",
                "accelerations/a-pilot-y-ft_sec2",
                "accelerations/a-pilot-z-ft_sec2",
                "position/h-agl-ft",
                "accelerations/gravity-ft_sec2",
            )
        ]
        self._sim_time_s = 0.0
        self._last_throttle = (0.0, 0.0, 0.0, 0.0)
        self._last_voltage_v = motor_max_voltage_v
        self._wind_nodes = [node(f"atmosphere/wind-{axis}-fps") for axis in ("north", "east", "down")]

    # ------------------------------------------------------------------ stepping
    def step(self, duty: tuple[float, float, float, float], battery_voltage_v: float) -> None:
        """Apply ESC duty cycles (0..1) powered by ``battery_voltage_v`` and advance one ``dt``."""
        ratio = battery_voltage_v / self.motor_max_voltage_v
        t0, t1, t2, t3 = duty[0] * ratio, duty[1] * ratio, duty[2] * ratio, duty[3] * ratio
        throttle = (
            1.0 if t0 > 1.0 else (t0 if t0 > 0.0 else 0.0),
            1.0 if t1 > 1.0 else (t1 if t1 > 0.0 else 0.0),
            1.0 if t2 > 1.0 else (t2 if t2 > 0.0 else 0.0),
            1.0 if t3 > 1.0 else (t3 if t3 > 0.0 else 0.0),
        )
        esc = self._esc
        esc[0].set_double_value(throttle[0])
        esc[1].set_double_value(throttle[1])
        esc[2].set_double_value(throttle[2])
        esc[3].set_double_value(throttle[3])
        self._last_throttle = throttle
        self._last_voltage_v = battery_voltage_v
        if not self._fdm.run():
            msg = "JSBSim run() returned false"
            raise FdmError(msg)
        self._sim_time_s += self.dt_s

    def set_wind_ned(self, wind_ned_mps: tuple[float, float, float]) -> None:
        """The air's velocity over the ground (NED, m/s): JSBSim's ``atmosphere/wind-*-fps``."""
        n = self._wind_nodes
        for node_, value in zip(n, wind_ned_mps, strict=True):
            node_.set_double_value(value / FT_TO_M)

    def wind_ned_mps(self) -> tuple[float, float, float]:
        """The wind JSBSim applied in the last step (``atmosphere/total-wind-*-fps``), NED m/s."""
        f = self._fdm
        return (
            f["atmosphere/total-wind-north-fps"] * FT_TO_M,
            f["atmosphere/total-wind-east-fps"] * FT_TO_M,
            f["atmosphere/total-wind-down-fps"] * FT_TO_M,
        )

    def set_terrain_amsl(self, elevation_m: float) -> None:
        """Move JSBSim's ground to ``elevation_m`` AMSL (from the bridge's TERRAIN_REPORT)."""
        self._terrain_amsl_m = elevation_m
        self._fdm["position/terrain-elevation-asl-ft"] = elevation_m / FT_TO_M

    @property
    def terrain_amsl_m(self) -> float:
        return self._terrain_amsl_m

    # ------------------------------------------------------------------ reading
    def state(self, t_s: float) -> VehicleState:
        """Ground truth after the last step (SI, NED/FRD). Position is the CG's."""
        q, rates = self.attitude_and_rates()
        if q[0] < 0.0:
            q = (-q[0], -q[1], -q[2], -q[3])
        a = self._att
        phi, theta, psi = a[0].get_double_value(), a[1].get_double_value(), a[2].get_double_value()
        lat, lon, h_ft, vn, ve, vd, ax, ay, az, agl_ft, g = [n.get_double_value() for n in self._state_nodes]
        state = VehicleState(
            t_s=t_s,
            lat_deg=lat,
            lon_deg=lon,
            alt_amsl_m=h_ft * FT_TO_M,
            vel_ned_mps=(vn * FT_TO_M, ve * FT_TO_M, vd * FT_TO_M),
            q_wxyz=q,
            euler_rad=(phi, theta, _wrap_pi(psi)),
            rates_frd_radps=rates,
            specific_force_frd_mps2=(ax * FT_TO_M, ay * FT_TO_M, az * FT_TO_M),
            height_above_ground_m=max(0.0, agl_ft * FT_TO_M - self.ground_clearance_m),
            gravity_mps2=g * FT_TO_M,
        )
        fin = math.isfinite
        if not (fin(h_ft) and fin(vn) and fin(ve) and fin(vd) and fin(q[0]) and fin(q[1]) and fin(q[2]) and fin(q[3])):
            msg = f"JSBSim state became non-finite at t={t_s:.3f} s"
            raise FdmError(msg)
        return state

    def attitude_and_rates(self) -> tuple[tuple[float, float, float, float], tuple[float, float, float]]:
        """The cheap per-step subset: quaternion (w, x, y, z) body->NED and FRD body rates."""
        a, r = self._att, self._rates
        phi, theta, psi = a[0].get_double_value(), a[1].get_double_value(), a[2].get_double_value()
        cos, sin = math.cos, math.sin
        cr, sr = cos(0.5 * phi), sin(0.5 * phi)
        cp, sp = cos(0.5 * theta), sin(0.5 * theta)
        cy, sy = cos(0.5 * psi), sin(0.5 * psi)
        q = (
            cr * cp * cy + sr * sp * sy,
            sr * cp * cy - cr * sp * sy,
            cr * sp * cy + sr * cp * sy,
            cr * cp * sy - sr * sp * cy,
        )
        return q, (r[0].get_double_value(), r[1].get_double_value(), r[2].get_double_value())

    def motors(self) -> tuple[MotorReading, ...]:
        """Per-motor throttle, rpm, thrust, current and applied voltage after the last step."""
        f = self._fdm
        out = []
        for i, throttle in enumerate(self._last_throttle):
            out.append(
                MotorReading(
                    throttle=throttle,
                    rpm=f[f"propulsion/engine[{i}]/engine-rpm"],
                    thrust_n=f[f"propulsion/engine[{i}]/thrust-lbs"] * LBF_TO_N,
                    current_a=max(0.0, f[f"propulsion/engine[{i}]/current-amperes"]),
                    applied_voltage_v=throttle * self.motor_max_voltage_v,
                )
            )
        return tuple(out)

    def motor_electrical_power_w(self) -> float:
        """Sum over the motors of applied voltage times motor current (W)."""
        c = self._current
        t0, t1, t2, t3 = self._last_throttle
        # max(0.0, current) written out (this runs every step; same result for -0.0 and NaN)
        c0, c1, c2, c3 = (
            c[0].get_double_value(),
            c[1].get_double_value(),
            c[2].get_double_value(),
            c[3].get_double_value(),
        )
        return self.motor_max_voltage_v * (
            t0 * (c0 if c0 > 0.0 else 0.0)
            + t1 * (c1 if c1 > 0.0 else 0.0)
            + t2 * (c2 if c2 > 0.0 else 0.0)
            + t3 * (c3 if c3 > 0.0 else 0.0)
        )

    @property
    def mass_kg(self) -> float:
        return float(self._fdm["inertia/mass-slugs"]) * 14.593903

    @property
    def on_ground(self) -> bool:
        return bool(self._fdm["gear/wow"])


def _ground_clearance_m(fdm: jsbsim.FGFDMExec, aircraft: str) -> float:
    """CG height above the landing-gear contacts (gear z is in structural inches, z up)."""
    gear_z_in = []
    for i in range(int(fdm["gear/num-units"])):
        with contextlib.suppress(KeyError):  # structure contacts have no gear properties
            gear_z_in.append(fdm[f"gear/unit[{i}]/z-position"])
    if not gear_z_in:
        msg = f"aircraft {aircraft!r} has no landing gear"
        raise FdmError(msg)
    return float(-min(gear_z_in) * 0.0254)


def _set_initial_conditions(  # noqa: PLR0917
    fdm: jsbsim.FGFDMExec, lat_deg: float, lon_deg: float, ground_alt_amsl_m: float, clearance_m: float, yaw_rad: float
) -> None:
    """Resting on the ground at home, engines running (at zero throttle)."""
    fdm["ic/lat-geod-deg"] = lat_deg
    fdm["ic/long-gc-deg"] = lon_deg
    fdm["ic/terrain-elevation-ft"] = ground_alt_amsl_m / FT_TO_M
    fdm["ic/h-agl-ft"] = clearance_m / FT_TO_M
    fdm["ic/psi-true-deg"] = math.degrees(yaw_rad)
    for name in ("ic/u-fps", "ic/v-fps", "ic/w-fps", "ic/p-rad_sec", "ic/q-rad_sec", "ic/r-rad_sec"):
        fdm[name] = 0.0
    with _quiet_stdio():
        if not fdm.run_ic():
            msg = "JSBSim run_ic() failed"
            raise FdmError(msg)
    for i in range(4):
        fdm[f"propulsion/engine[{i}]/set-running"] = 1


def _wrap_pi(angle: float) -> float:
    return (angle + math.pi) % (2.0 * math.pi) - math.pi

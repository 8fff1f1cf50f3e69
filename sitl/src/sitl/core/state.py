"""Vehicle state value types shared by the FDM, the estimator and the autopilot."""

from __future__ import annotations

from dataclasses import dataclass

__all__ = ["LocalState", "VehicleState"]


@dataclass(frozen=True, slots=True)
class VehicleState:
    """A full state in SI units: geodetic position of the CG, NED velocity, FRD body quantities.

    ``q_wxyz`` rotates FRD body vectors into NED. ``specific_force_frd_mps2`` is
    what an accelerometer measures (about ``(0, 0, -g)`` at rest).
    ``height_above_ground_m`` is the distance of the landing gear above the
    ground under the vehicle (0 when resting on it).
    """

    t_s: float
    lat_deg: float
    lon_deg: float
    alt_amsl_m: float
    vel_ned_mps: tuple[float, float, float]
    q_wxyz: tuple[float, float, float, float]
    euler_rad: tuple[float, float, float]
    rates_frd_radps: tuple[float, float, float]
    specific_force_frd_mps2: tuple[float, float, float]
    height_above_ground_m: float
    gravity_mps2: float = 9.80665


@dataclass(frozen=True, slots=True)
class LocalState:
    """What the controllers use: :class:`VehicleState` plus its position in LOCAL_NED (metres from home)."""

    full: VehicleState
    pos_ned_m: tuple[float, float, float]
    gps_ok: bool = True
    pos_valid: bool = True
    """False once the horizontal position is no longer aided (GPS failure longer than EKF2_NOAID_TOUT)."""

    @property
    def vel_ned_mps(self) -> tuple[float, float, float]:
        return self.full.vel_ned_mps

    @property
    def yaw_rad(self) -> float:
        return self.full.euler_rad[2]

    @property
    def altitude_above_home_m(self) -> float:
        return -self.pos_ned_m[2]

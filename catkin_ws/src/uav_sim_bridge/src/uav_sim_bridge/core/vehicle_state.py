"""Ground truth of the vehicle in ROS conventions, converted from the SITL's sim-link fields.

The sim link speaks MAVLink (NED / FRD, ``[w, x, y, z]``); everything here is ``map``
(ENU) and ``base_link`` (FLU).  The conversion goes through :mod:`uav_common.frames`,
the project's only ENU <-> NED module.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field

import numpy as np
import numpy.typing as npt

from uav_common.frames import frd_to_flu, ned_to_enu, quat_ned_frd_to_enu_flu
from uav_common.geo import GeoPoint, LocalProjection
from uav_sim_bridge.core.transforms import RigidTransform

__all__ = ["VehicleState", "home_from_fix", "state_from_odometry"]

FloatArray = npt.NDArray[np.float64]


@dataclass(frozen=True)
class VehicleState:
    """The vehicle at one simulation instant.

    Attributes:
        sim_time_s: simulation time.
        t_map_base: pose of ``base_link`` in ``map``.
        velocity_body_mps: linear velocity in ``base_link`` (FLU).
        angular_velocity_body_radps: body rates in ``base_link`` (FLU).
    """

    sim_time_s: float
    t_map_base: RigidTransform
    velocity_body_mps: FloatArray = field(default_factory=lambda: np.zeros(3))
    angular_velocity_body_radps: FloatArray = field(default_factory=lambda: np.zeros(3))

    @property
    def position_m(self) -> FloatArray:
        return self.t_map_base.translation_m

    @property
    def velocity_map_mps(self) -> FloatArray:
        return np.asarray(self.t_map_base.rotation @ self.velocity_body_mps, dtype=np.float64)


def state_from_odometry(
    time_usec: int,
    position_ned_m: npt.ArrayLike,
    q_ned_frd_wxyz: npt.ArrayLike,
    velocity_frd_mps: npt.ArrayLike,
    rates_frd_radps: npt.ArrayLike,
) -> VehicleState:
    """Build a :class:`VehicleState` from MAVLink ``ODOMETRY`` fields (LOCAL_NED / BODY_FRD).

    Raises:
        ValueError: a non-finite position or attitude, or a zero quaternion.
    """
    pos = np.asarray(position_ned_m, dtype=np.float64)
    q = np.asarray(q_ned_frd_wxyz, dtype=np.float64)
    if pos.shape != (3,) or q.shape != (4,) or not (np.all(np.isfinite(pos)) and np.all(np.isfinite(q))):
        msg = f"ODOMETRY with invalid position {pos.tolist()} or attitude {q.tolist()}"
        raise ValueError(msg)
    vel = np.nan_to_num(np.asarray(velocity_frd_mps, dtype=np.float64))
    rates = np.nan_to_num(np.asarray(rates_frd_radps, dtype=np.float64))
    q_enu_flu = quat_ned_frd_to_enu_flu(q)
    return VehicleState(
        sim_time_s=time_usec * 1e-6,
        t_map_base=RigidTransform.from_quat(q_enu_flu, ned_to_enu(pos)),
        velocity_body_mps=frd_to_flu(vel),
        angular_velocity_body_radps=frd_to_flu(rates),
    )


def home_from_fix(fix: GeoPoint, position_ned_m: npt.ArrayLike) -> GeoPoint:
    """Geodetic home (the ``map`` origin) from a vehicle fix and its NED offset from home.

    Solves ``LocalProjection(home).to_ned(fix) == position_ned_m`` by fixed-point
    iteration (sub-millimetre after a few steps within a few km).
    """
    n, e, d = (float(v) for v in np.asarray(position_ned_m, dtype=np.float64))
    home = GeoPoint(fix.lat_deg, fix.lon_deg, fix.alt_amsl_m + d)
    for _ in range(8):
        got_n, got_e, _ = LocalProjection(home).to_ned(fix)
        err_n, err_e = n - got_n, e - got_e
        if math.hypot(err_n, err_e) < 1e-6:
            break
        lat = home.lat_deg - math.degrees(err_n / 6_371_000.0)
        lon = home.lon_deg - math.degrees(err_e / (6_371_000.0 * math.cos(math.radians(home.lat_deg))))
        home = GeoPoint(lat, lon, home.alt_amsl_m)
    return home

"""Land detector: landed / in-air from height, velocity and thrust, with hysteresis.

Like PX4's multicopter land detector it needs low thrust (the ground carries
part of the weight), near-zero velocity and ground contact for a while before
it declares "landed"; leaving the ground is immediate.
"""

from __future__ import annotations

import math

__all__ = ["LandDetector"]


class LandDetector:
    """Stateful; call :meth:`update` at the outer-loop rate."""

    TAKEOFF_HEIGHT_M = 0.3
    GROUND_HEIGHT_M = 0.25
    MAX_VERTICAL_SPEED_MPS = 0.3
    MAX_HORIZONTAL_SPEED_MPS = 0.5
    LOW_THRUST_OF_HOVER = 0.8
    CONFIRM_S = 0.5

    def __init__(self) -> None:
        self.landed = True
        self._candidate_since: float | None = None

    def update(
        self,
        t_s: float,
        *,
        armed: bool,
        thrust: float,
        hover_thrust: float,
        vel_ned: tuple[float, float, float],
        height_above_ground_m: float,
    ) -> bool:
        """Returns the (possibly changed) landed state."""
        speed_v = abs(vel_ned[2])
        speed_h = math.hypot(vel_ned[0], vel_ned[1])
        near_ground = height_above_ground_m <= self.GROUND_HEIGHT_M
        still = speed_v <= self.MAX_VERTICAL_SPEED_MPS and speed_h <= self.MAX_HORIZONTAL_SPEED_MPS
        if self.landed:
            if height_above_ground_m > self.TAKEOFF_HEIGHT_M:
                self.landed = False
                self._candidate_since = None
            return self.landed
        low_thrust = (not armed) or thrust <= self.LOW_THRUST_OF_HOVER * hover_thrust
        if near_ground and still and low_thrust:
            if self._candidate_since is None:
                self._candidate_since = t_s
            elif t_s - self._candidate_since >= self.CONFIRM_S:
                self.landed = True
                self._candidate_since = None
        else:
            self._candidate_since = None
        return self.landed

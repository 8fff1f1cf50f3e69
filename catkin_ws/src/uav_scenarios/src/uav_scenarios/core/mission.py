"""Mission logic of a scenario run: phases, stop criteria, person confirmation.

Pure: the mission manager node feeds times (simulation seconds since the run
started) and observations, and acts on what these functions return.
"""

from __future__ import annotations

import enum
import math
from collections import deque
from dataclasses import dataclass, field

import numpy as np
import numpy.typing as npt

from uav_scenarios.core.config import MissionKind, Scenario, StopCriteria, Strategy
from uav_scenarios.core.scoring.types import Detection

__all__ = [
    "Confirmation",
    "ConfirmationGate",
    "Phase",
    "StopReason",
    "check_stop",
    "flying_phase",
    "point_in_polygon",
    "resume_needed",
]


class Phase(enum.Enum):
    STARTING = "STARTING"
    TAKEOFF = "TAKEOFF"
    LOITERING = "LOITERING"
    SEARCHING = "SEARCHING"
    HOLDING = "HOLDING"
    DONE = "DONE"
    FAILED = "FAILED"


class StopReason(enum.Enum):
    TIME_LIMIT = "time_limit"
    MAPPED = "mapped_pct"
    TARGET_FOUND = "target_found"
    BATTERY_RESERVE = "battery_reserve"
    COLLISION = "collision"
    CRASHED = "crashed"
    WALL_TIMEOUT = "wall_timeout"
    NODE_DIED = "node_died"


def flying_phase(scenario: Scenario) -> Phase:
    """The phase after takeoff: loitering or searching."""
    return Phase.LOITERING if scenario.mission is MissionKind.LOITER else Phase.SEARCHING


def controller_state_for(scenario: Scenario) -> str:
    """The controller state to request after takeoff."""
    return "AUTONOMOUS" if scenario.strategy is Strategy.AUTONOMOUS else "SCRIPTED"


def resume_needed(phase: Phase, controller_state: str, *, in_air: bool, link_ok: bool, autopilot_mode: str) -> bool:
    """The controller yielded in the air while the mission was flying: ask it to fly on.

    That happens when an autopilot failsafe took over (e.g. offboard setpoints late on an
    overloaded machine: the autopilot holds position and the controller yields). RTL and
    LAND are left alone: those are the autopilot's battery, geofence or link decisions.
    """
    return (
        phase in (Phase.LOITERING, Phase.SEARCHING, Phase.HOLDING)
        and controller_state == "IDLE"
        and in_air
        and link_ok
        and autopilot_mode not in ("AUTO.RTL", "AUTO.LAND")
    )


def check_stop(
    stop: StopCriteria,
    *,
    elapsed_s: float,
    mapped_pct: float,
    battery_pct: float,
    collisions: int,
    crashed: bool,
    found_for_s: float | None,
    wall_elapsed_s: float,
) -> StopReason | None:
    """The first stop criterion met, in order of severity, or ``None``.

    Args:
        elapsed_s: simulation seconds since the run started.
        mapped_pct: % of the scene mapped (NaN if unknown: never stops on it).
        battery_pct: remaining % (NaN if unknown).
        found_for_s: seconds since the person was confirmed, ``None`` if not yet.
        wall_elapsed_s: wall-clock seconds since start (guard against a wedged simulation).
    """
    checks = (
        (crashed, StopReason.CRASHED),
        (stop.on_collision and collisions > 0, StopReason.COLLISION),
        (wall_elapsed_s >= stop.wall_timeout_s, StopReason.WALL_TIMEOUT),
        (
            stop.battery_reserve_pct is not None
            and math.isfinite(battery_pct)
            and battery_pct <= stop.battery_reserve_pct,
            StopReason.BATTERY_RESERVE,
        ),
        (
            stop.target_found and found_for_s is not None and found_for_s >= stop.after_target_found_s,
            StopReason.TARGET_FOUND,
        ),
        (
            stop.mapped_pct is not None and math.isfinite(mapped_pct) and mapped_pct >= stop.mapped_pct,
            StopReason.MAPPED,
        ),
        (elapsed_s >= stop.time_limit_s, StopReason.TIME_LIMIT),
    )
    return next((reason for hit, reason in checks if hit), None)


@dataclass(frozen=True)
class Confirmation:
    t_s: float
    position_m: tuple[float, float, float]
    instance_id: int
    detections: int


@dataclass
class _Cluster:
    position: npt.NDArray[np.float64]  # running mean, (3,)
    times: deque[float]
    ids: list[int]
    count: int = 0


@dataclass
class ConfirmationGate:
    """Confirms a person after ``needed`` detections within ``window_s`` at one place.

    Detections are clustered by ground position (``gate_m``); a detector that gives
    no position (NaN) cannot confirm a location and is ignored. The first cluster to
    reach ``needed`` detections inside the window is the confirmation; later calls
    return the same one.

    ``instance_id`` is the person of interest: detections that name another instance
    (ground truth knows who everyone is) are someone else and never confirm; a
    detector that cannot tell people apart (instance id 0) is taken at its word.
    """

    needed: int
    window_s: float
    gate_m: float = 10.0
    class_name: str = "person"
    instance_id: int = 0
    _clusters: list[_Cluster] = field(default_factory=list)
    confirmed: Confirmation | None = None

    def update(self, t_s: float, detections: tuple[Detection, ...]) -> Confirmation | None:
        if self.confirmed is not None:
            return self.confirmed
        for det in detections:
            if det.class_name != self.class_name or not all(math.isfinite(v) for v in det.position_m):
                continue
            if self.instance_id and det.instance_id not in (0, self.instance_id):
                continue
            pos = np.asarray(det.position_m, dtype=np.float64)
            near = [c for c in self._clusters if float(np.linalg.norm(c.position[:2] - pos[:2])) <= self.gate_m]
            if near:
                cluster = min(near, key=lambda c: float(np.linalg.norm(c.position[:2] - pos[:2])))
            else:
                cluster = _Cluster(pos.copy(), deque(), [])
                self._clusters.append(cluster)
            cluster.count += 1
            cluster.position = cluster.position + (pos - cluster.position) / cluster.count
            cluster.times.append(t_s)
            cluster.ids.append(det.instance_id)
            while cluster.times and cluster.times[0] < t_s - self.window_s:
                cluster.times.popleft()
            if len(cluster.times) >= self.needed:
                best_id = max(set(cluster.ids), key=cluster.ids.count)
                p = cluster.position
                self.confirmed = Confirmation(t_s, (float(p[0]), float(p[1]), float(p[2])), best_id, cluster.count)
                return self.confirmed
        return None


def point_in_polygon(x: float, y: float, polygon: tuple[tuple[float, float], ...]) -> bool:
    """Even-odd rule; points on an edge may fall either way."""
    inside = False
    n = len(polygon)
    for k in range(n):
        (x0, y0), (x1, y1) = polygon[k], polygon[(k + 1) % n]
        if (y0 > y) != (y1 > y) and x < x0 + (y - y0) * (x1 - x0) / (y1 - y0):
            inside = not inside
    return inside

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
    "CONFIRM_RADIUS_M",
    "Confirmation",
    "ConfirmationGate",
    "Phase",
    "StopReason",
    "check_stop",
    "flying_phase",
    "point_in_polygon",
    "resume_needed",
]


#: A confirmation is a place: detections within this distance of each other confirm it, and the scorer counts a
#: confirmation this close to the person of interest as finding them.
CONFIRM_RADIUS_M = 10.0


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
    #: The operator looked at this candidate and it is not the person searched for.
    rejected: bool = False


@dataclass
class ConfirmationGate:
    """Confirms a person after ``needed`` detections within ``window_s`` at one place.

    Detections (the geolocator's: any detector's boxes placed in ``map``) are clustered by
    ground position (``gate_m``). The first cluster to reach ``needed`` detections inside the
    window is the confirmation; later calls return the same one.

    A detection of the class scoring below ``min_score`` is counted (``below_threshold``); one
    the geolocator could not place (NaN position) cannot confirm a place and is counted
    (``unplaced``); so is one placed so vaguely that it could be anywhere in the gate (horizontal
    1-sigma over ``gate_m``: ``too_uncertain``, e.g. a box near the horizon seen from low
    altitude); so is one outside the search ``area`` (``outside_area``: a person there is not
    the one searched for). The mission manager reports the counts: nothing is dropped unseen.

    ``instance_id`` is the person of interest: detections that name another instance
    (ground truth knows who everyone is) are someone else and never confirm; a
    detector that cannot tell people apart (instance id 0) is taken at its word.

    A box-only detector cannot tell the person searched for from a bystander. With ``verify_xy``
    (the person's position, standing in for the operator who looks at the candidate through the
    camera and knows who they are looking for), a candidate farther than ``gate_m`` from it is
    rejected (:attr:`rejections`), its place is remembered (later detections there are absorbed)
    and the search goes on. Without it, the first candidate is the confirmation, right or wrong.
    """

    needed: int
    window_s: float
    gate_m: float = CONFIRM_RADIUS_M
    class_name: str = "person"
    instance_id: int = 0
    min_score: float = 0.0
    #: The search area (polygon, map metres); empty = anywhere.
    area: tuple[tuple[float, float], ...] = ()
    _clusters: list[_Cluster] = field(default_factory=list)
    confirmed: Confirmation | None = None
    #: Detections of the class seen so far: used, without a position, below ``min_score``, too uncertain,
    #: outside the search area.
    used: int = 0
    unplaced: int = 0
    below_threshold: int = 0
    too_uncertain: int = 0
    outside_area: int = 0
    #: The operator's check (see the class docstring); None = none.
    verify_xy: tuple[float, float] | None = None
    rejections: list[Confirmation] = field(default_factory=list)

    def _sigma_m(self, det: Detection) -> float:
        """Horizontal 1-sigma (major axis) of a placement; 0 when no covariance is given (ground truth)."""
        cov = det.position_cov_m2
        if len(cov) != 9 or not all(math.isfinite(c) for c in (cov[0], cov[1], cov[3], cov[4])):
            return 0.0
        xy = np.array([[cov[0], cov[1]], [cov[3], cov[4]]], dtype=np.float64)
        return float(math.sqrt(max(0.0, float(np.linalg.eigvalsh(xy).max()))))

    def _usable(self, det: Detection) -> bool:
        """Whether a detection can count towards a confirmation; if not, it is counted by why."""
        if det.class_name != self.class_name:
            return False
        if det.score < self.min_score:
            self.below_threshold += 1
            return False
        if not det.placed:
            self.unplaced += 1
            return False
        if self._sigma_m(det) > self.gate_m:
            self.too_uncertain += 1
            return False
        if self.area and not point_in_polygon(det.position_m[0], det.position_m[1], self.area):
            self.outside_area += 1
            return False
        return not (self.instance_id and det.instance_id not in (0, self.instance_id))

    def update(self, t_s: float, detections: tuple[Detection, ...]) -> Confirmation | None:
        if self.confirmed is not None:
            return self.confirmed
        for det in detections:
            if not self._usable(det):
                continue
            self.used += 1
            pos = np.asarray(det.position_m, dtype=np.float64)
            near = [c for c in self._clusters if float(np.linalg.norm(c.position[:2] - pos[:2])) <= self.gate_m]
            if near:
                cluster = min(near, key=lambda c: float(np.linalg.norm(c.position[:2] - pos[:2])))
            else:
                cluster = _Cluster(pos.copy(), deque(), [])
                self._clusters.append(cluster)
            cluster.count += 1
            if cluster.rejected:
                continue  # a candidate the operator has already turned down
            cluster.position = cluster.position + (pos - cluster.position) / cluster.count
            cluster.times.append(t_s)
            cluster.ids.append(det.instance_id)
            while cluster.times and cluster.times[0] < t_s - self.window_s:
                cluster.times.popleft()
            if len(cluster.times) >= self.needed:
                best_id = max(set(cluster.ids), key=cluster.ids.count)
                p = cluster.position
                candidate = Confirmation(t_s, (float(p[0]), float(p[1]), float(p[2])), best_id, cluster.count)
                if self.verify_xy is not None and math.dist(self.verify_xy, (p[0], p[1])) > self.gate_m:
                    cluster.rejected = True
                    self.rejections.append(candidate)
                    continue
                self.confirmed = candidate
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

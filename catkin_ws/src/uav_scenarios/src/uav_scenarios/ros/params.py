"""The scenario nodes' private parameters, parsed once at start-up into frozen dataclasses.

An unknown or mistyped private parameter stops the node (exit code 2) with a message naming
the parameter and what was expected (:func:`uav_common.ros.params.node_params`). The ``run``
namespaces are written by ``scenario_params`` from the scenario file (the launch files set them).
"""

from __future__ import annotations

from dataclasses import dataclass, field
from typing import Any

__all__ = ["MissionManagerParams", "MissionRun", "ScorerParams", "ScorerRun", "TrackerParams"]


@dataclass(frozen=True)
class MissionRun:
    """``~run``: the person of interest and a scripted baseline's controller request."""

    person: dict[str, Any] = field(default_factory=dict)
    scripted: dict[str, Any] | None = None


@dataclass(frozen=True)
class MissionManagerParams:
    """``mission_manager``'s private parameters."""

    scenario: str
    controller: str = "/waypoint_controller"
    expect_mission: str = ""
    depth_source: str = ""
    detector: str = ""
    pose_source: str = ""
    #: The test rig's MAVLink link for scripted faults (pymavlink URL: the router's TCP server); "" = none.
    autopilot_url: str = ""
    #: The sim bridge's service the scenario's camera faults go to.
    camera_fault_service: str = "/sim_bridge/set_camera_fault"
    wait_for_recorder: bool = False
    shutdown_on_stop: bool = True
    linger_s: float = 1.0
    max_linger_s: float = 30.0
    run: MissionRun = field(default_factory=MissionRun)

    def __post_init__(self) -> None:
        if not self.scenario:
            msg = "~scenario must name the scenario file"
            raise ValueError(msg)
        if self.linger_s < 0.0 or self.max_linger_s < self.linger_s:
            msg = f"need 0 <= ~linger_s <= ~max_linger_s, got {self.linger_s} and {self.max_linger_s}"
            raise ValueError(msg)


@dataclass(frozen=True)
class ScorerRun:
    """``~run``: what the scorer needs from the run's set-up (person, camera geometry)."""

    person: dict[str, Any] = field(default_factory=dict)
    map_camera: str = "nadir"
    camera_pitch_deg: dict[str, float] = field(default_factory=dict)
    map_camera_hfov_deg: float = 90.0
    map_camera_aspect: float = 0.75


@dataclass(frozen=True)
class ScorerParams:
    """``scorer``'s private parameters."""

    scenario: str
    run_dir: str = ""
    world_cache_dir: str = ""
    cameras: tuple[str, ...] = ("nadir", "forward")
    map_server: str = "/map_server"
    run: ScorerRun = field(default_factory=ScorerRun)

    def __post_init__(self) -> None:
        if not self.scenario:
            msg = "~scenario must name the scenario file"
            raise ValueError(msg)


@dataclass(frozen=True)
class TrackerParams:
    """``tracker``'s private parameters."""

    camera: str = "forward"
    detections: str = "/geolocator/detections"
    gate_m: float = 5.0
    min_hits: int = 2
    max_coast_s: float = 3.0
    min_score: float = 0.0

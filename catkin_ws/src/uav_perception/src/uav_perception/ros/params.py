"""The depth nodes' private parameters and their sections of ``config/depth.yaml``.

Parsed once at start-up by :func:`uav_common.ros.params.node_params`; an unknown or mistyped
private parameter stops the node. ``~config`` names the settings file (empty: the project's
``config/depth.yaml``), ``~overrides`` is merged over the node's section.
"""

from __future__ import annotations

from collections.abc import Mapping
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any, Literal, TypeVar

from uav_common.config import config_errors_as
from uav_common.detection_classes import DetectionClasses, load_detection_classes
from uav_common.paths import config_file
from uav_common.ros.params import load_section
from uav_perception.core.detection.degrade import DegradeConfig
from uav_perception.core.detection.geolocation import GeolocationConfig
from uav_perception.core.detection.learned import DecodeConfig
from uav_perception.errors import PerceptionConfigError

__all__ = [
    "DegradedDetectorParams",
    "DetectorParams",
    "EstimatorParams",
    "EvaluatorParams",
    "GeolocatorParams",
    "depth_section",
    "detection_classes",
]

T = TypeVar("T")


def depth_section(cls: type[T], section: str, config: str, overrides: Mapping[str, Any]) -> T:
    """``section`` of the settings file ``config`` (empty: ``config/depth.yaml``) with ``overrides`` over it.

    Raises:
        PerceptionConfigError: missing file or section, unknown key, wrong type, failed validation.
    """
    with config_errors_as(PerceptionConfigError):
        path = Path(config).expanduser() if config else config_file("depth.yaml")
        return load_section(cls, path, section, overrides)


@dataclass(frozen=True)
class EstimatorParams:
    """``depth_estimator``'s private parameters."""

    config: str = ""
    overrides: dict[str, Any] = field(default_factory=dict)
    camera: str = "nadir"
    pose_source: Literal["tf", "odom"] = "tf"
    map_frame: str = "map"
    base_frame: str = "base_link"
    odom_topic: str = "/uav/ground_truth/odom"
    tf_timeout_s: float = 0.3

    def __post_init__(self) -> None:
        if not self.tf_timeout_s > 0.0:
            msg = f"~tf_timeout_s must be > 0, got {self.tf_timeout_s}"
            raise ValueError(msg)


@dataclass(frozen=True)
class EvaluatorParams:
    """``depth_evaluator``'s private parameters."""

    config: str = ""
    overrides: dict[str, Any] = field(default_factory=dict)
    camera: str = "nadir"
    estimate_topic: str = "/depth_estimator/depth/image_raw"
    objects_file: str = ""
    world_dir_param: str = "/sim_bridge/world_dir"
    run_dir: str = ""


def detection_classes(path: str) -> DetectionClasses:
    """The class map ``path`` (empty: the project's ``config/detection_classes.yaml``).

    Raises:
        PerceptionConfigError: missing file, unknown key, an id claimed twice (the message names the file).
    """
    with config_errors_as(PerceptionConfigError):
        return load_detection_classes(Path(path).expanduser() if path else config_file("detection_classes.yaml"))


@dataclass(frozen=True)
class GeolocatorParams:
    """``geolocator``'s private parameters (docs/perception.md)."""

    #: The detector's camera: its ``/cameras/<camera>/color/camera_info`` gives the intrinsics.
    camera: str = "forward"
    #: The detector's ``vision_msgs/Detection2DArray`` topic ("" = ``/detections/<camera>/ground_truth``).
    detections: str = ""
    #: The detector's name in the output (``uav_msgs/DetectionArray.source``).
    detector: str = "detector"
    #: ``sensor_msgs/CameraInfo`` topic ("" = ``/cameras/<camera>/color/camera_info``).
    camera_info: str = ""
    #: Depth image of the same camera ("" = none): intersected first.
    depth: str = ""
    #: ``uav_msgs/GridLayers`` with ``elevation_m`` ("" = none): the map server's ``/map_server/layers``.
    elevation: str = ""
    #: Terrain model file (``uav_perception.shell.dem`` format; "" = none).
    terrain_dem: str = ""
    #: Class map ("" = ``config/detection_classes.yaml``).
    classes: str = ""
    map_frame: str = "map"
    #: Wait for the camera pose at an image's stamp this long (wall clock).
    tf_timeout_s: float = 0.5
    #: A frame waits at most this long (wall clock) for the depth image of its stamp.
    depth_wait_s: float = 1.0
    #: Boxes reaching farther than this beyond the image's edges are discarded (out_of_image).
    box_margin_px: float = 2.0
    geolocation: GeolocationConfig = field(default_factory=GeolocationConfig)

    def __post_init__(self) -> None:
        if not self.camera:
            msg = "~camera must name the detector's camera"
            raise ValueError(msg)
        for name in ("tf_timeout_s", "depth_wait_s"):
            if not getattr(self, name) > 0.0:
                msg = f"~{name} must be > 0, got {getattr(self, name)}"
                raise ValueError(msg)
        if not self.box_margin_px >= 0.0:
            msg = f"~box_margin_px must be >= 0, got {self.box_margin_px}"
            raise ValueError(msg)


@dataclass(frozen=True)
class DegradedDetectorParams:
    """``degraded_detector``'s private parameters (a test instrument: docs/perception.md)."""

    camera: str = "forward"
    #: The ground truth's box-only ``Detection2DArray`` ("" = ``/detections/<camera>/ground_truth``).
    input: str = ""
    camera_info: str = ""
    classes: str = ""
    degrade: DegradeConfig = field(default_factory=DegradeConfig)


@dataclass(frozen=True)
class DetectorParams:
    """``detector``'s private parameters (the learned detector: docs/detector.md)."""

    #: The ONNX model file (the format of ``uav_perception.core.detection.learned``); "" = the shipped
    #: ``uav_perception/models/uav_detector.onnx``.
    model: str = ""
    camera: str = "forward"
    #: ``sensor_msgs/Image`` topic ("" = ``/cameras/<camera>/color/image_raw``).
    image: str = ""
    #: Class map ("" = ``config/detection_classes.yaml``): the model's ``uav_classes`` names -> class ids.
    classes: str = ""
    #: onnxruntime intra-op threads (the target: >= 10 Hz at 640x480 on one core).
    threads: int = 1
    decode: DecodeConfig = field(default_factory=DecodeConfig)

    def __post_init__(self) -> None:
        if not self.camera:
            msg = "~camera must name the camera"
            raise ValueError(msg)
        if not 1 <= self.threads <= 64:
            msg = f"~threads must be within [1, 64], got {self.threads}"
            raise ValueError(msg)

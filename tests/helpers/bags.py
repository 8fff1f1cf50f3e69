"""Write ROS 1 bags with rosbags (no ROS needed): message builders for synthetic runs (report and dataset tests)."""

from __future__ import annotations

import json
import math
from pathlib import Path
from typing import Any

import numpy as np
from rosbags.rosbag1 import Writer
from rosbags.typesys import Stores, get_types_from_msg, get_typestore

from helpers.paths import REPO

MSG_DIR = REPO / "catkin_ws" / "src" / "uav_msgs" / "msg"


def typestore() -> Any:
    ts = get_typestore(Stores.ROS1_NOETIC)
    types: dict[str, Any] = {}
    for path in sorted(MSG_DIR.glob("*.msg")):
        types.update(get_types_from_msg(path.read_text(), f"uav_msgs/msg/{path.stem}"))
    ts.register(types)
    return ts


class BagKit:
    """Build messages by type name and write them with their stamp as the record time."""

    def __init__(self, path: Path) -> None:
        self.ts = typestore()
        self.writer = Writer(path)
        self.writer.open()
        self.conns: dict[str, Any] = {}
        self.seq = 0

    def T(self, name: str) -> Any:  # noqa: N802 - a type constructor
        return self.ts.types[name]

    def header(self, t_s: float, frame: str = "map") -> Any:
        self.seq += 1
        sec = math.floor(t_s)
        stamp = self.T("builtin_interfaces/msg/Time")(sec=sec, nanosec=round((t_s - sec) * 1e9))
        return self.T("std_msgs/msg/Header")(seq=self.seq, stamp=stamp, frame_id=frame)

    def point(self, x: float, y: float, z: float) -> Any:
        return self.T("geometry_msgs/msg/Point")(x=x, y=y, z=z)

    def write(self, topic: str, t_s: float, msg: Any) -> None:
        msgtype = msg.__msgtype__
        if topic not in self.conns:
            self.conns[topic] = self.writer.add_connection(topic, msgtype, typestore=self.ts)
        self.writer.write(self.conns[topic], int(t_s * 1e9), self.ts.serialize_ros1(msg, msgtype))

    def close(self) -> None:
        self.writer.close()

    # ---- builders ----------------------------------------------------------------------

    def odom(
        self,
        t: float,
        x: float,
        y: float,
        z: float,
        quat_wxyz: tuple[float, float, float, float] = (1.0, 0.0, 0.0, 0.0),
    ) -> Any:
        g = self.T
        qw, qx, qy, qz = quat_wxyz
        pose = g("geometry_msgs/msg/Pose")(
            position=self.point(x, y, z), orientation=g("geometry_msgs/msg/Quaternion")(x=qx, y=qy, z=qz, w=qw)
        )
        cov = np.zeros(36)
        twist = g("geometry_msgs/msg/Twist")(
            linear=g("geometry_msgs/msg/Vector3")(x=0.0, y=0.0, z=0.0),
            angular=g("geometry_msgs/msg/Vector3")(x=0.0, y=0.0, z=0.0),
        )
        return g("nav_msgs/msg/Odometry")(
            header=self.header(t),
            child_frame_id="base_link",
            pose=g("geometry_msgs/msg/PoseWithCovariance")(pose=pose, covariance=cov),
            twist=g("geometry_msgs/msg/TwistWithCovariance")(twist=twist, covariance=cov),
        )

    def battery(self, t: float, pct: float, volts: float) -> Any:
        nan = math.nan
        return self.T("sensor_msgs/msg/BatteryState")(
            header=self.header(t),
            voltage=volts,
            temperature=nan,
            current=-20.0,
            charge=nan,
            capacity=nan,
            design_capacity=5.0,
            percentage=pct / 100.0,
            power_supply_status=2,
            power_supply_health=1,
            power_supply_technology=3,
            present=True,
            cell_voltage=np.zeros(0, np.float32),
            cell_temperature=np.zeros(0, np.float32),
            location="",
            serial_number="",
        )

    def grid(self, t: float, layers: dict[str, np.ndarray], res: float, ox: float, oy: float) -> Any:
        names = list(layers)
        h, w = next(iter(layers.values())).shape
        data = np.concatenate([layers[n].astype(np.float32).ravel() for n in names])
        return self.T("uav_msgs/msg/GridLayers")(
            header=self.header(t),
            resolution_m=res,
            origin_x_m=ox,
            origin_y_m=oy,
            width=w,
            height=h,
            names=names,
            data=data,
        )

    def detections(
        self,
        t: float,
        camera: str,
        source: str,
        dets: list[tuple[int, str, tuple[int, int, int, int], float, tuple[float, float, float]]],
        *,
        scores: list[float] | None = None,
        position_source: str = "ground_truth",
        sigma_m: float = 0.0,
        discarded: dict[str, int] | None = None,
    ) -> Any:
        """A DetectionArray: the truth's (``source`` ground_truth) or the geolocator's (scores, position source,
        covariance, discard counts; a NaN position is an unplaced detection)."""
        d = self.T("uav_msgs/msg/Detection")
        placed = [all(math.isfinite(v) for v in p) for *_, p in dets]
        cov = np.diag([sigma_m**2, sigma_m**2, sigma_m**2]).ravel()
        return self.T("uav_msgs/msg/DetectionArray")(
            header=self.header(t, f"camera_{camera}_optical"),
            camera=camera,
            source=source,
            detections=[
                d(
                    instance_id=i,
                    class_name=c,
                    score=1.0 if scores is None else scores[k],
                    x_min=b[0],
                    y_min=b[1],
                    x_max=b[2],
                    y_max=b[3],
                    range_m=r,
                    visible_fraction=1.0 if source == "ground_truth" else math.nan,
                    position=self.point(*p),
                    position_covariance=cov if placed[k] else np.full(9, np.nan),
                    position_source=position_source if placed[k] else "unplaced:no_surface",
                )
                for k, (i, c, b, r, p) in enumerate(dets)
            ],
            discarded_reasons=list(discarded or {}),
            discarded_counts=np.array(list((discarded or {}).values()), dtype=np.uint32),
        )

    def image(self, t: float, arr: np.ndarray, encoding: str) -> Any:
        h, w = arr.shape[:2]
        data = np.frombuffer(np.ascontiguousarray(arr).tobytes(), dtype=np.uint8)
        return self.T("sensor_msgs/msg/Image")(
            header=self.header(t),
            height=h,
            width=w,
            encoding=encoding,
            is_bigendian=0,
            step=data.size // h,
            data=data,
        )

    def string(self, text: str) -> Any:
        return self.T("std_msgs/msg/String")(data=text)

    def controller(self, t: float, state: str) -> Any:
        return self.T("uav_msgs/msg/ControllerState")(
            header=self.header(t),
            state=state,
            autopilot_mode="OFFBOARD",
            armed=True,
            in_air=True,
            link_ok=True,
            last_event="",
        )

    def goal_reason(self, t: float, x: float, y: float) -> Any:
        return self.T("uav_msgs/msg/GoalReason")(
            header=self.header(t),
            goal=self.point(x, y, 0.0),
            score=1.0,
            features=["age"],
            weights=np.ones(1, np.float32),
            values=np.ones(1, np.float32),
            contributions=np.ones(1, np.float32),
            reason="new_best",
        )

    def status(self, t: float, phase: str, *, found: bool = False, stop_reason: str = "") -> Any:
        return self.T("uav_msgs/msg/ScenarioStatus")(
            header=self.header(t),
            scenario="synthetic",
            mission="search_and_rescue",
            strategy="autonomous",
            phase=phase,
            sim_time_s=t,
            real_time_factor=3.0,
            mapped_pct=1.0,
            battery_pct=90.0,
            controller_state="AUTONOMOUS",
            autopilot_mode="OFFBOARD",
            goal=self.point(0, 0, 0),
            target_found=found,
            target_position=self.point(30.0, -80.0, 0.0),
            detections_unplaced=0,
            candidates_rejected=0,
            complete_time_s=math.nan,
            stop=bool(stop_reason),
            stop_reason=stop_reason,
        )

    def object_states(self, t: float, objects: list[tuple[int, str, float, float, float]]) -> Any:
        """``(instance_id, name, x, y, yaw)`` of moving objects (people 0.5 x 0.5 x 1.7 m, vehicles 4.5 x 1.8 x 1.5)."""
        out = []
        for iid, name, x, y, yaw in objects:
            person = name.startswith("person")
            size = (0.5, 0.5, 1.7) if person else (4.5, 1.8, 1.5)
            q = self.T("geometry_msgs/msg/Quaternion")(x=0.0, y=0.0, z=math.sin(yaw / 2), w=math.cos(yaw / 2))
            pose = self.T("geometry_msgs/msg/Pose")(position=self.point(x, y, 0.0), orientation=q)
            out.append(
                self.T("uav_msgs/msg/ObjectState")(
                    instance_id=iid,
                    name=name,
                    class_name="person" if person else "vehicle",
                    kind="walking" if person else "car",
                    pose=pose,
                    size=self.T("geometry_msgs/msg/Vector3")(x=size[0], y=size[1], z=size[2]),
                    velocity=self.T("geometry_msgs/msg/Vector3")(x=1.0, y=0.0, z=0.0),
                    moving=True,
                )
            )
        return self.T("uav_msgs/msg/ObjectStateArray")(header=self.header(t), objects=out)

    def metrics(self, t: float, values: dict[str, float], summary: dict[str, Any] | None = None) -> Any:
        fields = {
            "mapped_pct": 0.0,
            "mapped_m2": 0.0,
            "mean_cell_age_s": math.nan,
            "observed_cells": 0,
            "occupied_voxels": -1,
            "map_iou": math.nan,
            "distance_m": 0.0,
            "agl_m": 0.0,
            "battery_pct": 100.0,
            "battery_used_mah": 0.0,
            "collisions": 0,
            "det_tp": 0,
            "det_fp": 0,
            "det_fn": 0,
        }
        fields.update(values)
        return self.T("uav_msgs/msg/RunMetrics")(
            header=self.header(t), sim_time_s=t, summary_json=json.dumps(summary or {}), **fields
        )

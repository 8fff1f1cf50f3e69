"""feature_evaluator: the map server's 2D layers -> feature maps and the combined score.

ROS interface:

Subscribes:
    ``/map_server/layers`` (uav_msgs/GridLayers): needs ``elevation_m``, ``last_seen_s``, ``observed``.
    ``~odom_topic`` (nav_msgs/Odometry, default ``/uav/ground_truth/odom``): drone position.
    ``/autonomy/target`` (uav_msgs/SearchTarget, latched by goal_selector).
    ``/autonomy/weights`` (uav_msgs/FeatureWeights, latched by goal_selector): for the ``score`` layer.
Publishes:
    ``/autonomy/features`` (uav_msgs/GridLayers): ``elevation_m age frontier target drone origin score``.
    ``~image_ns``/<name>/image (sensor_msgs/Image 32FC1, north-up) and ``.../image_color`` (rgb8),
    for every layer above, only while subscribed; ``~image_ns``/info (nav_msgs/MapMetaData, latched):
    resolution, size and origin of the images. Default ``~image_ns``: ``/autonomy/feature_images``.
Services:
    ``~get_features`` (uav_msgs/GetGridLayers): the last published features.
Parameters:
    ``~config`` (str, default: the project's ``config/autonomy.yaml``), section ``features`` (docs/autonomy.md);
    ``~overrides`` (dict, default {}): keys merged over that section; ``~odom_topic``; ``~image_ns``.
    Any other private parameter stops the node (exit code 2, docs/architecture.md).

Evaluates on every new layers message (new observations), on target or weight
changes, and at least every ``1 / rate_hz`` seconds (ROS time) with the last layers.

Causal lockstep (docs/lockstep.md): a participant with a lookahead of 2 steps; its inputs are counted, its
timer fires from the step.
"""

from __future__ import annotations

import math
import threading

import numpy as np
import rospy
from nav_msgs.msg import MapMetaData, Odometry
from sensor_msgs.msg import Image
from std_msgs.msg import Header

from uav_autonomy.core.features import ELEVATION, SCORED_FEATURES, FeatureConfig, FeatureEvaluator, MapLayers, Target
from uav_autonomy.core.grid_geometry import GridSpec
from uav_autonomy.core.mcdm import validate_weights, weighted_score
from uav_autonomy.errors import InvalidInputError, UavAutonomyError
from uav_autonomy.ros.conversions import (
    NumpyGridLayers,
    color_image_msg,
    float_image_msg,
    grid_layers_from_msg,
    grid_layers_msg,
    map_meta_data,
    target_from_points,
)
from uav_autonomy.ros.params import FeatureParams, autonomy_section
from uav_common.ros.lockstep import Participant
from uav_common.ros.node import run_participant
from uav_common.ros.params import node_params
from uav_msgs.msg import FeatureWeights, GridLayers, SearchTarget
from uav_msgs.srv import GetGridLayers, GetGridLayersResponse

REQUIRED_LAYERS = (ELEVATION, "last_seen_s", "observed")
#: Steps between its inputs and when its features are consumed, in the causal lockstep (docs/lockstep.md).
LOOKAHEAD_STEPS = 2
PUBLISHED = (ELEVATION, *SCORED_FEATURES, "score")


def map_layers_from_msg(msg: GridLayers) -> MapLayers:
    """GridLayers -> MapLayers (``observed`` > 0.5 is observed; NaN is not).

    Raises:
        InvalidInputError: a required layer is missing or the grid is malformed.
    """
    spec, layers = grid_layers_from_msg(msg)
    missing = [n for n in REQUIRED_LAYERS if n not in layers]
    if missing:
        text = f"/map_server/layers lacks layer(s) {missing}; has {sorted(layers)}"
        raise InvalidInputError(text)
    observed = np.nan_to_num(layers["observed"], nan=0.0) > 0.5
    return MapLayers(spec, layers[ELEVATION], layers["last_seen_s"], observed)


class FeatureEvaluatorNode:
    def __init__(self, config: FeatureConfig, image_ns: str, odom_topic: str) -> None:
        self.config = config
        self.odom_topic = odom_topic
        self.core = FeatureEvaluator(config)
        self.image_ns = image_ns.rstrip("/")
        self._lock = threading.Lock()
        self._layers: MapLayers | None = None
        self._frame_id = "map"
        self._drone_xy: tuple[float, float] | None = None
        self._target: Target | None = None
        self._weights = validate_weights({})
        self._last_eval_s = -math.inf
        self._last_msg: GridLayers | None = None
        self._info_spec: GridSpec | None = None

    def start(self, ls: Participant) -> None:
        self.pub_features = ls.publisher("/autonomy/features", GridLayers, queue_size=1)
        self.pub_info = ls.publisher(f"{self.image_ns}/info", MapMetaData, queue_size=1, latch=True)
        self.pub_images = {
            name: (
                ls.publisher(f"{self.image_ns}/{name}/image", Image, queue_size=1),
                ls.publisher(f"{self.image_ns}/{name}/image_color", Image, queue_size=1),
            )
            for name in PUBLISHED
        }
        ls.subscribe("/map_server/layers", NumpyGridLayers, self.on_layers, queue_size=1, buff_size=2**26)
        ls.subscribe(self.odom_topic, Odometry, self.on_odom, queue_size=1)
        ls.subscribe("/autonomy/target", SearchTarget, self.on_target, queue_size=10)
        ls.subscribe("/autonomy/weights", FeatureWeights, self.on_weights, queue_size=10)
        ls.service("~get_features", GetGridLayers, self.on_get_features)
        ls.timer(1.0 / self.config.rate_hz, self.on_timer, name="evaluate")

    # -------------------------------------------------------------- callbacks
    def on_layers(self, msg: GridLayers) -> None:
        try:
            layers = map_layers_from_msg(msg)
        except InvalidInputError as err:
            rospy.logerr_throttle(5.0, f"feature_evaluator: ignoring bad layers: {err}")
            return
        with self._lock:
            self._layers = layers
            self._frame_id = msg.header.frame_id or "map"
        self.evaluate()

    def on_odom(self, msg: Odometry) -> None:
        x, y = msg.pose.pose.position.x, msg.pose.pose.position.y
        if math.isfinite(x) and math.isfinite(y):
            with self._lock:
                self._drone_xy = (x, y)

    def on_target(self, msg: SearchTarget) -> None:
        try:
            target = target_from_points(msg.points)
        except InvalidInputError as err:
            rospy.logerr(f"feature_evaluator: ignoring bad target: {err}")
            return
        with self._lock:
            self._target = target
        self.evaluate()

    def on_weights(self, msg: FeatureWeights) -> None:
        try:
            if len(msg.features) != len(msg.weights):
                text = f"{len(msg.features)} names but {len(msg.weights)} weights"
                raise InvalidInputError(text)
            weights = validate_weights(dict(zip(msg.features, msg.weights, strict=True)))
        except InvalidInputError as err:
            rospy.logerr(f"feature_evaluator: ignoring bad weights: {err}")
            return
        with self._lock:
            self._weights = weights
        self.evaluate()

    def on_timer(self, now_s: float) -> None:
        if now_s - self._last_eval_s >= 0.9 / self.config.rate_hz:
            self.evaluate()

    def on_get_features(self, _req: object) -> GetGridLayersResponse:
        with self._lock:
            if self._last_msg is None:
                text = "no features yet: waiting for /map_server/layers"
                raise rospy.ServiceException(text)
            return GetGridLayersResponse(layers=self._last_msg)

    # ---------------------------------------------------------------- work
    def evaluate(self) -> None:
        with self._lock:
            layers = self._layers
            if layers is None:
                return
            now_s = rospy.get_time()
            try:
                maps = self.core.evaluate(layers, now_s=now_s, drone_xy_m=self._drone_xy, target=self._target)
                score = weighted_score(maps.scored(), self._weights)
            except InvalidInputError as err:
                rospy.logerr_throttle(5.0, f"feature_evaluator: cannot evaluate: {err}")
                return
            self._last_eval_s = now_s
            out = {**maps.layers, "score": score}
            header = Header(stamp=rospy.Time.from_sec(now_s), frame_id=self._frame_id)
            msg = grid_layers_msg(maps.spec, out, header)
            self._last_msg = msg
        try:
            self.pub_features.publish(msg)
        except rospy.ROSException:
            if rospy.is_shutdown():
                return  # the node is going down: the topic closed under this publish
            raise
        if self._info_spec != maps.spec:
            self._info_spec = maps.spec
            self.pub_info.publish(map_meta_data(maps.spec, header.stamp))
        for name, (pub_raw, pub_color) in self.pub_images.items():
            if pub_raw.get_num_connections() > 0:
                pub_raw.publish(float_image_msg(out[name], header))
            if pub_color.get_num_connections() > 0:
                pub_color.publish(color_image_msg(out[name], header, unit_range=name in SCORED_FEATURES))


def main() -> None:
    run_participant("feature_evaluator", _build, lookahead_steps=LOOKAHEAD_STEPS, errors=(UavAutonomyError,))


def _build(ls: Participant) -> None:
    params = node_params(FeatureParams, "feature_evaluator")
    config = autonomy_section(FeatureConfig, "features", params.config, params.overrides)
    FeatureEvaluatorNode(config, params.image_ns, params.odom_topic).start(ls)
    rospy.loginfo(f"feature_evaluator: running ({config})")

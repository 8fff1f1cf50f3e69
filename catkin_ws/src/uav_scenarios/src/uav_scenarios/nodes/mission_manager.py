"""mission_manager: runs a scenario: starts the flight, confirms the person, stops the run.

ROS interface:

Subscribes:
    ``/uav/controller/state`` (uav_msgs/ControllerState), ``/uav/battery`` (sensor_msgs/BatteryState),
    ``/scenario/metrics`` (uav_msgs/RunMetrics: % mapped, collisions), ``/uav/sim_state`` (uav_msgs/SimState:
    crashed), ``/sim/collision`` (uav_msgs/Collision: one per contact, counted at once),
    ``/autonomy/goal`` (geometry_msgs/PointStamped), and for search and rescue the geolocated
    detections ``/geolocator/detections`` (uav_msgs/DetectionArray: the scenario's detector's boxes placed in
    map; frames of ``perception.camera`` only; detections below ``perception.score_threshold`` or without a
    position are counted, and the latter reported in ``/scenario/status`` ``detections_unplaced``).
Publishes:
    ``/scenario/config`` (std_msgs/String, latched): the scenario file's text, for the bag and the report.
    ``/scenario/status`` (uav_msgs/ScenarioStatus) at 2 Hz and on every change.
    ``/autonomy/target_point`` (geometry_msgs/PointStamped): the confirmed person (goal selector's target).
    ``/scenario/faults`` (uav_msgs/FaultEvent, latched queue): each scripted fault sent and the answer (the
    autopilot's, or the sim bridge's for a camera).
MAVLink (only when the scenario has autopilot ``faults``): over ``~autopilot_url`` (the router's TCP server) it
    sets ``SYS_FAILURE_EN`` to 1 at start and sends each fault as ``MAV_CMD_INJECT_FAILURE`` at its run time (and
    ``FAILURE_TYPE_OK`` ``duration_s`` later), as a test rig would (:mod:`uav_scenarios.shell.fault_link`).
Calls:
    ``<~controller>/set_state`` (uav_msgs/SetControllerState): AUTONOMOUS or SCRIPTED (pattern from the
    scenario) once the controller's link is up, HOLD staring at the person once confirmed.
    ``~camera_fault_service`` (uav_msgs/SetCameraFault, default ``/sim_bridge/set_camera_fault``): each camera
    fault (``unit: camera_nadir|camera_forward``) at its run time, and ``ok`` ``duration_s`` later
    (:mod:`uav_scenarios.ros.camera_faults`).
Parameters:
    ``~scenario`` (str, required); ``~controller`` (str, default ``/waypoint_controller``);
    ``~expect_mission`` (str, ""): refuse a scenario of another mission (``loiter.launch`` with a SAR file);
    ``~depth_source`` (str, ""): what the launch file started; must match the scenario's ``depth_source``;
    ``~detector`` (str, ""): the detector the launch file started; must match ``perception.detector``;
    ``~pose_source`` (str, ""): likewise for ``pose_source``;
    ``~autopilot_url`` (str, ""): pymavlink URL of the autopilot for scripted faults (a scenario with autopilot
    ``faults`` and no URL is refused); ``~camera_fault_service`` (str): see Calls;
    ``~wait_for_recorder`` (bool, false): the run starts only once ``/record`` (rosbag) subscribes to every
    recorded topic that has a publisher and is connected to each of them (both ends' ``getBusInfo`` list the
    link; in deterministic runs the bridge holds simulation time instead), so the bag holds the
    whole run (a replay needs it);
    ``~run/person`` (dict, from ``scenario_params``): the person of interest ``{name, instance_id, x_m, y_m}``;
    ``~shutdown_on_stop`` (bool, default true): exit once the scorer has published its final metrics
    (``"final": true`` in ``summary_json``), at least ``~linger_s`` (float, 1.0) and at most
    ``~max_linger_s`` (float, 30.0) wall seconds after a stop criterion is met (launch it
    ``required="true"`` so roslaunch ends the run). Any other private parameter stops the node (exit code 2).

Decisions are :mod:`uav_scenarios.core.mission`.

Causal lockstep (docs/lockstep.md): a participant with a lookahead of 2 steps; its service calls apply at the
step boundary the protocol names, its scripted faults go out from the step (the autopilot's over a lockstep
MAVLink client, the cameras' as calls to the bridge). Only the wall-clock guard (``stop.wall_timeout_s``) and the
linger before shutting down read the wall clock.
"""

from __future__ import annotations

import math
import time
from collections import deque
from pathlib import Path
from typing import Any

import rospy
from geometry_msgs.msg import Point, PointStamped
from sensor_msgs.msg import BatteryState
from std_msgs.msg import Header, String

from uav_common.ros.graph import bus_info_over_xmlrpc, node_uri_lookup, unconnected_subscriptions
from uav_common.ros.lockstep import Participant
from uav_common.ros.node import run_participant
from uav_common.ros.params import node_params
from uav_msgs.msg import Collision, ControllerState, DetectionArray, FaultEvent, RunMetrics, ScenarioStatus, SimState
from uav_msgs.srv import SetCameraFault, SetCameraFaultRequest, SetControllerState, SetControllerStateRequest
from uav_scenarios.core.config import (
    GEOLOCATED_TOPIC,
    MissionKind,
    Scenario,
    Strategy,
    load_scenario,
    recorded_topics,
)
from uav_scenarios.core.faults import FaultSchedule, camera_name, fault_actions
from uav_scenarios.core.mission import (
    ConfirmationGate,
    Phase,
    StopReason,
    check_stop,
    controller_state_for,
    flying_phase,
    resume_needed,
)
from uav_scenarios.core.params import needs_terrain, scripted_request
from uav_scenarios.errors import ScenarioConfigError, ScenarioError
from uav_scenarios.ros.camera_faults import CameraFaultCaller
from uav_scenarios.ros.messages import status_msg
from uav_scenarios.ros.params import MissionManagerParams
from uav_scenarios.ros.records import detections_from_msg
from uav_scenarios.shell.fault_link import FaultLink, FaultResult, StepFaultLink
from uav_scenarios.shell.world_store import load_world

FLYING = ("AUTONOMOUS", "SCRIPTED", "HOLD", "MANUAL")
#: The node name of the scenario's ``rosbag record`` (scenario_common.launch).
RECORDER = "/record"
#: Steps between its inputs and when its outputs are consumed, in the causal lockstep (docs/lockstep.md).
LOOKAHEAD_STEPS = 2
#: Simulated seconds between two resumes of a controller that yielded in the air.
RESUME_INTERVAL_S = 3.0


class MissionManager:
    def __init__(
        self,
        scenario: Scenario,
        controller_ns: str,
        *,
        shutdown_on_stop: bool,
        linger_s: float,
        max_linger_s: float = 30.0,
        person_instance_id: int = 0,
        person_xy: tuple[float, float] | None = None,
        scripted: dict[str, Any] | None = None,
    ) -> None:
        self.scenario = scenario
        self.scripted = scripted  # the baseline's request planned at launch (over the terrain), if any
        self.controller_ns = controller_ns.rstrip("/")
        self.shutdown_on_stop = shutdown_on_stop
        self.linger_s = linger_s
        self.max_linger_s = max_linger_s
        self.scorer_final = False
        search = scenario.search
        self.gate = (
            ConfirmationGate(
                search.confirm_detections,
                search.confirm_window_s,
                instance_id=person_instance_id,
                min_score=scenario.perception.score_threshold,
                area=search.area_m,
                verify_xy=person_xy if search.verify == "operator" else None,
            )
            if scenario.mission is MissionKind.SEARCH_AND_RESCUE and search is not None
            else None
        )
        self.phase = Phase.STARTING
        self.start_sim_s: float | None = None
        self.start_wall_s = time.monotonic()
        self.controller: ControllerState | None = None
        self.battery_pct = math.nan
        self.mapped_pct = math.nan
        self.collisions = 0
        self.contacts = 0  # /sim/collision messages
        self.crashed = False
        self.goal: tuple[float, float, float] | None = None
        self.found_at_s: float | None = None
        self.person: tuple[float, float, float] | None = None
        self.stop_reason: StopReason | None = None
        self.stop_wall_s: float | None = None
        self.flight_requested = False
        self.hold_requested = False
        self.wait_for_recorder = False
        self.resumes = 0
        self.max_resumes = 10
        self.last_resume_s = -math.inf
        self.rtf_window: deque[tuple[float, float]] = deque(maxlen=20)
        self.status_pub: rospy.Publisher | None = None
        self.target_pub: rospy.Publisher | None = None
        self.fault_pub: rospy.Publisher | None = None
        self.fault_link: FaultLink | None = None
        self.camera_faults: CameraFaultCaller | None = None

    def start(self, ls: Participant) -> None:
        self.ls = ls
        config_pub = ls.publisher("/scenario/config", String, queue_size=1, latch=True)
        assert self.scenario.source is not None
        config_pub.publish(String(data=self.scenario.source.read_text()))
        self.status_pub = ls.publisher("/scenario/status", ScenarioStatus, queue_size=10, latch=True)
        self.target_pub = ls.publisher("/autonomy/target_point", PointStamped, queue_size=1, latch=True)
        ls.subscribe("/uav/controller/state", ControllerState, self.on_controller, queue_size=10)
        ls.subscribe("/uav/battery", BatteryState, self.on_battery, queue_size=10)
        ls.subscribe("/scenario/metrics", RunMetrics, self.on_metrics, queue_size=5)
        ls.subscribe("/uav/sim_state", SimState, self.on_sim_state, queue_size=10)
        # collisions from the simulator itself (one message per contact), not through the scorer's metrics: the
        # scorer may lag (a lookahead of 50 steps in the causal lockstep), a collision stop must not
        ls.subscribe("/sim/collision", Collision, self.on_collision, queue_size=10)
        ls.subscribe("/autonomy/goal", PointStamped, self.on_goal, queue_size=5)
        if self.gate is not None and self.scenario.search is not None:
            ls.subscribe(GEOLOCATED_TOPIC, DetectionArray, self.on_detections, queue_size=20)
        ls.timer(0.5, self.on_tick, name="mission")

    def start_faults(self, autopilot_url: str, camera_fault_service: str) -> None:
        """Send the scenario's faults at their run times: the autopilot's over MAVLink (from a thread of the fault
        link's), the cameras' to the sim bridge (from a thread of the camera fault caller's)."""
        if not self.scenario.faults:
            return
        self.fault_pub = self.ls.publisher("/scenario/faults", FaultEvent, queue_size=20, latch=True)
        actions = fault_actions(self.scenario.faults)
        autopilot = [a for a in actions if not a.camera]
        cameras = [a for a in actions if a.camera]

        def elapsed() -> float | None:
            return None if self.start_sim_s is None else rospy.get_time() - self.start_sim_s

        if autopilot and self.ls.causal:
            step_link = StepFaultLink(
                autopilot_url,
                FaultSchedule(autopilot),
                elapsed_s=elapsed,
                now_s=rospy.get_time,
                on_result=self.on_fault_result,
                lookahead_steps=self.ls.settings.lookahead_steps,
                watchdog_s=self.ls.settings.watchdog_s,
                should_stop=rospy.is_shutdown,
            )
            step_link.start()
            self.ls.around_step(before=step_link.before_step, after=step_link.after_step)
            rospy.on_shutdown(step_link.stop)
            rospy.loginfo(f"mission_manager: {len(autopilot)} scripted autopilot fault action(s), over {autopilot_url}")
        elif autopilot:
            self.fault_link = FaultLink(
                autopilot_url,
                FaultSchedule(autopilot),
                elapsed_s=elapsed,
                now_s=rospy.get_time,
                on_result=self.on_fault_result,
            )
            self.fault_link.start()
            rospy.on_shutdown(self.fault_link.stop)
            rospy.loginfo(f"mission_manager: {len(autopilot)} scripted autopilot fault action(s), over {autopilot_url}")
        if cameras:
            self.camera_faults = CameraFaultCaller(
                camera_fault_service,
                FaultSchedule(cameras),
                elapsed_s=elapsed,
                now_s=rospy.get_time,
                on_result=self.on_fault_result,
            )
            if self.ls.causal:
                caller = self.camera_faults

                def call(camera: str, failure_type: str) -> Any:
                    request = SetCameraFaultRequest(camera=camera, type=failure_type)
                    return self.ls.call(camera_fault_service, SetCameraFault, request, wait_s=60.0)

                self.ls.on_step(lambda _step, _now: caller.send_due(call))
            else:
                self.camera_faults.start()
                rospy.on_shutdown(self.camera_faults.stop)
            rospy.loginfo(f"mission_manager: {len(cameras)} camera fault action(s), to {camera_fault_service}")

    def on_fault_result(self, r: FaultResult) -> None:
        a = r.action
        log = rospy.loginfo if r.result == "ACCEPTED" else rospy.logerr
        run_s = r.sent_s - self.start_sim_s if self.start_sim_s is not None else math.nan
        log(
            f"mission_manager: fault {a.label} (due at {a.at_s:g} s) sent at {run_s:.2f} s: {r.result}"
            + (f" ({r.detail})" if r.detail else "")
        )
        if self.fault_pub is None:
            return
        msg = FaultEvent(
            header=Header(stamp=rospy.Time.from_sec(r.sent_s), frame_id=""),
            index=a.index,
            at_s=a.at_s,
            unit=a.unit,
            type=a.failure_type,
            instance=a.instance,
            clear=a.clear,
            result=r.result,
            detail=r.detail,
            answered_s=r.answered_s,
        )
        self.fault_pub.publish(msg)

    # ---- inputs ----------------------------------------------------------------------------

    def on_controller(self, msg: ControllerState) -> None:
        self.controller = msg

    def on_battery(self, msg: BatteryState) -> None:
        self.battery_pct = 100.0 * msg.percentage if math.isfinite(msg.percentage) else math.nan

    def on_metrics(self, msg: RunMetrics) -> None:
        self.mapped_pct = msg.mapped_pct
        self.collisions = max(self.collisions, msg.collisions)
        if self.stop_reason is not None and '"final": true' in msg.summary_json:
            self.scorer_final = True

    def on_collision(self, _msg: Collision) -> None:
        self.contacts += 1
        self.collisions = max(self.collisions, self.contacts)

    def on_sim_state(self, msg: SimState) -> None:
        self.crashed = self.crashed or msg.crashed

    def on_goal(self, msg: PointStamped) -> None:
        self.goal = (msg.point.x, msg.point.y, msg.point.z)

    def on_detections(self, msg: DetectionArray) -> None:
        if self.gate is None or self.scenario.search is None:
            return
        frame = detections_from_msg(msg)
        if frame.camera != self.scenario.perception.camera or self.found_at_s is not None or self.start_sim_s is None:
            return
        unplaced = self.gate.unplaced
        rejected = len(self.gate.rejections)
        found = self.gate.update(frame.t_s, frame.detections)
        for candidate in self.gate.rejections[rejected:]:
            rospy.logwarn(
                f"mission_manager: candidate at {tuple(round(v, 1) for v in candidate.position_m)} after "
                f"{candidate.detections} detections is not the person searched for (operator check); searching on"
            )
        if self.gate.unplaced > unplaced:
            rospy.logwarn_throttle(
                30.0,
                f"mission_manager: {self.gate.unplaced} {self.gate.class_name} detections so far had no position "
                "(the geolocator could not place them) and cannot confirm anyone",
            )
        if found is None:
            return
        self.found_at_s = found.t_s
        self.person = found.position_m
        gate = self.gate
        rospy.loginfo(
            f"mission_manager: person confirmed at {found.position_m} after {found.detections} detections "
            f"(not used: {gate.unplaced} unplaced, {gate.below_threshold} below the threshold, "
            f"{gate.too_uncertain} too uncertain, {gate.outside_area} outside the search area)"
        )
        if self.target_pub is not None:
            self.target_pub.publish(
                PointStamped(header=Header(stamp=msg.header.stamp, frame_id="map"), point=Point(*found.position_m))
            )
        self.phase = Phase.HOLDING
        self._request_hold()

    # ---- actions ---------------------------------------------------------------------------

    def _call(self, request: SetControllerStateRequest) -> bool:
        service = f"{self.controller_ns}/set_state"
        try:
            response = self.ls.call(service, SetControllerState, request, wait_s=2.0)
        except (rospy.ROSException, rospy.ServiceException) as err:
            rospy.logwarn_throttle(10.0, f"mission_manager: {service} failed: {err}")
            return False
        if not response.success:
            rospy.logwarn_throttle(10.0, f"mission_manager: {request.state} refused: {response.message}")
        return bool(response.success)

    def _request_flight(self) -> None:
        if self.scenario.strategy is Strategy.AUTONOMOUS:
            req = SetControllerStateRequest(state=controller_state_for(self.scenario))
        else:
            try:
                spec = self.scripted or scripted_request(self.scenario)
            except ScenarioError as err:
                rospy.logerr_throttle(10.0, f"mission_manager: no scripted pattern: {err}")
                return
            req = SetControllerStateRequest(
                state=spec["state"],
                pattern=spec["pattern"],
                points=[Point(*p) for p in spec["points"]],
                spacing_m=spec["spacing_m"],
                altitude_m=spec["altitude_m"],
                max_radius_m=spec["max_radius_m"],
            )
        self.flight_requested = self._call(req)

    def _request_hold(self) -> None:
        assert self.person is not None
        self.hold_requested = self._call(SetControllerStateRequest(state="HOLD", points=[Point(*self.person)]))

    def on_tick(self, now: float) -> None:
        if now <= 0:
            return
        if self.start_sim_s is None:
            if self.wait_for_recorder and not self._recorder_listening():
                rospy.loginfo_throttle(10.0, "mission_manager: waiting for rosbag record before starting the run")
                return
            self.start_sim_s = now
        self.rtf_window.append((time.monotonic(), now))
        ctrl = self.controller
        if self.stop_reason is None:
            if ctrl is not None and ctrl.link_ok and not self.flight_requested and self.phase is Phase.STARTING:
                self._request_flight()
                if self.flight_requested:
                    self.phase = Phase.TAKEOFF
            if self.phase is Phase.TAKEOFF and ctrl is not None and ctrl.state in FLYING:
                self.phase = flying_phase(self.scenario)
            if self.person is not None and not self.hold_requested:
                self._request_hold()
            self._resume_if_yielded(ctrl, now)
            self.stop_reason = check_stop(
                self.scenario.stop,
                elapsed_s=now - self.start_sim_s,
                mapped_pct=self.mapped_pct,
                battery_pct=self.battery_pct,
                collisions=self.collisions,
                crashed=self.crashed,
                found_for_s=now - self.found_at_s if self.found_at_s is not None else None,
                wall_elapsed_s=time.monotonic() - self.start_wall_s,
            )
            if self.stop_reason is not None:
                rospy.loginfo(f"mission_manager: stop ({self.stop_reason.value}) at {now - self.start_sim_s:.1f} s")
                self.phase = (
                    Phase.FAILED if self.stop_reason in (StopReason.CRASHED, StopReason.COLLISION) else Phase.DONE
                )
                self.stop_wall_s = time.monotonic()
        self._publish(now)
        if self.stop_wall_s is not None and self.shutdown_on_stop:
            waited = time.monotonic() - self.stop_wall_s
            if (self.scorer_final and waited >= self.linger_s) or waited >= self.max_linger_s:
                if not self.scorer_final:
                    rospy.logwarn(f"mission_manager: no final metrics from the scorer after {waited:.0f} s; ending")
                rospy.signal_shutdown(f"scenario stopped: {self.stop_reason.value if self.stop_reason else ''}")

    def _recorder_listening(self) -> bool:
        """Is ``/record`` (rosbag) subscribed to every recorded topic that has a publisher, and connected to
        each publisher? Then the bag holds the run from its first message (a replay needs that)."""
        import rosgraph  # noqa: PLC0415

        master = rosgraph.Master(rospy.get_name())
        try:
            pubs, subs, _srvs = master.getSystemState()
        except (rosgraph.MasterError, OSError):
            return False
        published = {topic for topic, _nodes in pubs}
        recording = {topic for topic, nodes in subs if RECORDER in nodes}
        wanted = set(recorded_topics(self.scenario)) & published
        if "/scenario/status" not in recording or not wanted <= recording:
            return False
        if self.scenario.time.deterministic:
            # The bridge starts simulation time only once /record is up and grants each step only when the
            # run is idle; asking the nodes here would make the start step depend on the machine.
            return True

        uri = node_uri_lookup(master.lookupNode)
        # Subscribed is not connected: each publisher is connected to a moment later (seconds, on a busy machine).
        unconnected = unconnected_subscriptions(
            pubs,
            subs,
            subscriber_nodes={RECORDER},
            topics=wanted,
            bus_info=bus_info_over_xmlrpc(rospy.get_name(), uri),
            node_uri=uri,
        )
        if unconnected:
            rospy.loginfo_throttle(10.0, f"mission_manager: rosbag record not yet connected: {unconnected[:3]}")
        return not unconnected

    def _resume_if_yielded(self, ctrl: ControllerState | None, now: float) -> None:
        if ctrl is None or not resume_needed(
            self.phase, ctrl.state, in_air=ctrl.in_air, link_ok=ctrl.link_ok, autopilot_mode=ctrl.autopilot_mode
        ):
            return
        if self.resumes >= self.max_resumes or now - self.last_resume_s < RESUME_INTERVAL_S:
            return
        self.resumes += 1
        self.last_resume_s = now
        rospy.logwarn(
            f"mission_manager: the controller yielded in the air ({ctrl.last_event!r}); "
            f"resuming the mission ({self.resumes}/{self.max_resumes})"
        )
        if self.phase is Phase.HOLDING and self.person is not None:
            self._request_hold()
        else:
            self._request_flight()

    def _rtf(self) -> float:
        if len(self.rtf_window) < 2:
            return math.nan
        (w0, s0), (w1, s1) = self.rtf_window[0], self.rtf_window[-1]
        return (s1 - s0) / (w1 - w0) if w1 > w0 else math.nan

    def _publish(self, now: float) -> None:
        if self.status_pub is None or self.start_sim_s is None:
            return
        ctrl = self.controller
        fields = {
            "scenario": self.scenario.name,
            "mission": self.scenario.mission.value,
            "strategy": self.scenario.strategy.value,
            "phase": self.phase.value,
            "sim_time_s": now - self.start_sim_s,
            "real_time_factor": self._rtf(),
            "mapped_pct": self.mapped_pct,
            "battery_pct": self.battery_pct,
            "controller_state": ctrl.state if ctrl else "",
            "autopilot_mode": ctrl.autopilot_mode if ctrl else "",
            "goal": self.goal,
            "target_found": self.person is not None,
            "target_position": self.person,
            "detections_unplaced": self.gate.unplaced if self.gate is not None else 0,
            "candidates_rejected": len(self.gate.rejections) if self.gate is not None else 0,
            "complete_time_s": self.found_at_s - self.start_sim_s if self.found_at_s is not None else math.nan,
            "stop": self.stop_reason is not None,
            "stop_reason": self.stop_reason.value if self.stop_reason else "",
        }
        self.status_pub.publish(status_msg(rospy.Time.from_sec(now), fields))


def launch_mismatch(
    scenario: Scenario, expect_mission: str, depth_source: str, pose_source: str = "", detector: str = ""
) -> str:
    """Why the launch file and the scenario disagree ("" when they agree)."""
    if detector and detector != scenario.perception.detector.value:
        return (
            f"{scenario.source} says perception.detector: {scenario.perception.detector.value} but the launch started "
            f"detector:={detector}; pass detector:={scenario.perception.detector.value} (uav-run does)"
        )
    if expect_mission and expect_mission != scenario.mission.value:
        return (
            f"{scenario.source} is a {scenario.mission.value} scenario but this is {expect_mission}.launch; "
            f"use {scenario.mission.value}.launch (or uav-run, which picks it)"
        )
    if depth_source and depth_source != scenario.depth_source.value:
        return (
            f"{scenario.source} says depth_source: {scenario.depth_source.value} but the launch started "
            f"depth_source:={depth_source}; pass depth_source:={scenario.depth_source.value} (uav-run does)"
        )
    if pose_source and pose_source != scenario.pose_source.value:
        return (
            f"{scenario.source} says pose_source: {scenario.pose_source.value} but the launch started "
            f"pose_source:={pose_source}; pass pose_source:={scenario.pose_source.value} (uav-run does)"
        )
    return ""


def main() -> None:
    run_participant("mission_manager", _build, lookahead_steps=LOOKAHEAD_STEPS, errors=(ScenarioError,))


def _build(ls: Participant) -> None:
    params = node_params(MissionManagerParams, "mission_manager")
    scenario = load_scenario(Path(params.scenario))
    problem = launch_mismatch(scenario, params.expect_mission, params.depth_source, params.pose_source, params.detector)
    if problem:
        raise ScenarioConfigError(problem)
    scripted = params.run.scripted
    if scripted is None and needs_terrain(scenario):
        # Started without the launch files' run settings: plan the baseline over the world's terrain here.
        scripted = scripted_request(scenario, load_world(scenario).height_at)
    node = MissionManager(
        scenario,
        params.controller,
        shutdown_on_stop=params.shutdown_on_stop,
        linger_s=params.linger_s,
        max_linger_s=params.max_linger_s,
        person_instance_id=int(params.run.person.get("instance_id", 0)),
        person_xy=(float(person["x_m"]), float(person["y_m"])) if (person := params.run.person) else None,
        scripted=scripted,
    )
    node.wait_for_recorder = params.wait_for_recorder
    if any(not camera_name(f.unit) for f in scenario.faults) and not params.autopilot_url:
        msg = (
            f"{scenario.source} scripts autopilot faults but ~autopilot_url is empty: the mission manager sends "
            "them over MAVLink (scenario_common.launch sets it to the router's TCP server)"
        )
        raise ScenarioConfigError(msg)
    node.start(ls)
    node.start_faults(params.autopilot_url, params.camera_fault_service)

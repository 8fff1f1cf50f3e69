#!/usr/bin/env python3
"""ROS side of the autonomy e2e tests, in its own process (one rospy node per process and roscore).

Usage: autonomy_e2e_ros_client.py <listen_udp_port> <report_udp_port>

Commands arrive as JSON datagrams on ``listen_udp_port``; everything the test needs to see goes back as
JSON datagrams to ``report_udp_port`` on localhost:

* ``{"cmd": "set_state", "id": n, "state": "TAKEOFF", "points": [[x, y, z], ...]}`` ->
  ``{"type": "reply", "id": n, "success": b, "message": s, "state": s}``
* ``{"cmd": "goal", "x": x, "y": y}`` publishes ``/autonomy/goal`` (geometry_msgs/PointStamped, map)
* ``{"cmd": "manual", "x": x, "y": y, "z": z}`` publishes ``/waypoint_controller/manual_setpoint``
* ``/uav/controller/state`` -> ``{"type": "state", ...}``; ``/autonomy/path`` -> ``{"type": "path", "points": ...}``
"""

from __future__ import annotations

import json
import socket
import sys
import threading

import rospy
from geometry_msgs.msg import Point, PointStamped, PoseStamped
from nav_msgs.msg import Path

from uav_msgs.msg import ControllerState
from uav_msgs.srv import SetControllerState


def main() -> None:
    listen_port, report_port = int(sys.argv[1]), int(sys.argv[2])
    rospy.init_node("autonomy_e2e_client", disable_signals=True)
    out = socket.socket(socket.AF_INET, socket.SOCK_DGRAM)
    lock = threading.Lock()

    def report(payload: dict[str, object]) -> None:
        with lock:
            out.sendto(json.dumps(payload).encode(), ("127.0.0.1", report_port))

    def on_state(msg: ControllerState) -> None:
        report({
            "type": "state", "state": msg.state, "autopilot_mode": msg.autopilot_mode, "armed": msg.armed,
            "in_air": msg.in_air, "link_ok": msg.link_ok, "last_event": msg.last_event,
        })  # fmt: skip

    def on_path(msg: Path) -> None:
        pts = [[p.pose.position.x, p.pose.position.y, p.pose.position.z] for p in msg.poses]
        report({"type": "path", "points": pts})

    rospy.Subscriber("/uav/controller/state", ControllerState, on_state, queue_size=50)
    rospy.Subscriber("/autonomy/path", Path, on_path, queue_size=10)
    pub_goal = rospy.Publisher("/autonomy/goal", PointStamped, queue_size=1, latch=True)
    pub_manual = rospy.Publisher("/waypoint_controller/manual_setpoint", PoseStamped, queue_size=1)
    rospy.wait_for_service("/waypoint_controller/set_state", timeout=60.0)
    set_state = rospy.ServiceProxy("/waypoint_controller/set_state", SetControllerState)
    sock = socket.socket(socket.AF_INET, socket.SOCK_DGRAM)
    sock.bind(("127.0.0.1", listen_port))
    sock.settimeout(0.2)
    report({"type": "ready"})
    while not rospy.is_shutdown():
        try:
            data, _ = sock.recvfrom(65536)
        except TimeoutError:
            continue
        cmd = json.loads(data)
        kind = cmd["cmd"]
        if kind == "set_state":
            pts = [Point(*p) for p in cmd.get("points", [])]
            try:
                res = set_state(state=cmd["state"], points=pts)
                report({"type": "reply", "id": cmd["id"], "success": res.success, "message": res.message,
                        "state": res.state})  # fmt: skip
            except rospy.ServiceException as err:
                report({"type": "reply", "id": cmd["id"], "success": False, "message": str(err), "state": ""})
        elif kind == "goal":
            goal = PointStamped()
            goal.header.stamp = rospy.Time.now()
            goal.header.frame_id = "map"
            goal.point = Point(cmd["x"], cmd["y"], 0.0)
            pub_goal.publish(goal)
        elif kind == "manual":
            sp = PoseStamped()
            sp.header.stamp = rospy.Time.now()
            sp.header.frame_id = "map"
            sp.pose.position = Point(cmd["x"], cmd["y"], cmd["z"])
            sp.pose.orientation.w = 1.0
            pub_manual.publish(sp)
        report({"type": "done", "cmd": kind})


if __name__ == "__main__":
    main()

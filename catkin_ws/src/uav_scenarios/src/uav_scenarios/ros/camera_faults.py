"""A scenario's camera faults, sent to the sim bridge: the range's own faults (MAVLink has no FAILURE_UNIT for a
payload camera), so they go to the simulator's cameras, ``/sim_bridge/set_camera_fault`` (uav_msgs/SetCameraFault),
instead of the autopilot.

As :class:`uav_scenarios.shell.fault_link.FaultLink` does for the autopilot's faults: one thread hands out each
action when the run's elapsed simulation time reaches it and reports the bridge's answer (``ACCEPTED`` with the
simulation time it applies after, or ``DENIED`` and why) as a :class:`~uav_scenarios.shell.fault_link.FaultResult`;
a bridge that never offers the service makes every action ``NOT_SENT``, a call that fails ``NO_ANSWER``.

Time: the schedule is on ROS time (simulated seconds); the bridge applies a fault from the next state it
processes, so in lockstep a fault lands within a step or two of its time (its ``answered_s`` says when). In the
causal lockstep there is no thread: the mission manager calls :meth:`CameraFaultCaller.send_due` from its step,
and the call is applied at the step boundary the protocol names (docs/lockstep.md), the same in every run.
"""

from __future__ import annotations

import math
import threading
import time
from collections.abc import Callable
from typing import Any

import rospy

from uav_msgs.srv import SetCameraFault
from uav_scenarios.core.faults import FaultAction, FaultSchedule
from uav_scenarios.shell.fault_link import FaultResult

__all__ = ["DEFAULT_SERVICE", "CameraFaultCaller"]

DEFAULT_SERVICE = "/sim_bridge/set_camera_fault"
#: How long (wall seconds) the caller waits for the bridge's service before giving the faults up.
SERVICE_WAIT_S = 60.0


class CameraFaultCaller:
    """Sends camera faults to the sim bridge from a thread of its own.

    Args:
        service: the bridge's ``set_camera_fault`` service.
        schedule: the camera actions (:attr:`FaultAction.camera` set).
        elapsed_s: the run's elapsed time (ROS time), ``None`` before the mission started.
        now_s: ROS time (stamps of the results).
        on_result: called (from the caller's thread) with each action's result.
    """

    def __init__(
        self,
        service: str,
        schedule: FaultSchedule,
        *,
        elapsed_s: Callable[[], float | None],
        now_s: Callable[[], float],
        on_result: Callable[[FaultResult], None],
    ) -> None:
        self.service = service
        self.schedule = schedule
        self.elapsed_s = elapsed_s
        self.now_s = now_s
        self.on_result = on_result
        self.problem = ""
        self._stop = threading.Event()
        self._proxy: rospy.ServiceProxy | None = None
        self._thread = threading.Thread(target=self._run, name="camera-faults", daemon=True)

    def start(self) -> None:
        self._thread.start()

    def send_due(self, call: Callable[[str, Any], Any]) -> None:
        """Causal lockstep: send the actions due at the run's elapsed time now, from the caller's step, through
        ``call(camera, type)`` (the participant's service call, which names the step boundary)."""
        elapsed = self.elapsed_s()
        if elapsed is None:
            return
        for action in self.schedule.due(elapsed):
            sent_s = self.now_s()
            try:
                resp = call(action.camera, action.failure_type)
            except (rospy.ServiceException, rospy.ROSException) as err:
                self.on_result(FaultResult(action, sent_s, "NO_ANSWER", f"{self.service}: {err}"))
                continue
            self.on_result(FaultResult(action, sent_s, str(resp.result), str(resp.detail), float(resp.applied_s)))

    def stop(self) -> None:
        self._stop.set()
        self._thread.join(timeout=5.0)

    def _run(self) -> None:
        self._connect()
        while not self._stop.is_set() and self.schedule.next_at_s is not None:
            elapsed = self.elapsed_s()
            if elapsed is not None:
                for action in self.schedule.due(elapsed):
                    self._send(action)
            self._stop.wait(0.005)
        for action in self.schedule.due(math.inf):
            self.on_result(FaultResult(action, self.now_s(), "NOT_SENT", self.problem or "the run ended first"))

    def _connect(self) -> None:
        deadline = time.monotonic() + SERVICE_WAIT_S
        while not self._stop.is_set():
            try:
                rospy.wait_for_service(self.service, timeout=1.0)
            except rospy.ROSException:
                if time.monotonic() > deadline:
                    self.problem = f"the sim bridge offers no {self.service} (waited {SERVICE_WAIT_S:.0f} s)"
                    return
                continue
            except rospy.ROSInterruptException:
                return
            self._proxy = rospy.ServiceProxy(self.service, SetCameraFault)
            return

    def _send(self, action: FaultAction) -> None:
        sent_s = self.now_s()
        if self._proxy is None:
            self.on_result(FaultResult(action, sent_s, "NOT_SENT", self.problem or f"no {self.service}"))
            return
        try:
            resp = self._proxy(camera=action.camera, type=action.failure_type)
        except (rospy.ServiceException, rospy.ROSException) as err:
            self.on_result(FaultResult(action, sent_s, "NO_ANSWER", f"{self.service}: {err}"))
            return
        self.on_result(FaultResult(action, sent_s, str(resp.result), str(resp.detail), float(resp.applied_s)))

"""A /clock publisher for rostest check nodes that play the simulator (50 Hz of simulation time per wall 50 Hz)."""

from __future__ import annotations

import threading
import time

import rospy
from rosgraph_msgs.msg import Clock


class SimClock:
    """Publishes ``/clock`` from ``start_s`` in ``step_s`` steps, one per ``step_s`` of wall time, on a thread.

    Call after ``rospy.init_node``; :meth:`stop` ends the thread.
    """

    def __init__(self, start_s: float, step_s: float = 0.02) -> None:
        self.now_s = start_s
        self.step_s = step_s
        self._pub = rospy.Publisher("/clock", Clock, queue_size=1)
        self._stop = threading.Event()
        self._thread = threading.Thread(target=self._run, name="sim-clock", daemon=True)
        self._thread.start()

    def _run(self) -> None:
        while not self._stop.is_set():
            try:
                self._pub.publish(Clock(clock=rospy.Time.from_sec(self.now_s)))
            except rospy.ROSException:
                if rospy.is_shutdown():  # the node shut down before stop(): rospy closed the topic
                    return
                raise
            self.now_s += self.step_s
            time.sleep(self.step_s)

    def stop(self) -> None:
        self._stop.set()

#!/usr/bin/env python3

"""rostest node: the step master of docs/lockstep.md over two real participants (lockstep_echo.py).

The master publishes one counted message a step and ticks, as fast as the barrier lets it, with random pauses
in between; each participant reports what it consumed at each step. What a participant consumes at step k must
be exactly what the protocol says, whatever the timing: the master's data of step k, its peer's report of step
k - L_peer (/a has a lookahead of 1, /b of 2), its 0.25 s timer at the steps whose time first reaches each due
time, and a service call /b makes in its step 10 applied at /a's boundary 10 + L_b - 1 = 11 | 12. Then a message
the tick counts but that never comes: the participant waiting for it reports an error naming the topic after the
watchdog, and the master stops.
"""

from __future__ import annotations

import random
import sys
import time
import unittest
from pathlib import Path

HERE = Path(__file__).resolve().parent
sys.path[:0] = [str(HERE.parents[1])]

import rospy  # noqa: E402
import rostest  # noqa: E402
from std_msgs.msg import Int64, String  # noqa: E402

from uav_common.lockstep.protocol import LockstepError  # noqa: E402
from uav_common.ros.lockstep import StepMaster  # noqa: E402

STEPS = 60
STEP_S = 0.1


def _published() -> dict[int, list[int]]:
    """What the master published at each step: the test's draws from random.Random(1), replayed."""
    rng = random.Random(1)
    published = {}
    for k in range(1, STEPS + 1):
        n = rng.randint(1, 2)
        published[k] = [100 * k + i for i in range(n)]
        for _ in range(n):
            rng.uniform(0.0, 0.002)
    return published


class LockstepProtocol(unittest.TestCase):
    def test_participants_consume_exactly_what_the_protocol_says(self) -> None:
        rospy.init_node("master")
        seen: dict[str, dict[int, str]] = {"/a": {}, "/b": {}}

        def record(msg: String, name: str) -> None:
            seen[name][int(msg.data.split()[0])] = msg.data

        for name in seen:
            rospy.Subscriber(f"{name}/seen", String, record, callback_args=name)
        master = StepMaster(step_s=STEP_S, expected=["/a", "/b"])
        data = master.publisher("/master/data", Int64)
        rng = random.Random(1)
        deadline = time.monotonic() + 60.0
        while not master.try_start():
            self.assertLess(time.monotonic(), deadline, "the participants never joined")
            time.sleep(0.05)
        for k in range(1, STEPS + 1):
            while not master.can_grant():
                master.check_watchdog()
                time.sleep(0.0002)
            for i in range(rng.randint(1, 2)):
                data.publish(Int64(data=100 * k + i))
                time.sleep(rng.uniform(0.0, 0.002))
            master.publish_tick(STEP_S * k)
        wait = time.monotonic() + 20.0
        while min(len(seen["/a"]), len(seen["/b"])) < STEPS and time.monotonic() < wait:
            time.sleep(0.05)
        published = _published()
        timer_steps = {3, 5, 8, 10, 13, 15, 18, 20, 23, 25, 28, 30, 33, 35, 38, 40, 43, 45, 48, 50, 53, 55, 58, 60}
        for k in range(1, STEPS + 1):
            from_b = [str(k - 2)] if k > 2 else []  # /b's lookahead is 2: its report of step k - 2
            from_a = [str(k - 1)] if k > 1 else []  # /a's is 1
            # /b calls /a's poke in its step 10: applied at /a's boundary 10 + L_b - 1 = 11 | 12
            poked = 11 if k == 12 else -1
            timer = int(k in timer_steps)
            expect_a = f"{k} data={published[k]} peer={from_b!r} timer={timer} poked={poked}"
            expect_b = f"{k} data={published[k]} peer={from_a!r} timer={timer} poked=-1"
            self.assertEqual(seen["/a"].get(k), expect_a, f"what /a consumed at step {k}")
            self.assertEqual(seen["/b"].get(k), expect_b, f"what /b consumed at step {k}")
        self._a_missing_message_stops_the_run(master, sum(len(v) for v in published.values()))

    def _a_missing_message_stops_the_run(self, master: StepMaster, total: int) -> None:
        """A message the tick counts but nobody sent: the participants wait, report it, and the master stops."""
        master.count(rospy.resolve_name("/master/data"))
        while not master.can_grant():
            time.sleep(0.001)
        master.publish_tick(STEP_S * (STEPS + 1))
        with self.assertRaises(LockstepError) as err:
            end = time.monotonic() + 30.0
            while time.monotonic() < end:
                if master.can_grant():
                    self.fail("step granted although a participant never got its input")
                master.check_watchdog()
                time.sleep(0.05)
        text = str(err.exception)
        for name in ("/a", "/b"):
            self.assertIn(
                f"{name} at step {STEPS + 1}: step {STEPS + 1}: inputs never arrived: "
                f"/master/data from {rospy.get_name()} ({total} of {total + 1})",
                text,
            )


if __name__ == "__main__":
    rostest.rosrun("uav_rostests", "lockstep_check", LockstepProtocol)

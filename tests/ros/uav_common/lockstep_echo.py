#!/usr/bin/env python3

"""rostest participant of the causal lockstep (uav_common.ros.lockstep.Participant): what it consumed, step by step.

Each step it publishes (counted) one line ``"<step> data=<the master's data> peer=<the peer's lines> timer=<0|1>
poked=<boundary or -1>"`` on ``~seen``. It subscribes to the master's ``/master/data`` and its peer's ``seen``;
``~poke_peer_at`` (int, 0 = never) makes it call the peer's ``~poke`` in that step. It sleeps a random few
milliseconds in every step and callback, so the order things arrive in differs from run to run.
"""

from __future__ import annotations

import random
import time

import rospy
from std_msgs.msg import Int64, String
from std_srvs.srv import Trigger, TriggerRequest, TriggerResponse

from uav_common.ros.lockstep import Participant


def main() -> None:
    rospy.init_node("echo")
    peer = rospy.get_param("~peer")
    poke_at = int(rospy.get_param("~poke_peer_at", 0))
    ls = Participant(lookahead_steps=1)
    rng = random.Random()
    seen = ls.publisher("~seen", String)
    data: list[int] = []
    lines: list[str] = []
    fired = [0]
    poked = [-1]

    def on_data(msg: Int64) -> None:
        time.sleep(rng.uniform(0.0, 0.002))
        data.append(int(msg.data))

    def on_peer(msg: String) -> None:
        lines.append(msg.data.split(" ", 1)[0])

    def on_timer(_now: float) -> None:
        fired[0] = 1

    def on_poke(_req: object) -> TriggerResponse:
        poked[0] = ls.finished_step
        return TriggerResponse(success=True, message=str(ls.finished_step))

    def on_step(step: int, _now: float) -> None:
        if step == poke_at:
            ls.call(f"{peer}/poke", Trigger, TriggerRequest())
        time.sleep(rng.uniform(0.0, 0.004))
        seen.publish(String(data=f"{step} data={data} peer={lines} timer={fired[0]} poked={poked[0]}"))
        data.clear()
        lines.clear()
        fired[0] = 0
        poked[0] = -1

    ls.subscribe("/master/data", Int64, on_data)
    ls.subscribe(f"{peer}/seen", String, on_peer)
    ls.timer(0.25, on_timer, name="quarter")
    ls.service("~poke", Trigger, on_poke)
    ls.on_step(on_step)
    ls.spin()


if __name__ == "__main__":
    main()

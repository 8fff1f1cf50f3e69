"""The causal lockstep's pure parts (docs/lockstep.md): no ROS, no sockets, no clocks.

``protocol``: the step master's barrier and the subscribers' counting; ``timers``: timers in simulated time;
``markers``: the MAVLink step markers (HELLO / STEP in ``V2_EXTENSION``).
"""

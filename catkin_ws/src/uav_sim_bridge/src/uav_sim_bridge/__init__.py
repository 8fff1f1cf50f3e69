"""Simulated world and sensor bridge.

* ``uav_sim_bridge.core``: pure world generation, camera model and geometry.
* ``uav_sim_bridge.ros``: conversions between ROS messages and core types.
* ``uav_sim_bridge.nodes``: one module per executable in ``nodes/``, each with ``main()``.
"""

"""UAV autonomy: what flies a vehicle, in the simulator or on a real PX4 / ArduPilot.

Feature maps, MCDM goal selection, path planning and the MAVLink waypoint controller. It depends on
neither the simulator (``uav_sim_bridge``) nor the scenario layer (``uav_scenarios``).

* ``uav_autonomy.core``: pure numpy/stdlib algorithms; no rospy, sockets or clocks.
* ``uav_autonomy.mavlink``: the controller's MAVLink link (pymavlink, no ROS).
* ``uav_autonomy.ros``: conversions between ROS messages and core types.
* ``uav_autonomy.nodes``: one module per executable in ``nodes/``, each with ``main()``.
"""

"""UAV autonomy: mapping, feature maps, MCDM goal selection, planning, control, scoring.

Layout (REP 8, functional core / imperative shell):

* ``uav_autonomy.core``: pure numpy/stdlib algorithms; no rospy, sockets or clocks.
* ``uav_autonomy.ros``: conversions between ROS messages and core types.
* ``uav_autonomy.nodes``: one module per executable in ``nodes/``, each with ``main()``.
"""

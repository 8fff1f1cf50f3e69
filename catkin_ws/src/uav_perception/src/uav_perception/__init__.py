"""UAV perception: what turns camera images into geometry the map and the autonomy use.

* ``uav_perception.core.depth``: motion-stereo depth estimation and its evaluation (pure numpy/OpenCV).
* ``uav_perception.ros``: conversions between ROS messages and the core's types.
* ``uav_perception.shell``: file outputs (the depth evaluator's run log).
* ``uav_perception.nodes``: ``depth_estimator`` and ``depth_evaluator``, each with ``main()``.
"""

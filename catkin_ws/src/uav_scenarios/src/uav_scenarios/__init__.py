"""The test-range layer: scenarios, scoring, tracking, record/replay and run reports.

* ``uav_scenarios.core``: scenario files, mission logic, scripted baselines, the scoring and tracking
  cores (pure; no rospy, sockets, clocks, subprocesses, matplotlib or file caches).
* ``uav_scenarios.world``: the scenario's world and its ground truth, with their on-disk caches.
* ``uav_scenarios.report``: the offline run report (bag reading, figures, HTML).
* ``uav_scenarios.ros``: conversions between the scoring records and ROS messages.
* ``uav_scenarios.cli``: ``uav-run`` (a run's processes, progress and report) and ``uav-report``.
* ``uav_scenarios.nodes``: mission manager, tracker, scorer, scenario parameters and the launchers.
"""

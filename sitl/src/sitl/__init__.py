"""JSBSim quadrotor behind a PX4-compatible MAVLink autopilot emulator. Never imports ROS."""

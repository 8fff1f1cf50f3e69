"""MAVLink router with mavlink-routerd semantics and configuration format. Never imports ROS."""

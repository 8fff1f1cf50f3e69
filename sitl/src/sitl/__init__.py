"""JSBSim quadrotor behind a PX4- or ArduPilot-compatible MAVLink autopilot emulator. Never imports ROS."""

from sitl.compiled_core import activate as _activate_compiled_core

# before any sitl.core module is imported: the compiled per-step modules, if built for these sources
_activate_compiled_core()

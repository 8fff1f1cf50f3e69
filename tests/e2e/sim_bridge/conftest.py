"""The bridge's e2e tests drive the SITL with pymavlink: select MAVLink 2 before mavutil is imported."""

import os

os.environ["MAVLINK20"] = "1"

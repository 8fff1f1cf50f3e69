"""SITL e2e tests speak MAVLink 2: select pymavlink's v2 dialect before any test module imports mavutil."""

import os

os.environ["MAVLINK20"] = "1"

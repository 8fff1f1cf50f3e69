"""The autonomy e2e tests speak MAVLink 2: select it before mavutil is imported."""

import os

os.environ["MAVLINK20"] = "1"

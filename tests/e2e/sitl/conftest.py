"""SITL e2e tests speak MAVLink 2.

mavutil picks its dialect from ``MAVLINK20`` when a connection is made with
``dialect="common"`` (every connection in these tests does so); constants and
encoders come from ``pymavlink.dialects.v20.common`` directly, so it does not
matter which dialect another test module imported first.
"""

import os

os.environ["MAVLINK20"] = "1"

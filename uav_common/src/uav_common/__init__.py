"""ROS-free shared core of the UAV autonomy test range.

Submodules:

* :mod:`uav_common.config`: strict YAML -> frozen dataclass loading.
* :mod:`uav_common.frames`: the one place where ENU/FLU (ROS) meets NED/FRD (MAVLink).
* :mod:`uav_common.geo`: WGS-84 <-> local tangent plane around home.
* :mod:`uav_common.waiting`: ``wait_until`` with an injected clock.
"""

from uav_common.errors import ConfigError, ResourceError, UavCommonError, WaitTimeoutError

__all__ = ["ConfigError", "ResourceError", "UavCommonError", "WaitTimeoutError"]

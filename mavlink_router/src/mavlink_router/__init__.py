"""MAVLink router with mavlink-routerd semantics and configuration format. Never imports ROS.

Layout (functional core, imperative shell):

* pure core: :mod:`~mavlink_router.frames` (framing, CRC), :mod:`~mavlink_router.routing`
  (learned systems, routing decisions, filters), :mod:`~mavlink_router.dedup`,
  :mod:`~mavlink_router.signing`, :mod:`~mavlink_router.core` (bytes in, routed frames out),
  :mod:`~mavlink_router.config` (INI parsing and validation);
* adapters and shell: :mod:`~mavlink_router.dialect` (message table from pymavlink),
  :mod:`~mavlink_router.endpoints`, :mod:`~mavlink_router.tlog`, :mod:`~mavlink_router.mainloop`,
  :mod:`~mavlink_router.cli`.
"""

from mavlink_router.errors import ConfigError, DialectError, EndpointError, RouterError, SerialUnavailableError

__all__ = ["ConfigError", "DialectError", "EndpointError", "RouterError", "SerialUnavailableError"]

"""MAVLink router with mavlink-routerd semantics and configuration format. Never imports ROS.

Layout (functional core, imperative shell):

* pure core: :mod:`~mavlink_router.core.frames` (framing, CRC), :mod:`~mavlink_router.core.routing`
  (learned systems, routing decisions, filters), :mod:`~mavlink_router.core.dedup`,
  :mod:`~mavlink_router.core.signing`, :mod:`~mavlink_router.core.engine` (bytes in, routed frames out),
  :mod:`~mavlink_router.core.config` (INI parsing and validation);
* adapters and shell: :mod:`~mavlink_router.shell.dialect` (message table from pymavlink),
  :mod:`~mavlink_router.shell.endpoints`, :mod:`~mavlink_router.shell.tlog`, :mod:`~mavlink_router.shell.mainloop`,
  :mod:`~mavlink_router.cli`.
"""

from mavlink_router.errors import ConfigError, DialectError, EndpointError, RouterError, SerialUnavailableError

__all__ = ["ConfigError", "DialectError", "EndpointError", "RouterError", "SerialUnavailableError"]

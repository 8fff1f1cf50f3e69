"""``python -m sitl``: the same as ``uav-sitl``."""

from sitl.cli import main

raise SystemExit(main())

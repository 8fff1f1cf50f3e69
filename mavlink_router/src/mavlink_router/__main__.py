"""``python -m mavlink_router``: same as the ``uav-mavlink-router`` command."""

import sys

from mavlink_router.cli import main

sys.exit(main())

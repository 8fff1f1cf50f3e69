"""Preload of the embedded cluster's worker processes: Ctrl-C belongs to ``uav-campaign``, not to its workers.

A terminal's Ctrl-C reaches every process of its foreground process group, which includes the worker processes
the embedded ``LocalCluster`` spawns. A worker interrupted there would die with its run; instead the workers
ignore SIGINT and ``uav-campaign`` stops the runs itself (docs/campaigns.md, "Nothing lost").
"""

from __future__ import annotations

import signal
import threading
from typing import Any

__all__ = ["dask_setup"]


def dask_setup(worker: Any) -> None:
    """Called by Dask in each worker process when the worker starts (``preload``)."""
    del worker
    if threading.current_thread() is threading.main_thread():
        signal.signal(signal.SIGINT, signal.SIG_IGN)

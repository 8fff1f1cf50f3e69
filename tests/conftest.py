"""Shared fixtures for every tier.

Tiers live in directories: ``tests/unit`` (pure, no ROS master), ``tests/ros``
(rostest with a real roscore) and ``tests/e2e`` (SITL + router + ROS stack).
"""

from __future__ import annotations

from pathlib import Path

import pytest
from helpers.procs import artifacts_dir, slug


@pytest.fixture
def artifacts(request: pytest.FixtureRequest) -> Path:
    """A per-test folder under artifacts/ for images and logs a person may inspect."""
    path = artifacts_dir() / slug(request.node.nodeid)
    path.mkdir(parents=True, exist_ok=True)
    return path

from __future__ import annotations

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from uav_sim_bridge.core.transforms import RigidTransform

angles = st.floats(-3.0, 3.0)
coords = st.floats(-1000.0, 1000.0)


@settings(max_examples=50, deadline=None)
@given(st.tuples(angles, angles, angles), st.tuples(coords, coords, coords), angles, coords)
def test_compose_and_inverse(
    rpy: tuple[float, float, float], t: tuple[float, float, float], y2: float, t2: float
) -> None:
    a = RigidTransform.from_rpy(list(t), *rpy)
    b = RigidTransform.from_rpy([t2, 0.0, 1.0], 0.1, 0.0, y2)
    pts = np.array([[1.0, 2.0, 3.0], [-4.0, 0.5, 9.0]])
    np.testing.assert_allclose((a @ b).apply(pts), a.apply(b.apply(pts)), atol=1e-9)
    np.testing.assert_allclose((a.inverse() @ a).matrix(), np.eye(4), atol=1e-9)
    np.testing.assert_allclose(RigidTransform.from_quat(a.quat_wxyz, a.translation_m).rotation, a.rotation, atol=1e-9)


def test_rejects_non_rotations() -> None:
    with pytest.raises(ValueError, match="proper rotation"):
        RigidTransform(np.diag([1.0, 1.0, -1.0]), np.zeros(3))
    with pytest.raises(ValueError, match="finite"):
        RigidTransform(np.eye(3), np.array([np.nan, 0, 0]))

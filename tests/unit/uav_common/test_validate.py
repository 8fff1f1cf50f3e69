"""uav_common.validate: the shared validators name the value and what was expected, in the caller's error type."""

from __future__ import annotations

import math

import numpy as np
import pytest

from uav_common.validate import (
    require,
    require_finite,
    require_finite_vector,
    require_in_range,
    require_non_negative,
    require_port,
    require_positive,
)


class MyError(ValueError):
    pass


def test_good_values_pass_through() -> None:
    assert require_finite("x", 3) == 3.0
    assert require_positive("x", 0.5) == 0.5
    assert require_non_negative("x", 0) == 0.0
    assert require_in_range("x", 2, 1, 3) == 2.0
    assert require_finite_vector("p", np.array([[1, 2, 3]]), 3) == (1.0, 2.0, 3.0)
    assert require_port("port", 0, allow_zero=True) == 0
    require(True, "never raised")


@pytest.mark.parametrize(
    ("call", "match"),
    [
        (lambda: require_finite("altitude_m", math.nan), "altitude_m must be finite, got nan"),
        (lambda: require_positive("spacing_m", 0.0), "spacing_m must be a finite number > 0, got 0.0"),
        (lambda: require_positive("spacing_m", math.inf), "spacing_m must be a finite number > 0"),
        (lambda: require_non_negative("count", -1), "count must be a finite number >= 0, got -1"),
        (lambda: require_in_range("rate_hz", 5000, 50, 2000), r"rate_hz must be in \[50, 2000\], got 5000"),
        (lambda: require_finite_vector("goal", [1.0, math.nan, 0.0], 3), "goal: expected 3 finite numbers"),
        (lambda: require_finite_vector("goal", [1.0, 2.0], 3), "goal: expected 3 finite numbers"),
        (lambda: require_finite_vector("goal", "abc", 3), "goal: expected 3 numbers"),
        (lambda: require_port("remote_port", 0), r"'remote_port' must be a port in \[1, 65535\], got 0"),
        (lambda: require_port("port", 70000, allow_zero=True), r"in \[0, 65535\]"),
        (lambda: require(False, "custom message"), "custom message"),
    ],
)
def test_bad_values_are_named_in_the_callers_error(call: object, match: str) -> None:
    with pytest.raises(ValueError, match=match):
        call()  # type: ignore[operator]


def test_the_error_type_is_the_callers() -> None:
    with pytest.raises(MyError):
        require_positive("x", -1.0, error=MyError)
    with pytest.raises(MyError):
        require_finite_vector("x", [math.inf], 1, error=MyError)

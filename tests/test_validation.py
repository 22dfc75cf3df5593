"""The shared argument checks: one message format, bounds open and closed, kinds refused."""

from __future__ import annotations

import math

import numpy as np
import pytest

from fpg_gym.core.validation import check_choice, check_integer, check_number
from fpg_gym.reconstruct import ReconstructorConfig


def test_check_number_bounds_open_and_closed() -> None:
    assert check_number(0.0, "x", low=0.0) == 0.0
    assert check_number(np.float32(1.0), "x", low=0.0, high=1.0) == 1.0
    with pytest.raises(ValueError, match=r"^x: expected a number > 0, got 0\.0$"):
        check_number(0.0, "x", low=0.0, low_open=True)
    with pytest.raises(ValueError, match=r"^x: expected a number in \[0, 1\), got 1$"):
        check_number(1, "x", low=0, high=1, high_open=True)
    with pytest.raises(ValueError, match=r"x: expected a number <= 2"):
        check_number(2.5, "x", high=2)


@pytest.mark.parametrize("bad", [math.nan, math.inf, -math.inf, True, "1", None, [1.0]])
def test_check_number_refuses_what_is_not_a_finite_real(bad: object) -> None:
    with pytest.raises(ValueError, match=r"^blend: expected a number"):
        check_number(bad, "blend")


def test_check_integer() -> None:
    assert check_integer(np.int64(4), "k", low=1) == 4
    assert isinstance(check_integer(np.int64(4), "k"), int)
    for bad in (0, 2.0, True, "3", 11):
        with pytest.raises(ValueError, match=r"^k: expected an integer in \[1, 10\], got"):
            check_integer(bad, "k", low=1, high=10)


def test_check_choice() -> None:
    assert check_choice("b", "mode", ("a", "b")) == "b"
    with pytest.raises(ValueError, match=r"^mode: expected one of 'a', 'b', got 'c'$"):
        check_choice("c", "mode", ("a", "b"))


def test_the_library_uses_them_at_its_boundary() -> None:
    with pytest.raises(ValueError, match=r"^k: expected an integer >= 1, got 0$"):
        ReconstructorConfig(k=0)
    with pytest.raises(ValueError, match=r"^selector: expected one of 'graph', 'brute-force'"):
        ReconstructorConfig(selector="kd-tree")

"""The one JSON converter used by every file writer and command."""

from __future__ import annotations

import json
from pathlib import Path

import numpy as np

from fpg_gym.core.jsonable import jsonable


def test_jsonable_converts_numpy_paths_and_non_finite_floats() -> None:
    value = {
        1: np.float32(0.5),
        "array": np.arange(3),
        "nested": (np.int64(2), [Path("a/b"), float("nan")]),
        "inf": np.float64(np.inf),
    }
    out = jsonable(value)
    assert out == {"1": 0.5, "array": [0, 1, 2], "nested": [2, ["a/b", None]], "inf": None}
    assert json.loads(json.dumps(out)) == out

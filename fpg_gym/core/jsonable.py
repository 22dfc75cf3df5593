"""JSON-ready copies of values holding numpy scalars and arrays, paths and non-finite floats."""

from __future__ import annotations

import math
from collections.abc import Mapping
from pathlib import PurePath
from typing import Any

import numpy as np


def jsonable(value: Any) -> Any:
    """A copy of ``value`` that ``json.dumps`` accepts and that reads back the same everywhere.

    Mappings become dicts with string keys, tuples and arrays become lists, numpy scalars become
    Python numbers, paths become strings, and NaN or infinite floats become None (JSON has no
    spelling for them).
    """
    if isinstance(value, Mapping):
        return {str(key): jsonable(item) for key, item in value.items()}
    if isinstance(value, list | tuple):
        return [jsonable(item) for item in value]
    if isinstance(value, np.ndarray):
        return jsonable(value.tolist())
    if isinstance(value, np.generic):
        return jsonable(value.item())
    if isinstance(value, PurePath):
        return str(value)
    if isinstance(value, float) and not math.isfinite(value):
        return None
    return value

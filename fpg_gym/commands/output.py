"""Helpers shared by the commands: JSON summaries on the last stdout line."""

from __future__ import annotations

import json
import math
from typing import Any

import numpy as np


def _plain(value: Any) -> Any:
    if isinstance(value, dict):
        return {str(k): _plain(v) for k, v in value.items()}
    if isinstance(value, list | tuple):
        return [_plain(v) for v in value]
    if isinstance(value, np.ndarray):
        return _plain(value.tolist())
    if isinstance(value, np.generic):
        return _plain(value.item())
    if isinstance(value, float) and not math.isfinite(value):
        return None
    return value


def emit_json(summary: dict[str, Any]) -> None:
    """Print ``summary`` as one JSON line (numpy values converted, NaN as null)."""
    print(json.dumps(_plain(summary), sort_keys=False), flush=True)

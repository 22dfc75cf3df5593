"""Helpers shared by the commands: JSON summaries on the last stdout line."""

from __future__ import annotations

import json
from typing import Any

from fpg_gym.core.jsonable import jsonable


def emit_json(summary: dict[str, Any]) -> None:
    """Print ``summary`` as one JSON line (numpy values converted, NaN as null)."""
    print(json.dumps(jsonable(summary), sort_keys=False), flush=True)

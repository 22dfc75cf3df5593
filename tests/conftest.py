"""Shared fixtures: the real data folder ``../shared/data`` (skipped when absent), a seeded RNG."""

from __future__ import annotations

import os
from pathlib import Path

import numpy as np
import pytest

REPO = Path(__file__).resolve().parents[1]
SHARED_DATA = Path(os.environ.get("FPG_GYM_SHARED_DATA", REPO.parent / "shared" / "data"))


def shared_path(*parts: str) -> Path:
    """A path under ``../shared/data``; skips the calling test when it does not exist."""
    path = SHARED_DATA.joinpath(*parts)
    if not path.exists():
        pytest.skip(f"needs the shared data set: {path} is absent (set FPG_GYM_SHARED_DATA)")
    return path


@pytest.fixture
def shared_data() -> Path:
    """The ``../shared/data`` folder, or skip the test when it is absent."""
    return shared_path()


@pytest.fixture
def rng() -> np.random.Generator:
    """A seeded random generator."""
    return np.random.default_rng(12345)

"""Shared fixtures: the real data folder ``../shared/data`` (skipped when absent), a seeded RNG,
a cache folder of the session's own (the tests never touch the user's ``~/.cache/fpg-gym``), the
embedded default graph without the held-out clips and a few short simulated streams."""

from __future__ import annotations

import os
from collections.abc import Iterator
from pathlib import Path
from typing import Any

import numpy as np
import pytest

REPO = Path(__file__).resolve().parents[1]
SHARED_DATA = Path(os.environ.get("FPG_GYM_SHARED_DATA", REPO.parent / "shared" / "data"))


#: A three-joint BVH hierarchy (Hips > Chest > Hand, 12 channels) up to ``MOTION``: the tests'
#: small BVH files add ``Frames:``, ``Frame Time:`` and their frame lines.
TINY_BVH_HIERARCHY = """HIERARCHY
ROOT Hips
{
  OFFSET 0 0 0
  CHANNELS 6 Xposition Yposition Zposition Zrotation Xrotation Yrotation
  JOINT Chest
  {
    OFFSET 0 50 0
    CHANNELS 3 Zrotation Xrotation Yrotation
    JOINT Hand
    {
      OFFSET 0 0 30
      CHANNELS 3 Xrotation Yrotation Zrotation
      End Site
      {
        OFFSET 0 0 10
      }
    }
  }
}
MOTION
"""


def tiny_bvh(frames: list[str], frame_time: str = "0.0333333") -> str:
    """A BVH text of :data:`TINY_BVH_HIERARCHY` with the given frame lines (12 values each)."""
    lines = [f"Frames: {len(frames)}", f"Frame Time: {frame_time}", *frames]
    return TINY_BVH_HIERARCHY + "\n".join(lines) + "\n"


def one_error_line(capsys: pytest.CaptureFixture[str], command: str) -> str:
    """The single error line of a failed command on stderr: asserts there is exactly one, of
    the form ``fpg-gym COMMAND: error: ...``, and no traceback (a progress bar may precede it)."""
    err = capsys.readouterr().err
    lines = [line for line in err.splitlines() if ": error:" in line]
    assert len(lines) == 1, err
    assert lines[0].startswith(f"fpg-gym {command}: error: "), err
    assert "Traceback" not in err
    return lines[0]


def exit_status(argv: list[str]) -> int:
    """``fpg_gym.cli.main``'s exit status, whether returned or raised (argparse raises
    SystemExit)."""
    from fpg_gym.cli import main

    try:
        return main(argv)
    except SystemExit as exit_:
        return int(exit_.code or 0)


def shared_path(*parts: str) -> Path:
    """A path under ``../shared/data``; skips the calling test when it does not exist."""
    path = SHARED_DATA.joinpath(*parts)
    if not path.exists():
        pytest.skip(f"needs the shared data set: {path} is absent (set FPG_GYM_SHARED_DATA)")
    return path


@pytest.fixture(scope="session", autouse=True)
def _session_cache(tmp_path_factory: pytest.TempPathFactory) -> Iterator[None]:
    """``$FPG_GYM_CACHE`` points into the session's temporary folder (subprocesses inherit it):
    the default graph is built once per session and never read from, or written to, the user's
    cache."""
    with pytest.MonkeyPatch.context() as patch:
        patch.setenv("FPG_GYM_CACHE", str(tmp_path_factory.mktemp("fpg-gym-cache")))
        yield


@pytest.fixture
def shared_data() -> Path:
    """The ``../shared/data`` folder, or skip the test when it is absent."""
    return shared_path()


@pytest.fixture
def rng() -> np.random.Generator:
    """A seeded random generator."""
    return np.random.default_rng(12345)


@pytest.fixture(scope="session")
def graph(_session_cache: None) -> Any:
    """The embedded default graph without the held-out clips (``DEFAULT_HOLDOUT_CLIPS``), built
    once per session into the session's cache; a module may define a ``graph`` of its own."""
    from fpg_gym.core.defaults import DEFAULT_HOLDOUT_CLIPS
    from fpg_gym.graph import default_graph

    return default_graph(exclude=DEFAULT_HOLDOUT_CLIPS)


@pytest.fixture(scope="session")
def short_streams() -> list[Any]:
    """Four simulated streams of 5 frames (walk and punch, ``front-many``, seeds 0 and 1)."""
    from fpg_gym.io import load_default_clips
    from policies.training import simulate_episodes

    clips = load_default_clips(["walk", "punch"])
    return simulate_episodes(clips, ["front-many"], [0, 1], max_frames=5)

"""The one seeding rule (fpg_gym.core.seeding): a part of a run is seeded from the user's seed and
its names, and every derivation in the library goes through it."""

from __future__ import annotations

import zlib
from pathlib import Path

import numpy as np
import pytest

from fpg_gym.core.seeding import as_generator, derive_seed
from fpg_gym.simulate import episode_seed, plan_episode

REPO = Path(__file__).resolve().parents[1]


def test_a_derived_seed_is_the_seed_sequence_of_the_seed_and_the_names_crc32() -> None:
    words = [7, zlib.crc32(b"walk"), zlib.crc32(b"front-many")]
    expected = int(np.random.SeedSequence(words).generate_state(1)[0])
    assert derive_seed(7, "walk", "front-many") == expected
    assert episode_seed(7, "walk", "front-many") == expected
    assert plan_episode("walk", "front-many", 7).sim_seed == expected
    # Names, not positions: another name, another seed; the same names, the same seed.
    assert derive_seed(7, "walk", "side") != expected
    assert derive_seed(7, "kick", "front-many") != expected != derive_seed(8, "walk", "front-many")
    assert 0 <= derive_seed(0) < 2**32
    with pytest.raises(ValueError, match="seed: expected an integer >= 0"):
        derive_seed(-1, "walk")


def test_as_generator_keeps_a_generator_and_seeds_the_rest() -> None:
    generator = np.random.default_rng(3)
    assert as_generator(generator) is generator
    assert as_generator(3).random() == np.random.default_rng(3).random()
    assert isinstance(as_generator(None), np.random.Generator)


def test_the_library_derives_seeds_only_through_the_rule() -> None:
    """No module of fpg_gym but the rule's builds a SeedSequence or hashes a name into a seed
    (policies' own schemes are to move to it separately)."""
    offenders = [
        path.relative_to(REPO).as_posix()
        for path in sorted((REPO / "fpg_gym").rglob("*.py"))
        if path.name != "seeding.py"
        and any(call in path.read_text() for call in ("random.SeedSequence(", "zlib.crc32("))
    ]
    assert offenders == []

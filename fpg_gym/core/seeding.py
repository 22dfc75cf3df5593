"""The seeding rule: the one way a seed is derived from a user's seed, and generators from seeds.

Randomness only flows through a passed :class:`numpy.random.Generator` (DESIGN.md). Where a run
needs a seed of its own for a part of it (an episode's simulator, the optimisers on a recording,
the occlusion put into a real stream), it is derived from the user's seed ``n`` and the *names*
of that part, never from a position in a list or a counter::

    derive_seed(n, name_1, name_2, ...) = SeedSequence([n, crc32(name_1), crc32(name_2), ...])
                                              .generate_state(1)[0]

(``crc32`` of each name's text in UTF-8; a non-negative 32-bit integer). A part's seed therefore
depends on ``n`` and its names only, not on the order or the length of the lists it was planned
from, and parts with different names get unrelated streams. Uses:
:func:`fpg_gym.simulate.episode_seed` (an episode's simulator and optimisers: clip and scenario,
or a recording's stem), the demo's occlusions (stem and case).

Seeds the project does not derive keep their owners' conventions: a Gymnasium env's
``reset(seed=n)`` seeds its ``np_random`` (the env draws its episode from it), and
:class:`fpg_gym.vector_env.KinectPoseVectorEnv` gives sub-env ``i`` the seed ``n + i``, as
Gymnasium's ``SyncVectorEnv`` does (tested against it).

Examples
--------
>>> derive_seed(0, "walk", "front-many") == derive_seed(0, "walk", "front-many")
True
>>> derive_seed(0, "walk", "front-many") != derive_seed(1, "walk", "front-many")
True
"""

from __future__ import annotations

import zlib

import numpy as np

from fpg_gym.core.validation import check_integer

__all__ = ["SeedLike", "as_generator", "derive_seed"]

#: What a function that draws takes: a seed, a generator (used as is) or None (fresh entropy).
SeedLike = int | np.integer | np.random.Generator | np.random.SeedSequence | None


def derive_seed(seed: int, *names: object) -> int:
    """The seed of a part of a run: the user's ``seed`` and the part's names (module docstring).

    Parameters
    ----------
    seed : int
        The user's seed (non-negative).
    *names : object
        The part's names (each enters as the CRC-32 of ``str(name)``).

    Returns
    -------
    int
        A non-negative 32-bit integer.

    Raises
    ------
    ValueError
        If ``seed`` is not a non-negative integer.
    """
    words = [check_integer(seed, "seed", low=0)] + [
        zlib.crc32(str(name).encode()) for name in names
    ]
    return int(np.random.SeedSequence(words).generate_state(1)[0])


def as_generator(rng: SeedLike) -> np.random.Generator:
    """``rng`` itself when it is a generator, else ``numpy.random.default_rng(rng)``."""
    return rng if isinstance(rng, np.random.Generator) else np.random.default_rng(rng)

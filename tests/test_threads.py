"""The per-frame linear algebra runs on one BLAS thread, and the caller's setting comes back."""

from __future__ import annotations

import numpy as np
import pytest
from threadpoolctl import threadpool_info, threadpool_limits

from fpg_gym.reconstruct.latent import LatentSpace
from fpg_gym.runtime.threads import one_blas_thread


def blas_threads() -> list[int]:
    return [lib["num_threads"] for lib in threadpool_info() if lib["user_api"] == "blas"]


def test_one_blas_thread_limits_the_block_and_restores_the_setting() -> None:
    if not blas_threads():
        pytest.skip("no BLAS library that threadpoolctl can control")
    with threadpool_limits(limits=2, user_api="blas"):
        before = blas_threads()
        with one_blas_thread():
            assert set(blas_threads()) == {1}
        assert blas_threads() == before
        with pytest.raises(RuntimeError), one_blas_thread():
            raise RuntimeError("restored on errors too")
        assert blas_threads() == before


def test_the_local_pca_gives_the_same_space_on_one_thread_as_on_two() -> None:
    poses = np.random.default_rng(0).normal(0.0, 0.3, (30, 20, 3))
    spaces = []
    for threads in (1, 2):
        with threadpool_limits(limits=threads, user_api="blas"):
            spaces.append(LatentSpace.fit(poses, kernel="numpy"))
    np.testing.assert_array_equal(spaces[0].basis, spaces[1].basis)
    np.testing.assert_array_equal(spaces[0].std, spaces[1].std)

"""The supervised sampler's training pairs (policies.imitation): the same pairs whatever the
batch size and the number of worker processes, the frame cap in recording order, and the
arguments checked."""

from __future__ import annotations

from typing import Any

import numpy as np
import pytest

from fpg_gym.reconstruct.kernels import available_kernels
from fpg_gym.runtime.ray_session import signal_handlers
from policies.imitation import ImitationData, collect_imitation_data
from tests.test_truth_target import SPEC


@pytest.fixture
def recordings(short_streams: list[Any]) -> list[Any]:
    return short_streams


def _assert_same(a: ImitationData, b: ImitationData) -> None:
    np.testing.assert_array_equal(a.episodes, b.episodes)
    if "numba" in available_kernels():  # the same compiled arithmetic: equal to the bit
        np.testing.assert_array_equal(a.actions, b.actions)
        np.testing.assert_array_equal(a.observations, b.observations)
        np.testing.assert_array_equal(a.search_energies, b.search_energies)
    else:
        np.testing.assert_allclose(a.actions, b.actions, atol=1e-4)
        np.testing.assert_allclose(a.search_energies, b.search_energies, rtol=1e-6)


def test_pairs_do_not_depend_on_batch_or_workers(graph: Any, recordings: list[Any]) -> None:
    alone = collect_imitation_data(graph, recordings, SPEC, target="best", seed=3, batch=1)
    batched = collect_imitation_data(graph, recordings, SPEC, target="best", seed=3, batch=3)
    pooled = collect_imitation_data(
        graph, recordings, SPEC, target="best", seed=3, batch=8, workers=2
    )
    assert len(alone) == sum(r.num_frames for r in recordings)
    # Episode-major order: each episode's frames contiguous, episodes in recording order.
    np.testing.assert_array_equal(
        alone.episodes, np.repeat(np.arange(len(recordings)), [r.num_frames for r in recordings])
    )
    _assert_same(alone, batched)
    _assert_same(alone, pooled)
    assert np.all(alone.masks == 1.0)
    # Another seed draws other searches: the equalities above are not vacuous.
    other = collect_imitation_data(graph, recordings, SPEC, target="best", seed=4, batch=3)
    assert not np.array_equal(other.actions, alone.actions)


def test_the_frame_cap_takes_frames_in_recording_order(graph: Any, recordings: list[Any]) -> None:
    whole = collect_imitation_data(graph, recordings, SPEC, target="search", seed=0)
    first = recordings[0].num_frames
    capped = collect_imitation_data(
        graph, recordings, SPEC, target="search", seed=0, frames=first + 2
    )
    assert len(capped) == first + 2
    np.testing.assert_array_equal(capped.episodes, [0] * first + [1, 1])
    # An episode's first frames do not depend on where the cap cuts it.
    np.testing.assert_allclose(capped.actions, whole.actions[: first + 2])


def test_bad_arguments_are_named(graph: Any, recordings: list[Any]) -> None:
    with pytest.raises(ValueError, match="batch: expected >= 1"):
        collect_imitation_data(graph, recordings, SPEC, batch=0)
    with pytest.raises(ValueError, match="workers: expected >= 1"):
        collect_imitation_data(graph, recordings, SPEC, workers=0)
    with pytest.raises(ValueError, match="target 'truth' needs ground truth"):
        no_truth = [type(recordings[0])(r.positions, r.states, r.timestamps) for r in recordings]
        collect_imitation_data(graph, no_truth, SPEC, target="truth", follow="anchor")
    empty = collect_imitation_data(graph, recordings, SPEC, frames=0)
    assert len(empty) == 0 and empty.observations.shape == (0, SPEC.layout.size)


def test_ray_backend_gives_the_local_pairs(graph: Any, recordings: list[Any]) -> None:
    ray = pytest.importorskip(
        "ray", reason="Ray is not installed (pip install 'fpg-gym[distributed]')"
    )
    local = collect_imitation_data(graph, recordings, SPEC, target="best", seed=3, batch=3)
    handlers = signal_handlers()
    on_ray = collect_imitation_data(
        graph, recordings, SPEC, target="best", seed=3, batch=3, workers=2, backend="ray"
    )
    assert not ray.is_initialized()  # the local instance it started is stopped
    assert signal_handlers() == handlers  # and Ray's driver handlers are gone
    _assert_same(local, on_ray)
    with pytest.raises(ValueError, match="backend: expected one of"):
        collect_imitation_data(graph, recordings, SPEC, backend="dask")


def test_train_config_checks_where_the_data_is_collected() -> None:
    from policies.training import TrainConfig

    assert TrainConfig(kind="supervised", out="m", workers=2, backend="ray").workers == 2
    with pytest.raises(ValueError, match="workers: expected >= 1"):
        TrainConfig(kind="supervised", out="m", workers=0)
    with pytest.raises(ValueError, match="backend: expected one of"):
        TrainConfig(kind="supervised", out="m", backend="dask")
    with pytest.raises(ValueError, match="--kind rl runs one environment here"):
        TrainConfig(kind="rl", out="m", workers=2)

"""The frame's compiled stages (numba) against the numpy code they stand for.

The filters' steps, the pose retarget, one pose's bone lengths and the sorted window do the same
operations in the same order, so their outputs must be equal to the bit; the local PCA, the
energy's set-up, the candidates' assembly and the behaviour angles sum in another order (or call
another arccos), so theirs must agree to rounding. Each numpy path runs within
``fpg_gym.core.compiled.numpy_only()``.
"""

from __future__ import annotations

import contextlib
import os
import subprocess
import sys
from typing import Any

import numpy as np
import pytest

from fpg_gym.core import poses, skeleton
from fpg_gym.core.compiled import (
    COMPILED_MODULES,
    NO_NUMBA_VARIABLE,
    compiled_module,
    numba_available,
    numpy_only,
    only_compiled,
)
from fpg_gym.filters import INFERRED, NOT_TRACKED, TRACKED, KalmanFilter, OneEuroFilter
from fpg_gym.reconstruct.energy import TERM_NAMES, EnergyModel, EnergyWeights
from fpg_gym.reconstruct.latent import LatentSpace
from fpg_gym.reconstruct.left_right import LABEL_PERMUTATIONS, best_labelling, left_right_costs
from fpg_gym.reconstruct.node_database import NodeDatabase
from fpg_gym.reconstruct.reliability import SortedWindow, behaviour_angles

pytestmark = pytest.mark.skipif(not numba_available(), reason="needs numba (fpg-gym[fast])")


def test_numpy_only_hides_every_compiled_module_within_its_block() -> None:
    with numpy_only():
        assert [compiled_module(name) for name in COMPILED_MODULES] == [None] * len(
            COMPILED_MODULES
        )
        with numpy_only():
            pass
        assert compiled_module(COMPILED_MODULES[0]) is None  # still hidden after a nested block
    assert all(compiled_module(name) is not None for name in COMPILED_MODULES)


def test_the_environment_variable_runs_a_process_as_without_numba() -> None:
    """``FPG_GYM_NO_NUMBA=1`` (CI's second run of the equation tests): no compiled module and
    ``numba_available()`` False for the whole process, numba itself never imported."""
    code = (
        "import sys\n"
        "from fpg_gym.core.compiled import COMPILED_MODULES, compiled_module, numba_available\n"
        "from fpg_gym.reconstruct import reliability\n"
        "print(numba_available(), {compiled_module(n) for n in COMPILED_MODULES},"
        " 'numba' in sys.modules)"
    )
    for value, expected in (("1", "False {None} False"), ("0", "True")):
        out = subprocess.run(
            [sys.executable, "-c", code],
            env={**os.environ, NO_NUMBA_VARIABLE: value},
            capture_output=True,
            text=True,
            check=True,
        ).stdout.strip()
        assert out.startswith(expected), (value, out)


@pytest.mark.parametrize("before", [None, "0"])
def test_numpy_only_for_new_processes_sets_the_variable_for_its_block(
    before: str | None, monkeypatch: pytest.MonkeyPatch
) -> None:
    """The processes a block starts (a compare's spawned workers) run as without numba; the
    environment is as it was after the block, also when the block raises."""
    if before is None:
        monkeypatch.delenv(NO_NUMBA_VARIABLE, raising=False)
    else:
        monkeypatch.setenv(NO_NUMBA_VARIABLE, before)
    code = "from fpg_gym.core.compiled import numba_available; print(numba_available())"
    with pytest.raises(KeyError), numpy_only(new_processes=True):
        assert compiled_module(COMPILED_MODULES[0]) is None
        child = subprocess.run(
            [sys.executable, "-c", code], capture_output=True, text=True, check=True
        )
        assert child.stdout.strip() == "False"
        raise KeyError("the block fails")
    assert os.environ.get(NO_NUMBA_VARIABLE) == before
    assert compiled_module(COMPILED_MODULES[0]) is not None


def test_only_compiled_shows_its_modules_and_nests_as_an_intersection() -> None:
    first, second, third = COMPILED_MODULES[:3]
    with only_compiled([first, second]):
        assert compiled_module(first) is not None and compiled_module(third) is None
        with only_compiled([second, third]):
            assert [compiled_module(n) for n in (first, second, third)] == [
                None,
                compiled_module(second),
                None,
            ]
            assert compiled_module(second) is not None
        with numpy_only():
            assert compiled_module(first) is None
        assert compiled_module(second) is not None
    assert all(compiled_module(name) is not None for name in COMPILED_MODULES)


def hostile_stream(rng: np.random.Generator, frames: int = 90) -> tuple[np.ndarray, ...]:
    """A noisy walk with every state, dropped and non-finite joints, a repeated timestamp and
    a long gap (the velocity is zeroed past max_coast)."""
    walk = np.cumsum(rng.normal(0.0, 0.02, (frames, 20, 3)), axis=0)
    positions = walk + np.array([0.0, 1.0, 2.5])
    states = rng.choice([NOT_TRACKED, INFERRED, TRACKED], (frames, 20), p=[0.1, 0.2, 0.7])
    states[:, 3] = NOT_TRACKED  # a joint never measured
    states = states.astype(np.int8)
    positions[rng.random((frames, 20)) < 0.03] = np.nan
    times = np.arange(frames) / 30.0
    times[40] = times[39]  # a repeated timestamp
    times[60:] += 0.5  # a gap longer than max_coast
    return positions, states, times


def run_filter(make: Any, hidden: bool, stream: tuple[np.ndarray, ...]) -> Any:
    with numpy_only() if hidden else contextlib.nullcontext():
        filt = make()
        out = np.stack([filt.update(p, s, t) for p, s, t in zip(*stream, strict=True)])
        state = {k: np.copy(v) for k, v in vars(filt).items() if isinstance(v, np.ndarray)}
    return out, state


@pytest.mark.parametrize(
    "make",
    [
        KalmanFilter,
        lambda: KalmanFilter(max_coast=None, not_tracked_std=0.2),
        OneEuroFilter,
        lambda: OneEuroFilter("output"),
    ],
)
def test_compiled_filter_steps_equal_the_numpy_steps_to_the_bit(make: Any) -> None:
    stream = hostile_stream(np.random.default_rng(3))
    compiled, compiled_state = run_filter(make, False, stream)
    reference, reference_state = run_filter(make, True, stream)
    np.testing.assert_array_equal(compiled, reference)
    assert compiled_state.keys() == reference_state.keys()
    for name, value in reference_state.items():
        np.testing.assert_array_equal(compiled_state[name], value, err_msg=name)


def test_compiled_kalman_keeps_the_innovations_fit_noise_reads() -> None:
    positions, states, times = hostile_stream(np.random.default_rng(4), frames=70)
    innovations = []
    for hidden in (False, True):
        with numpy_only() if hidden else contextlib.nullcontext():
            kf = KalmanFilter()
            seen = []
            for p, s, t in zip(positions, states, times, strict=True):
                kf.update(p, s, t)
                seen.append([np.copy(a) for a in kf._innovation])
            innovations.append(seen)
    for compiled, reference in zip(*innovations, strict=True):
        for a, b in zip(compiled, reference, strict=True):
            np.testing.assert_array_equal(a, b)


def test_compiled_retarget_of_one_pose_equals_the_numpy_retarget() -> None:
    rng = np.random.default_rng(5)
    for i in range(200):
        pose = rng.normal(0.0, 0.3, (20, 3))
        if i % 5 == 0:
            pose[6] = pose[5]  # a zero-length bone takes its rest direction
        lengths = rng.uniform(0.05, 0.5, skeleton.NUM_BONES)
        compiled = poses.retarget(pose, lengths)
        with numpy_only():
            reference = poses.retarget(pose, lengths)
        assert compiled.dtype == np.float32
        np.testing.assert_array_equal(compiled, reference)
        np.testing.assert_allclose(poses.bone_lengths(compiled), lengths, atol=1e-6)


def test_compiled_sorted_window_equals_the_numpy_window() -> None:
    rng = np.random.default_rng(8)
    rows = np.round(rng.normal(1.0, 0.1, (60, 19)), 2)  # rounded: many equal values
    rows[rng.random(rows.shape) < 0.2] = np.nan
    windows = {}
    for hidden in (False, True):
        with numpy_only() if hidden else contextlib.nullcontext():
            window, medians = SortedWindow(), []
            for i, row in enumerate(rows):
                if i >= 25:
                    window.remove(rows[i - 25])
                window.add(row)
                medians.append(window.median())
                kept = rows[max(0, i - 24) : i + 1]
                np.testing.assert_array_equal(window.values, np.sort(kept[np.isfinite(kept)]))
            windows[hidden] = medians
    assert windows[False] == windows[True]


def test_compiled_remove_sorted_refuses_a_value_not_in_the_window() -> None:
    compiled = compiled_module("fpg_gym.reconstruct.compiled_reliability")
    with pytest.raises(ValueError, match="not in the window"):
        compiled.remove_sorted(np.array([1.0, 2.0]), np.array([3.0]))


def test_compiled_pose_helpers_equal_their_numpy_paths(graph: Any) -> None:
    rng = np.random.default_rng(9)
    database = NodeDatabase(graph.poses)
    nodes = rng.choice(len(graph.poses), 30, replace=False)
    lengths = rng.uniform(0.05, 0.5, skeleton.NUM_BONES)
    pose = rng.normal(0.0, 0.3, (20, 3))
    a, b = rng.normal(0.0, 0.05, (2, 20, 3))
    a[3] = 0.0  # a short displacement: angle 0
    results = []
    for hidden in (False, True):
        with numpy_only() if hidden else contextlib.nullcontext():
            results.append(
                (
                    database.poses_for(nodes, lengths),
                    poses.bone_lengths(pose),
                    behaviour_angles(a, b, 0.03),
                    behaviour_angles(b, -b, 0.03),  # opposite: pi
                )
            )
    compiled, reference = results
    assert compiled[0].dtype == np.float32 and compiled[0].flags.c_contiguous
    np.testing.assert_allclose(compiled[0], reference[0], rtol=0, atol=1e-6)
    np.testing.assert_array_equal(compiled[1], reference[1])  # the same sums
    for x, y in zip(compiled[2:], reference[2:], strict=True):
        np.testing.assert_allclose(x, y, rtol=0, atol=1e-7)  # arccos is steep at pi
        np.testing.assert_array_equal(x == 0.0, y == 0.0)


def test_compiled_placements_of_one_pose_agree_with_numpy() -> None:
    rng = np.random.default_rng(10)
    for i in range(100):
        pose = rng.normal(0.0, 0.4, (20, 3)) + np.array([0.0, 1.0, 2.5])
        if i % 10 == 0:  # hips on a vertical line: the heading comes from the shoulders
            pose[16] = pose[12] + np.array([0.0, 0.05, 0.0])
        placement = poses.Placement(root=rng.normal(size=3), yaw=np.asarray(rng.uniform(-3, 3)))
        results = []
        for hidden in (False, True):
            with numpy_only() if hidden else contextlib.nullcontext():
                normalised, found = poses.normalise(pose)
                results.append(
                    (
                        normalised,
                        found.yaw,
                        poses.denormalise(normalised, found),
                        poses.into_placement(pose, placement),
                    )
                )
        (a, yaw, back, placed), (a2, yaw2, back2, placed2) = results
        np.testing.assert_array_equal(a, a2)
        # arctan2 of numba's libm and numpy's may differ in the last bit (numba 0.68, numpy 2.4)
        assert abs(float(yaw) - float(yaw2)) <= 1e-14 and np.ndim(yaw) == np.ndim(yaw2) == 0
        np.testing.assert_allclose(back, back2, rtol=0, atol=1e-6)  # float32 poses
        np.testing.assert_allclose(placed, placed2, rtol=0, atol=1e-14)  # numpy may fuse


def test_compiled_left_right_costs_agree_with_numpy() -> None:
    rng = np.random.default_rng(11)
    for _ in range(200):
        positions = rng.normal(0.0, 0.4, (20, 3)) + np.array([0.0, 1.0, 2.5])
        prediction = positions + rng.normal(0.0, 0.05, (20, 3))
        states = rng.choice([NOT_TRACKED, INFERRED, TRACKED], 20).astype(np.int8)
        compiled = left_right_costs(positions, states, prediction)
        with numpy_only():
            reference = left_right_costs(positions, states, prediction)
        np.testing.assert_allclose(compiled, reference, rtol=1e-13, atol=1e-15)
        assert np.argmin(compiled) == np.argmin(reference)


def test_compiled_best_labelling_chooses_as_numpy() -> None:
    """``compiled_frame.best_labelling`` against :func:`best_labelling`'s numpy code: mirrored,
    arms-swapped and legs-swapped sensor poses near the prediction of one or two previous
    outputs (also at uneven and zero time steps), and poses near no labelling's margin."""
    rng = np.random.default_rng(12)
    chosen = []
    for i in range(400):
        before = rng.normal(0.0, 0.3, (20, 3)) + np.array([0.0, 1.0, 2.5])
        last = before + rng.normal(0.0, 0.03, (20, 3))
        history = [(before, 0.0), (last, float(rng.choice([0.0, 1 / 30, 1 / 15])))][i % 2 :]
        labelling = i % len(LABEL_PERMUTATIONS)
        noise = rng.choice([0.01, 0.05, 0.2])
        sensor = (2 * last - before + rng.normal(0.0, noise, (20, 3)))[
            LABEL_PERMUTATIONS[labelling]
        ]
        states = rng.choice([NOT_TRACKED, INFERRED, TRACKED], 20, p=[0.1, 0.2, 0.7]).astype(np.int8)
        margin = float(rng.choice([0.5, 0.8]))
        compiled = best_labelling(sensor.astype(np.float32), states, history, 1 / 30, margin)
        with numpy_only():
            reference = best_labelling(sensor.astype(np.float32), states, history, 1 / 30, margin)
        assert compiled == reference, i
        chosen.append(compiled)
    assert set(chosen) == set(range(len(LABEL_PERMUTATIONS)))


def candidate_sets(graph: Any, count: int = 12) -> list[np.ndarray]:
    rng = np.random.default_rng(6)
    nodes = np.asarray(graph.poses, dtype=np.float64)
    sets = [nodes[rng.choice(len(nodes), 30, replace=False)] for _ in range(count)]
    duplicated = sets[0].copy()
    duplicated[10:] = duplicated[0]  # duplicates: the SVD path
    return [*sets, duplicated]


def test_compiled_latent_fit_agrees_with_numpy(graph: Any) -> None:
    for candidates in candidate_sets(graph):
        for max_dim in (20, 5):
            fast = LatentSpace.fit(candidates, max_dim=max_dim, kernel="numba")
            slow = LatentSpace.fit(candidates, max_dim=max_dim, kernel="numpy")
            np.testing.assert_allclose(fast.mean, slow.mean, rtol=0, atol=1e-15)
            np.testing.assert_allclose(fast.std, slow.std, rtol=1e-10)
            np.testing.assert_array_equal(fast.degenerate, slow.degenerate)
            live = ~slow.degenerate
            np.testing.assert_allclose(fast.basis[live], slow.basis[live], rtol=0, atol=1e-7)
            assert fast.explained_variance_ratio == pytest.approx(slow.explained_variance_ratio)


@pytest.mark.parametrize("dtype", [np.float64, np.float32])
@pytest.mark.parametrize("with_target", [True, False])
def test_compiled_energy_setup_and_terms_agree_with_numpy(
    graph: Any, dtype: Any, with_target: bool
) -> None:
    rng = np.random.default_rng(7)
    for candidates in candidate_sets(graph, count=4):
        latent = LatentSpace.fit(candidates, kernel="numpy")
        sensor = candidates[0] + rng.normal(0.0, 0.03, (20, 3))
        target = candidates[1] if with_target else None
        arguments = (
            latent,
            sensor,
            rng.uniform(0.0, 1.0, 20),
            candidates,
            poses.bone_lengths(candidates[2]),
            target,
            EnergyWeights.with_prior(),
            dtype,
        )
        fast, slow = (
            EnergyModel(*arguments, kernel="numba"),
            EnergyModel(*arguments, kernel="numpy"),
        )
        tolerance = 1e-12 if dtype == np.float64 else 1e-5
        for name in ("matrix", "ycst", "b0", "lengths"):
            a, b = getattr(fast.tables, name), getattr(slow.tables, name)
            assert a.dtype == b.dtype == np.dtype(dtype)
            np.testing.assert_allclose(a, b, rtol=tolerance, atol=tolerance * np.abs(b).max())
        assert fast.tables.c0 == pytest.approx(slow.tables.c0, rel=tolerance)
        assert fast.tables.wk == slow.tables.wk
        z = rng.normal(0.0, 1.0, (16, latent.dim))
        fast_terms, slow_terms = fast.terms(z), slow.terms(z)
        for name in TERM_NAMES:
            assert fast_terms[name].dtype == np.float64
            np.testing.assert_allclose(
                fast_terms[name], slow_terms[name], rtol=50 * tolerance, atol=1e-12, err_msg=name
            )
        np.testing.assert_allclose(fast(z), slow(z), rtol=50 * tolerance)


@pytest.mark.parametrize("damping", [1.0, 0.6])
def test_compiled_continuity_equals_numpy_to_the_bit(
    rng: np.random.Generator, damping: float
) -> None:
    """The previous output and the prediction (FPG Eq. 6) of one compiled call: numpy's
    arithmetic around the compiled turn (``place_pose``) to the bit, and the numpy turn to
    rounding (two, one or no previous outputs, a frame without a body, irregular timestamps)."""
    from fpg_gym.reconstruct.temporal import continuity

    for trial in range(20):
        history = [
            (poses.rest_pose() + rng.normal(0.0, 0.3, (skeleton.NUM_JOINTS, 3)), t)
            for t in (0.0, float(rng.uniform(0.0, 0.05)))
        ][: trial % 3]
        args = (history, np.asarray(rng.uniform(-np.pi, np.pi)), float(rng.uniform(0.01, 0.1)))
        for no_body in (False, True):
            got = continuity(*args, no_body, damping)
            with only_compiled(["fpg_gym.core.compiled_poses"]):
                expected = continuity(*args, no_body, damping)
            with numpy_only():
                numpy_path = continuity(*args, no_body, damping)
            for a, b, c in zip(got, expected, numpy_path, strict=True):
                assert (a is None and b is None and c is None) or np.array_equal(a, b)
                if a is not None:
                    np.testing.assert_allclose(a, c, rtol=0, atol=1e-12)


def test_compiled_output_smoother_equals_numpy_to_the_bit(rng: np.random.Generator) -> None:
    """The output stage (the Kalman filter's step, root-relative, retargeted, put back) in one
    compiled call: numpy's operations around the compiled filter and retarget, to the bit, and
    the numpy filter and retarget to rounding."""
    from fpg_gym.reconstruct.temporal import OutputSmoother, TemporalConfig

    smoothers = [OutputSmoother(TemporalConfig()) for _ in range(4)]
    contexts = [
        contextlib.nullcontext,
        lambda: only_compiled(["fpg_gym.core.compiled_poses", "fpg_gym.filters.compiled_filters"]),
        numpy_only,
        lambda: only_compiled(["fpg_gym.reconstruct.compiled_frame"]),  # the warm-up's share
    ]
    for t in range(30):
        pose = poses.rest_pose() + rng.normal(0.0, 0.05, (skeleton.NUM_JOINTS, 3)) + [0, 0, 2]
        lengths = poses.DEFAULT_BONE_LENGTHS * rng.uniform(0.9, 1.1, skeleton.NUM_BONES)
        outputs = []
        for smoother, context in zip(smoothers, contexts, strict=True):
            with context():
                outputs.append(smoother.update(pose, lengths, t / 30.0))
        assert outputs[0].dtype == np.float32
        np.testing.assert_array_equal(outputs[0], outputs[1])
        np.testing.assert_array_equal(outputs[0], outputs[3])
        np.testing.assert_allclose(outputs[0], outputs[2], rtol=0, atol=1e-6)


def test_compiled_output_pose_equals_the_pose_kernels_to_the_bit() -> None:
    """A frame's output pose (retarget, then put back): one compiled call, the same as the
    compiled retarget and placement it chains (to the bit) and the numpy path (to rounding)."""
    from fpg_gym.reconstruct.pending import output_pose

    rng = np.random.default_rng(12)
    for i in range(50):
        local = rng.normal(0.0, 0.4, (20, 3))
        if i % 10 == 0:
            local[5] = local[4]  # a zero-length bone: its rest direction
        lengths = poses.DEFAULT_BONE_LENGTHS * rng.uniform(0.8, 1.2, skeleton.NUM_BONES)
        placement = poses.Placement(root=rng.normal(size=3), yaw=np.asarray(rng.uniform(-3, 3)))
        got = output_pose(local, lengths, placement)
        with only_compiled(["fpg_gym.core.compiled_poses"]):
            chained = output_pose(local, lengths, placement)
        with numpy_only():
            reference = output_pose(local, lengths, placement)
        assert got.dtype == chained.dtype == reference.dtype == np.float32
        np.testing.assert_array_equal(got, chained)
        np.testing.assert_allclose(got, reference, rtol=0, atol=1e-6)

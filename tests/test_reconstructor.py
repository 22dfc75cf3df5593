"""The per-frame pipeline (Reconstructor) and the ``reconstruct`` command."""

from __future__ import annotations

import json
import time
from functools import lru_cache
from types import SimpleNamespace
from typing import ClassVar

import numpy as np
import pytest

import optimizers
from fpg_gym.cli import main
from fpg_gym.core import metrics, poses, skeleton
from fpg_gym.io import Recording, load_default_clips, write_recording
from fpg_gym.methods import ragdoll_factory
from fpg_gym.physics.ragdoll import Ragdoll
from fpg_gym.reconstruct import (
    STAGES,
    TERM_NAMES,
    Reconstructor,
    ReconstructorConfig,
    SearchProblem,
    TemporalConfig,
)

ARM = [skeleton.joint_index(n) for n in ("ElbowLeft", "WristLeft", "HandLeft")]


class KnnGraph:
    """Stand-in for FilteredPoseGraph: node poses and an undirected k-nearest-neighbour CSR."""

    def __init__(self, node_poses: np.ndarray, k: int = 8) -> None:
        self.poses = np.asarray(node_poses, dtype=np.float32)
        n = len(self.poses)
        d = poses.pairwise_pose_distance(self.poses, self.poses)
        np.fill_diagonal(d, np.inf)
        nearest = np.argsort(d, axis=1)[:, :k]
        adjacency = np.zeros((n, n), dtype=bool)
        adjacency[np.repeat(np.arange(n), k), nearest.ravel()] = True
        adjacency |= adjacency.T
        self.indptr = np.concatenate([[0], np.cumsum(adjacency.sum(1))]).astype(np.int64)
        self.indices = np.nonzero(adjacency)[1].astype(np.int32)

    def neighbors_of(self, nodes: np.ndarray) -> np.ndarray:
        parts = [self.indices[self.indptr[i] : self.indptr[i + 1]] for i in nodes]
        return np.unique(np.concatenate(parts))


@lru_cache(maxsize=1)
def graph() -> KnnGraph:
    """Every second frame of the embedded clips (spin held out), normalised."""
    clips = [c for c in load_default_clips() if c.name != "spin"]
    return KnnGraph(np.concatenate([poses.normalise(c.positions)[0][::2] for c in clips]))


def to_camera(positions: np.ndarray) -> np.ndarray:
    """Turn a clip to face the camera and put it 2.5 m away, 1 m below the sensor."""
    rotation = poses.yaw_matrix(np.array(2.0))
    return (positions @ rotation.T + np.array([0.3, -1.0, 2.5])).astype(np.float32)


def recording(
    name: str = "punch", noise: float = 0.01, occlude: bool = True, seed: int = 0
) -> SimpleNamespace:
    clip = next(c for c in load_default_clips() if c.name == name)
    truth = to_camera(clip.positions)
    frames = len(truth)
    rng = np.random.default_rng(seed)
    positions = truth + rng.normal(0.0, noise, truth.shape).astype(np.float32)
    states = np.full((frames, skeleton.NUM_JOINTS), 2, dtype=np.int8)
    if occlude:  # an inferred hand and wrist that the sensor puts 35 cm off
        positions[20:50, ARM[1:]] += np.array([0.0, 0.25, 0.25], dtype=np.float32)
        states[20:50, ARM[1:]] = 1
    return SimpleNamespace(
        positions=positions, states=states, timestamps=np.arange(frames) / 30.0, ground_truth=truth
    )


def test_problem_exposes_what_a_policy_needs() -> None:
    rec = recording()
    r = Reconstructor(graph())
    problem = r.prepare(rec.positions[0], rec.states[0], 0.0)
    assert isinstance(problem, SearchProblem)
    k, d = 30, 20
    assert problem.dim == d == r.latent_dim and r.k == k
    assert problem.kinect_pose.shape == (20, 3)
    assert abs(problem.kinect_pose[skeleton.ROOT]).max() < 1e-6  # normalised
    for name in ("reliability", "behaviour", "kinematic", "tracking"):
        assert getattr(problem, name).shape == (20,)
    assert problem.nodes.shape == (k,) and problem.node_poses.shape == (k, 20, 3)
    assert problem.mean.shape == (60,) and problem.basis.shape == (d, 60)
    assert problem.std.shape == (d,) and problem.z_kinect.shape == (d,)
    assert problem.prediction is None and problem.previous is None  # first frame
    assert problem.context.first and problem.selection.full_search
    # x0 on a first frame is the best candidate (projected into the d = 20 space).
    best = problem.latent.project(problem.node_poses[:1])[0]
    assert np.allclose(problem.decode(problem.x0[None])[0], best, atol=1e-6)
    terms = problem.evaluate_terms(np.zeros((3, d)))
    assert set(terms) == {*TERM_NAMES, "E"} and problem.evaluations == 3
    with pytest.raises(RuntimeError, match="not finished"):
        r.prepare(rec.positions[1], rec.states[1], 1 / 30)
    for bad in (np.full(d, np.nan), np.zeros(d + 1)):
        with pytest.raises(ValueError, match="z: expected 20 finite values"):
            r.finish(bad)
    pose, record = r.finish(problem.x0)
    assert pose.shape == (20, 3) and pose.dtype == np.float32
    assert record.evaluations == 3 and set(record.ms) == {*STAGES, "total"}
    # The record's terms, uncounted (numpy's products round by batch: equal to rounding).
    x0_terms = problem.evaluate_terms(problem.x0, count=False)
    assert record.energy == pytest.approx(float(x0_terms["E"][0]), rel=1e-12, abs=1e-15)
    assert record.energy_x0 == pytest.approx(record.energy, rel=1e-12, abs=1e-15)
    for name in TERM_NAMES:
        assert record.terms[name] == pytest.approx(float(x0_terms[name][0]), rel=1e-12, abs=1e-15)
    with pytest.raises(RuntimeError, match="no prepared frame"):
        r.finish(problem.x0)
    second = r.prepare(rec.positions[1], rec.states[1], 1 / 30)
    assert second.previous is not None and second.z_previous is not None
    assert second.prediction is not None and second.z_prediction is not None
    assert np.allclose(second.x0, second.z_previous)
    assert not second.context.first and not second.selection.full_search
    assert second.context.dt == pytest.approx(1 / 30)


def test_reconstruction_repairs_an_occluded_limb_and_keeps_bone_lengths() -> None:
    rec = recording()
    truth = rec.ground_truth
    lengths = poses.bone_lengths(truth[0])
    r = Reconstructor(graph(), reference_lengths=tuple(lengths))
    result = r.reconstruct(rec, "local-search", rng=0)
    assert result.poses.shape == truth.shape and not result.interrupted
    raw = metrics.frame_error(truth, rec.positions)
    out = metrics.frame_error(truth, result.poses)
    occluded = slice(20, 50)
    assert out[occluded].mean() < 0.85 * raw[occluded].mean()
    assert out.mean() < raw.mean()
    assert np.allclose(poses.bone_lengths(result.poses), lengths, atol=1e-4)
    # Roots follow the sensor (camera space): smoothed by default (issue 15), frame for frame in
    # the papers' pipeline.
    assert np.abs(result.poses[:, skeleton.ROOT] - rec.positions[:, skeleton.ROOT]).max() < 0.05
    papers = Reconstructor(graph(), reference_lengths=tuple(lengths), temporal=TemporalConfig.off())
    head = SimpleNamespace(positions=rec.positions[:10], states=rec.states[:10])
    roots = papers.reconstruct(head, "local-search", rng=0).poses[:, skeleton.ROOT]
    assert np.allclose(roots, rec.positions[:10, skeleton.ROOT], atol=1e-5)
    arrays = result.arrays()
    t = len(truth)
    assert arrays["reliability"].shape == (t, 20) and arrays["ms_per_frame"].shape == (t,)
    assert arrays["nodes"].shape == (t, 30) and arrays["energy_terms"].shape == (t, 5)
    assert arrays["ms_stages"].shape == (t, len(STAGES))
    assert np.all(arrays["evaluations"] <= 2000) and np.all(arrays["energy"] <= arrays["energy_x0"])
    assert arrays["full_search"][0]  # later full searches only through the recovery rule
    assert np.array_equal(arrays["full_search"][1:], arrays["recovered"][1:])
    assert np.all(arrays["reliability"][25:50, ARM[1:]] < 0.05)


def test_search_beats_no_search_and_brute_force_runs() -> None:
    rec = recording(occlude=False)
    errors = {}
    runs = (("graph", "local-search"), ("graph", "none"), ("brute-force", "local-search"))
    for selector, optimizer in runs:
        r = Reconstructor(graph(), selector=selector)
        out = r.reconstruct(rec, optimizer, rng=1)
        errors[selector, optimizer] = metrics.mean_error(rec.ground_truth, out.poses)
        if selector == "brute-force":
            assert all(rec_.num_scored == len(graph().poses) for rec_ in out.records)
    assert errors["graph", "local-search"] < errors["graph", "none"]
    assert errors["brute-force", "local-search"] < errors["graph", "none"]


def test_same_seed_same_output() -> None:
    rec = recording()
    a = Reconstructor(graph()).reconstruct(rec, "local-search", rng=np.random.default_rng(5))
    b = Reconstructor(graph()).reconstruct(rec, "local-search", rng=np.random.default_rng(5))
    c = Reconstructor(graph()).reconstruct(rec, "local-search", rng=np.random.default_rng(6))
    assert np.array_equal(a.poses, b.poses)
    for key in ("nodes", "energy", "evaluations", "reliability"):
        assert np.array_equal(a.arrays()[key], b.arrays()[key])
    assert not np.array_equal(a.poses, c.poses)
    # reset() between streams: a reused reconstructor gives the same output again.
    r = Reconstructor(graph())
    first = r.reconstruct(rec, "local-search", rng=5)
    again = r.reconstruct(rec, "local-search", rng=5)
    assert np.array_equal(first.poses, again.poses)


def test_no_body_frames_and_gaps() -> None:
    rec = recording(occlude=False)
    rec.states[10:14] = 0  # body lost for four frames
    rec.positions[10:14] = 0.0
    rec.timestamps[30:] += 2.0  # a two-second gap
    r = Reconstructor(graph())
    result = r.reconstruct(rec, "local-search", rng=0)
    arrays = result.arrays()
    assert arrays["no_body"][10:14].all() and not arrays["no_body"][14:].any()
    assert np.all(np.isfinite(result.poses))
    held = result.poses[10:14, skeleton.ROOT]
    assert np.allclose(held, result.poses[9, skeleton.ROOT], atol=1e-5)  # placement held
    assert arrays["first"][0] and arrays["first"][30] and arrays["first"].sum() == 2
    assert arrays["full_search"][30]
    errors = metrics.frame_error(rec.ground_truth, result.poses)
    assert errors[10:14].max() < 0.15


def test_ragdoll_stage_with_a_fake() -> None:
    calls: list[tuple[str, np.ndarray]] = []

    class FakeRagdoll:
        info: ClassVar[dict[str, int]] = {"divergences": 0}

        def __init__(self, lengths: np.ndarray) -> None:
            calls.append(("init", lengths))

        def reset(self, pose: np.ndarray) -> np.ndarray:
            calls.append(("reset", pose))
            time.sleep(0.005)  # the ragdoll stage's time must be counted as the ragdoll's
            return pose + 0.01

        def track(self, target: np.ndarray) -> np.ndarray:
            calls.append(("track", target))
            time.sleep(0.005)
            return target + 0.01

        def close(self) -> None:
            calls.append(("close", np.zeros(0)))

    rec = recording()
    lengths = poses.bone_lengths(rec.ground_truth[0])
    r = Reconstructor(graph(), ragdoll=FakeRagdoll, reference_lengths=tuple(lengths))
    plain = Reconstructor(graph(), reference_lengths=tuple(lengths))
    frames = SimpleNamespace(
        positions=rec.positions[:5], states=rec.states[:5], timestamps=rec.timestamps[:5]
    )
    out = r.reconstruct(frames, "none")
    ref = plain.reconstruct(frames, "none")
    kinds = [c[0] for c in calls]
    assert kinds == ["init", "reset", "track", "track", "track", "track"]
    assert np.allclose(calls[0][1], lengths)
    assert np.allclose(out.poses[0], ref.poses[0] + 0.01, atol=1e-5)
    # The ragdoll works above a floor at y = 0: targets are shifted by the lowest joint seen.
    assert calls[1][1][:, 1].min() == pytest.approx(0.0, abs=1e-6)
    assert out.records[0].ragdoll is not None and "floor_y" in out.records[0].ragdoll
    # Every frame slept 5 ms inside the ragdoll: its stage time holds them, and the total too.
    assert all(rec.ms["ragdoll"] >= 5.0 for rec in out.records)
    assert all(rec.ms["total"] >= rec.ms["ragdoll"] for rec in out.records)
    r.close()
    assert calls[-1][0] == "close"


def test_ragdoll_divergences_are_counted_per_frame_across_rebuilds() -> None:
    """``new_divergences`` is each frame's count, also when a rebuild restarts the ragdoll's
    cumulative counter (a new stream rebuilds it)."""

    class Diverging:
        """Diverges on every second tracked frame; ``rebuild`` restarts its counter."""

        def __init__(self, lengths: np.ndarray) -> None:
            self.info = {"divergences": 0}
            self.frames = 0

        def reset(self, pose: np.ndarray) -> np.ndarray:
            return pose

        def track(self, target: np.ndarray) -> np.ndarray:
            self.frames += 1
            self.info["divergences"] += self.frames % 2
            return target

        def rebuild(self, lengths: np.ndarray) -> None:
            self.info = {"divergences": 0}

        def close(self) -> None:
            pass

    rec = recording()
    lengths = poses.bone_lengths(rec.ground_truth[0])
    r = Reconstructor(graph(), ragdoll=Diverging, reference_lengths=tuple(lengths))
    frames = SimpleNamespace(
        positions=rec.positions[:7], states=rec.states[:7], timestamps=rec.timestamps[:7]
    )
    for _ in range(2):  # the second stream starts from a rebuilt (restarted) counter
        out = r.reconstruct(frames, "none")
        new = [record.ragdoll["new_divergences"] for record in out.records if record.ragdoll]
        assert new == [0, 1, 0, 1, 0, 1, 0]


def test_config_validation() -> None:
    with pytest.raises(TypeError, match="unknown setting"):
        Reconstructor(graph(), selektor="graph")
    with pytest.raises(ValueError, match="selector"):
        ReconstructorConfig(selector="nearest")
    r = Reconstructor(graph())
    with pytest.raises(ValueError, match="positions"):
        r.prepare(np.zeros((19, 3)), np.zeros(20))
    with pytest.raises(ValueError, match="states"):
        r.prepare(np.zeros((20, 3)), np.zeros(3))


def test_cli_reconstruct_writes_poses_and_errors(tmp_path, capsys) -> None:

    rec = recording(occlude=True)
    frames = 30
    path = write_recording(
        tmp_path / "rec.npz",
        Recording(
            positions=rec.positions[:frames],
            states=rec.states[:frames],
            timestamps=rec.timestamps[:frames],
            ground_truth=rec.ground_truth[:frames],
            metadata={"source": "test"},
        ),
    )
    out = tmp_path / "out.npz"
    code = main(
        ["reconstruct", "--graph", "default", "--input", str(path), "--out", str(out),
         "--no-ragdoll", "--seed", "3", "--budget", "500", "--json"]
    )  # fmt: skip
    assert code == 0
    lines = capsys.readouterr().out.strip().splitlines()
    summary = json.loads(lines[-1])
    for key in ("frames", "raw_mean_error_m", "mean_error_m", "raw_err02_pct", "err02_pct",
                "ms_per_frame_median", "ms_per_frame_p95"):  # fmt: skip
        assert summary[key] is not None, key
    assert summary["frames"] == frames and summary["evaluations_mean"] <= 500
    assert any("error histogram" in line for line in lines)
    with np.load(out, allow_pickle=False) as data:
        assert data["poses"].shape == (frames, 20, 3)
        assert data["reliability"].shape == (frames, 20)
        assert data["ms_per_frame"].shape == (frames,)
        assert data["frame_error"].shape == (frames,)
        assert json.loads(str(data["metadata"]))["seed"] == 3
        assert summary["mean_error_m"] == pytest.approx(float(data["frame_error"].mean()))
    code = main(["reconstruct", "--graph", "default", "--input", str(path), "--out", str(out),
                 "--optimizer", "nope", "--no-ragdoll"])  # fmt: skip
    assert code == 2
    assert "unknown optimizer" in capsys.readouterr().err


def test_left_right_confusions_are_undone_by_continuity() -> None:
    rec = recording(occlude=False, noise=0.005)
    swapped = slice(30, 45)  # the sensor reports the body mirrored (labels swapped)
    rec.positions[swapped] = rec.positions[swapped][:, skeleton.MIRROR_PERMUTATION]
    rec.states[swapped] = rec.states[swapped][:, skeleton.MIRROR_PERMUTATION]
    fixed = Reconstructor(graph()).reconstruct(rec, "local-search", rng=0)
    plain = Reconstructor(graph(), left_right_fix=False).reconstruct(rec, "local-search", rng=0)
    labels = fixed.arrays()["labelling"]
    assert np.all(labels[swapped] == 1) and np.all(labels[:30] == 0) and np.all(labels[45:] == 0)
    assert [r.labelling for r in fixed.records[30:32]] == ["mirrored", "mirrored"]
    err_fixed = metrics.frame_error(rec.ground_truth, fixed.poses)[swapped].mean()
    err_plain = metrics.frame_error(rec.ground_truth, plain.poses)[swapped].mean()
    assert err_fixed < 0.5 * err_plain


def test_pickled_reconstructor_continues_identically() -> None:
    import pickle

    rec = recording()
    a = Reconstructor(graph())
    rng_a = np.random.default_rng(3)
    for t in range(10):
        a.reconstruct_frame(
            rec.positions[t], rec.states[t], rec.timestamps[t], "local-search", rng_a
        )
    b = pickle.loads(pickle.dumps(a))
    rng_b = pickle.loads(pickle.dumps(rng_a))
    for t in range(10, 15):
        pa, _ = a.reconstruct_frame(
            rec.positions[t], rec.states[t], rec.timestamps[t], "local-search", rng_a
        )
        pb, _ = b.reconstruct_frame(
            rec.positions[t], rec.states[t], rec.timestamps[t], "local-search", rng_b
        )
        assert np.array_equal(pa, pb)


def test_reset_makes_a_stream_independent_of_earlier_ones() -> None:
    """Reconstructing a stream after another equals reconstructing it on a fresh instance,
    ragdoll included (no cached database or physics state carried over)."""
    from fpg_gym.graph import FilteredPoseGraph
    from fpg_gym.io import load_default_clips
    from fpg_gym.simulate import simulate

    clips = load_default_clips(["walk", "punch", "run", "kick"])
    graph = FilteredPoseGraph.build(clips[2:], thres1=0.05, progress=False)
    first = simulate(clips[0], "front-many", seed=1)
    second = simulate(clips[1], "front-many", seed=2)
    used = Reconstructor(graph, ragdoll=Ragdoll)
    used.reconstruct(first, "local-search", rng=0, progress=False)
    again = used.reconstruct(second, "local-search", rng=0, progress=False)
    fresh = Reconstructor(graph, ragdoll=Ragdoll).reconstruct(
        second, "local-search", rng=0, progress=False
    )
    np.testing.assert_array_equal(again.poses, fresh.poses)


def test_the_ragdoll_is_injected_not_imported() -> None:
    """The reconstruction layer takes a ragdoll factory; a bare ``True`` (which it could only
    resolve by importing physics) is refused with the fix, which the layer above provides."""
    with pytest.raises(TypeError, match=r"ragdoll: expected a factory.*ragdoll_factory\(True\)"):
        Reconstructor(graph(), ragdoll=True)
    assert ragdoll_factory(True) is Ragdoll
    assert ragdoll_factory(False) is None and ragdoll_factory(None) is None
    assert ragdoll_factory(SimpleNamespace) is SimpleNamespace


class BareStream:
    """The least a stream needs (:class:`fpg_gym.core.poses.RecordingLike`): no timestamps."""

    def __init__(self, positions: np.ndarray, states: np.ndarray) -> None:
        self._positions, self._states = positions, states

    @property
    def positions(self) -> np.ndarray:
        return self._positions

    @property
    def states(self) -> np.ndarray:
        return self._states


def test_a_bare_recording_like_stream_runs_at_frame_dt() -> None:
    rec = recording(occlude=False)
    bare = BareStream(rec.positions[:12], rec.states[:12])
    assert isinstance(bare, poses.RecordingLike) and isinstance(rec, poses.RecordingLike)
    assert not isinstance(object(), poses.RecordingLike)
    r = Reconstructor(graph())
    stamped = SimpleNamespace(
        positions=bare.positions, states=bare.states, timestamps=np.arange(12) * r.config.frame_dt
    )
    a = r.reconstruct(bare, "local-search", rng=2)
    b = r.reconstruct(stamped, "local-search", rng=2)
    assert a.poses.shape == (12, skeleton.NUM_JOINTS, 3)
    assert np.array_equal(a.poses, b.poses)
    # Other timestamps change the continuity terms, so the stamps are really read.
    slow = SimpleNamespace(positions=bare.positions, states=bare.states, timestamps=np.arange(12))
    assert not np.array_equal(a.poses, r.reconstruct(slow, "local-search", rng=2).poses)


@pytest.mark.parametrize("numpy_twin", [False, True])
def test_left_right_costs_are_their_definition_in_each_twin(numpy_twin: bool) -> None:
    """Each labelling's cost, the compiled twin's (when numba is installed) and the numpy one's,
    against its definition written out joint by joint: the tracking-weighted mean distance
    (tracked 1, inferred 0.5, not tracked 0) of the relabelled root-relative sensor joints to
    the root-relative prediction."""
    import contextlib

    from fpg_gym.core.compiled import numpy_only
    from fpg_gym.reconstruct.left_right import LABEL_PERMUTATIONS, left_right_costs

    rng = np.random.default_rng(3)
    for _ in range(20):
        positions = rng.normal(0.0, 0.4, (20, 3)) + np.array([0.0, 1.0, 2.5])
        prediction = positions + rng.normal(0.0, 0.05, (20, 3))
        states = rng.choice([0, 1, 2], 20).astype(np.int8)
        with numpy_only() if numpy_twin else contextlib.nullcontext():
            costs = left_right_costs(positions, states, prediction)
        weight = {0: 0.0, 1: 0.5, 2: 1.0}
        for labelling, permutation in enumerate(LABEL_PERMUTATIONS):
            total = count = 0.0
            for j, source in enumerate(permutation):
                w = weight[int(states[source])]
                sensor = positions[source] - positions[skeleton.ROOT]
                target = prediction[j] - prediction[skeleton.ROOT]
                total += w * float(np.linalg.norm(sensor - target))
                count += w
            assert costs[labelling] == pytest.approx(total / max(count, 1e-9), rel=1e-12)


def test_an_interrupt_a_compiled_call_swallowed_still_keeps_the_frames_done(
    monkeypatch: pytest.MonkeyPatch, capsys: pytest.CaptureFixture[str]
) -> None:
    """A signal handler's KeyboardInterrupt raised while a numba call runs Python code on its
    way out reaches the caller as ``SystemError`` with the interrupt as its cause; the run path
    treats it as the interrupt (the frames done are kept), and the command line exits 130."""
    from fpg_gym.core.errors import interrupt_in
    from fpg_gym.reconstruct.streams import Stream, reconstruct_stream, search_streams

    rec = recording()

    def swallowing(problems, streams):  # the way numba's dispatcher reports it
        if streams[0].next == 5:
            try:
                raise KeyboardInterrupt("signal 15")
            except KeyboardInterrupt as interrupt:
                raise SystemError(
                    "CPUDispatcher(...) returned a result with an exception set"
                ) from interrupt
        return search_streams(problems, streams)

    reconstructor = Reconstructor(graph())
    stream = Stream(reconstructor, rec, optimizers.make("local-search"), np.random.default_rng(0))
    result = reconstruct_stream(stream, swallowing, stop_on_interrupt=True)
    assert result.interrupted and result.num_frames == 5
    with pytest.raises(KeyboardInterrupt):
        reconstruct_stream(
            Stream(reconstructor, rec, optimizers.make("local-search"), np.random.default_rng(0)),
            swallowing,
        )
    # Only an interrupt counts: another SystemError, or one caused by something else, does not.
    assert interrupt_in(SystemError("x")) is None
    other = SystemError("x")
    other.__cause__ = ValueError("y")
    assert interrupt_in(other) is None
    assert interrupt_in(ValueError("y")) is None

    def interrupted_command(args: object) -> int:
        swallowing([], [SimpleNamespace(next=5)])
        return 0

    import fpg_gym.commands.reconstruct as command

    monkeypatch.setattr(command, "run", interrupted_command)
    assert main(["reconstruct", "--input", "x.npz", "--out", "y.npz"]) == 130
    assert "interrupted" in capsys.readouterr().err

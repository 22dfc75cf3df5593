"""Temporal coherence (issue 15): lag and settled bone-spread metrics, the One-Euro filter, the
aligned latent basis, the bone settling rule and the pipeline on small synthetic streams."""

from __future__ import annotations

import contextlib
from types import SimpleNamespace

import numpy as np
import pytest
from test_reconstructor import graph, recording, to_camera

from fpg_gym.core import metrics, poses, skeleton
from fpg_gym.filters import make_filter
from fpg_gym.methods import ragdoll_factory
from fpg_gym.reconstruct import (
    BoneSettler,
    BoneSettlingConfig,
    LatentSpace,
    Reconstructor,
    TemporalConfig,
    align_basis,
)

FPS = 30.0


def moving_clip(frames: int = 90, speed: float = 0.6) -> np.ndarray:
    """The rest pose walking sideways at ``speed`` m/s while its arms swing (camera space)."""
    t = np.arange(frames) / FPS
    base = poses.rest_pose().astype(np.float64)
    clip = np.repeat(base[None], frames, axis=0)
    clip[:, :, 0] += speed * t[:, None]
    swing = 0.15 * np.sin(2.0 * np.pi * 0.8 * t)
    for name in ("ElbowLeft", "WristLeft", "HandLeft"):
        clip[:, skeleton.joint_index(name), 2] += swing
    return clip


# --------------------------------------------------------------------------- metrics


def test_lag_finds_a_known_shift_in_either_direction() -> None:
    truth = moving_clip()
    for shift in (0, 2, 5):
        late = np.concatenate([np.repeat(truth[:1], shift, axis=0), truth[: len(truth) - shift]])
        assert metrics.lag(late, truth) == pytest.approx(shift, abs=0.05)
        assert metrics.lag(truth, late) == pytest.approx(-shift, abs=0.05)


def test_lag_of_a_constant_velocity_ramp_is_exact_and_sub_frame() -> None:
    # A ramp is the case a plain (unnormalised) cross-correlation gets wrong.
    t = np.arange(60) / FPS
    truth = np.repeat(poses.rest_pose()[None].astype(np.float64), 60, axis=0)
    truth += (0.9 * t)[:, None, None] * np.array([1.0, 0.0, 0.3])
    half = truth - 0.5 * (truth[1] - truth[0])  # half a frame late
    assert metrics.lag(half, truth) == pytest.approx(0.5, abs=0.1)


def test_lag_is_robust_to_noise_and_checks_its_input() -> None:
    rng = np.random.default_rng(0)
    truth = moving_clip()
    noisy = truth + rng.normal(0.0, 0.01, truth.shape)
    assert abs(metrics.lag(noisy, truth)) < 0.3
    with pytest.raises(ValueError, match="differ"):
        metrics.lag(truth[:10], truth)
    assert np.isnan(metrics.lag(truth[:3], truth[:3]))
    short = truth[:8]  # shorter than the default search: the shifts shrink to keep 3 frames
    assert metrics.lag(np.concatenate([short[:1], short[:-1]]), short) == pytest.approx(
        1.0, abs=0.05
    )


def test_lag_leaves_out_every_pair_with_an_invalid_frame() -> None:
    """``valid`` (e.g. frames with a body): a pair of frames counts only when both are valid.
    Garbage in the invalid frames of either stream, at either end of a pair, leaves the lag
    unchanged to the bit; without the mask it moves it."""
    truth = moving_clip()
    shift = 3
    late = np.concatenate([np.repeat(truth[:1], shift, axis=0), truth[: len(truth) - shift]])
    valid = np.ones(len(truth), dtype=bool)
    valid[10::9] = False
    clean = metrics.lag(late, truth, valid=valid)
    assert clean == pytest.approx(shift, abs=0.05)
    rng = np.random.default_rng(5)
    far_late, far_truth = late.copy(), truth.copy()
    far_late[~valid] += rng.uniform(-3.0, 3.0, (int((~valid).sum()), 1, 3))
    far_truth[~valid] += rng.uniform(-3.0, 3.0, (int((~valid).sum()), 1, 3))
    for estimate, reference in ((far_late, truth), (late, far_truth), (far_late, far_truth)):
        assert metrics.lag(estimate, reference, valid=valid) == clean
        assert metrics.lag(estimate, reference) != clean


def test_settled_bone_spread_ignores_the_first_second() -> None:
    clip = moving_clip(frames=90)
    lengths = poses.bone_lengths(clip[0])
    grown = np.repeat(lengths[None], 90, axis=0)
    grown[:30] *= np.linspace(0.8, 1.0, 30)[:, None]  # settling in the first second
    stream = poses.retarget(clip, grown)
    assert np.nanmax(metrics.settled_bone_spread(stream)) < 1e-5
    late = grown.copy()
    late[60:, 3] += 0.01  # one bone grows by 1 cm at 2 s
    spread = metrics.settled_bone_spread(poses.retarget(clip, late))
    assert spread[3] == pytest.approx(0.01, abs=1e-5)
    assert np.all(np.isnan(metrics.settled_bone_spread(stream[:20])))


# --------------------------------------------------------------------------- One-Euro filter


def test_one_euro_quiets_a_static_joint_and_follows_a_fast_one() -> None:
    rng = np.random.default_rng(1)
    static = np.zeros((120, 2, 3)) + rng.normal(0.0, 0.01, (120, 2, 3))
    out = make_filter("one-euro").filter_sequence(static)
    assert out[30:].std() < 0.4 * static[30:].std()
    ramp = np.zeros((60, 1, 3))
    ramp[:, 0, 0] = 2.0 * np.arange(60) / FPS  # 2 m/s
    slow = make_filter("one-euro", beta=0.0).filter_sequence(ramp)
    fast = make_filter("one-euro", beta=4.0).filter_sequence(ramp)
    lag_slow = np.abs(slow[-1, 0, 0] - ramp[-1, 0, 0])
    lag_fast = np.abs(fast[-1, 0, 0] - ramp[-1, 0, 0])
    assert lag_fast < 0.25 * lag_slow


def test_one_euro_rejects_bad_parameters() -> None:
    with pytest.raises(ValueError, match="min_cutoff"):
        make_filter("one-euro", min_cutoff=0.0)
    with pytest.raises(ValueError, match="preset"):
        make_filter("one-euro:nope")


# --------------------------------------------------------------------------- latent basis


def test_aligned_basis_gives_the_same_latent_point_the_same_meaning() -> None:
    candidates = np.asarray(graph().poses[:30], dtype=np.float64)
    space = LatentSpace.fit(candidates, max_dim=10)
    signs = np.where(np.arange(space.dim) % 2 == 0, -1.0, 1.0)  # the SVD's arbitrary signs
    flipped = LatentSpace(
        space.mean,
        space.basis * signs[:, None],
        space.std,
        space.degenerate,
        space.explained_variance_ratio,
    )
    z = np.random.default_rng(2).normal(size=(5, space.dim))
    assert not np.allclose(flipped.decode(z), space.decode(z), atol=1e-3)
    aligned = align_basis(flipped, space)
    assert np.allclose(aligned.basis, space.basis)
    assert np.allclose(aligned.decode(z), space.decode(z))
    # Flips change no expressible pose: the projection of any pose is the same.
    assert np.allclose(flipped.project(candidates), space.project(candidates))
    assert align_basis(space, None) is space


# --------------------------------------------------------------------------- bone settling


def test_bone_settler_follows_then_bounds_the_change() -> None:
    cfg = BoneSettlingConfig(settle_s=1.0, max_spread_m=0.004, max_rate_m_s=0.002)
    settler = BoneSettler(cfg)
    base = poses.bone_lengths(poses.rest_pose())
    out = []
    for i in range(150):
        estimate = base * (0.9 if i < 20 else 1.0)  # a fast first estimate corrected early
        if i >= 90:
            estimate = estimate + 0.03  # a late calibration 3 cm longer on every bone
        out.append(settler.update(estimate, i / FPS))
    lengths = np.array(out)
    assert np.allclose(lengths[25], base)  # still settling: follows the estimate
    after = lengths[30:]
    assert np.max(after.max(axis=0) - after.min(axis=0)) <= 0.004 + 1e-12
    assert np.all(np.diff(after, axis=0) <= 0.002 / FPS + 1e-12)
    report = settler.report()
    assert report["settled_at_s"] == pytest.approx(1.0)
    assert report["changes_after_settling"] > 0 and report["max_spread_mm"] <= 4.0 + 1e-9
    off = BoneSettler(BoneSettlingConfig(enabled=False))
    assert np.allclose(off.update(base + 0.03, 5.0), base + 0.03)


def test_bone_settler_compiled_step_gives_the_numpy_lengths_and_events() -> None:
    """The settled step compiled (``compiled_frame.settle_lengths``) against its numpy code: the
    same lengths, ranges and events to the bit, on noisy estimates that hit both bounds."""
    from fpg_gym.core.compiled import numpy_only

    rng = np.random.default_rng(5)
    base = poses.bone_lengths(poses.rest_pose())
    estimates = base + np.cumsum(rng.normal(0.0, 0.002, (200, len(base))), axis=0)
    runs = []
    for hidden in (False, True):
        with numpy_only() if hidden else contextlib.nullcontext():
            settler = BoneSettler()
            out = [
                settler.update(e, i / FPS + 0.01 * (i % 3 == 0)) for i, e in enumerate(estimates)
            ]
            runs.append((np.array(out), settler.report(), settler.events))
    np.testing.assert_array_equal(runs[0][0], runs[1][0])
    assert runs[0][1] == runs[1][1] and runs[0][2] == runs[1][2]
    assert runs[0][1]["max_spread_mm"] == pytest.approx(4.0)  # the bound was reached
    assert runs[0][1]["changes_after_settling"] > 50


# --------------------------------------------------------------------------- the pipeline


def stream(clip: np.ndarray, noise: float, seed: int) -> SimpleNamespace:
    """A fully tracked sensor stream of a camera-space clip with white noise."""
    truth = clip.astype(np.float32)
    rng = np.random.default_rng(seed)
    positions = truth + rng.normal(0.0, noise, truth.shape).astype(np.float32)
    frames = len(truth)
    return SimpleNamespace(
        positions=positions,
        states=np.full((frames, skeleton.NUM_JOINTS), 2, dtype=np.int8),
        timestamps=np.arange(frames) / FPS,
        ground_truth=truth,
    )


def static_stream(seed: int = 0) -> SimpleNamespace:
    pose = np.asarray(graph().poses[100], dtype=np.float64)
    return stream(to_camera(np.repeat(pose[None], 90, axis=0)), 0.01, seed)


@pytest.mark.parametrize("seed", [0, 1])
def test_static_pose_with_sensor_noise_comes_out_nearly_static(seed: int) -> None:
    rec = static_stream(seed)
    papers = Reconstructor(graph(), temporal=TemporalConfig.off())
    default = Reconstructor(graph())
    before = papers.reconstruct(rec, "local-search", rng=seed).poses
    after = default.reconstruct(rec, "local-search", rng=seed).poses
    raw_jitter = np.nanmean(metrics.jitter(rec.positions))
    jitter_before = np.nanmean(metrics.jitter(before[10:]))
    jitter_after = np.nanmean(metrics.jitter(after[10:]))
    assert jitter_after < 0.5 * raw_jitter
    assert jitter_after < 0.6 * jitter_before
    truth = rec.ground_truth
    assert metrics.mean_error(truth, after) <= 1.05 * metrics.mean_error(truth, before)


def test_constant_velocity_motion_comes_out_without_lag() -> None:
    # The sensor's own pose on a body walking sideways at 1 m/s, facing the camera.
    pose = np.asarray(graph().poses[100], dtype=np.float64)
    t = np.arange(90) / FPS
    clip = to_camera(np.repeat(pose[None], 90, axis=0)).astype(np.float64)
    clip += (1.0 * t)[:, None, None] * np.array([1.0, 0.0, 0.0])
    rec = stream(clip, 0.005, 3)
    out = Reconstructor(graph()).reconstruct(rec, "local-search", rng=0).poses
    assert abs(metrics.lag(out, rec.ground_truth)) <= 1.0


@pytest.mark.parametrize("ragdoll", [False, True])
def test_bone_lengths_settle_with_and_without_the_ragdoll(ragdoll: bool) -> None:

    rec = recording("punch", noise=0.02, occlude=True, seed=4)
    with Reconstructor(graph(), ragdoll=ragdoll_factory(ragdoll)) as r:
        result = r.reconstruct(rec, "local-search", rng=0)
    spread = metrics.settled_bone_spread(result.poses, timestamps=rec.timestamps)
    assert np.nanmax(spread) <= 0.005
    assert result.bones["settled_at_s"] == pytest.approx(1.0, abs=1 / FPS)
    lengths = result.arrays()["bone_lengths"]
    assert lengths.shape == (len(rec.positions), skeleton.NUM_BONES)
    # The papers' reference lengths move with every calibration frame (no settling rule).
    with Reconstructor(
        graph(), ragdoll=ragdoll_factory(ragdoll), bones=BoneSettlingConfig(enabled=False)
    ) as r:
        loose = r.reconstruct(rec, "local-search", rng=0).arrays()["bone_lengths"]
    assert np.ptp(loose[30:], axis=0).max() > np.ptp(lengths[30:], axis=0).max()


@pytest.mark.parametrize(
    ("changes", "message"),
    [
        ({"velocity_damping": 1.5}, "velocity_damping"),
        ({"motion_scale": -1.0}, "motion_scale"),
        ({"root_min_cutoff": 0.0}, "root_min_cutoff"),
    ],
)
def test_temporal_config_rejects_bad_values(changes: dict[str, float], message: str) -> None:
    with pytest.raises(ValueError, match=message):
        TemporalConfig(**changes)  # type: ignore[arg-type]
    with pytest.raises(ValueError, match="max_spread_m"):
        BoneSettlingConfig(max_spread_m=-0.001)


def test_papers_pipeline_is_every_switch_off() -> None:
    rec = static_stream(0)
    papers = Reconstructor(graph(), temporal=TemporalConfig.off())
    result = papers.reconstruct(rec, "local-search", rng=0)
    # The papers' Em weight reaches the problem as is; the default scales it by 8.
    assert papers.prepare(rec.positions[0], rec.states[0], 9.0).weights.motion == 0.25
    default = Reconstructor(graph())
    assert default.prepare(rec.positions[0], rec.states[0], 0.0).weights.motion == 2.0
    # Without the placement stage the output root is the sensor's, frame for frame.
    assert np.allclose(result.poses[:, skeleton.ROOT], rec.positions[:, skeleton.ROOT], atol=1e-5)

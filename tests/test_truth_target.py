"""The supervised ``truth`` target lies in the problem's frame, also on the frames whose
heading the reconstructor does not take from the raw sensor pose (left/right relabelled, no
body), and the cheap ``follow`` modes of the imitation data."""

from __future__ import annotations

from typing import Any

import numpy as np
import pytest

from fpg_gym.core import metrics, skeleton
from fpg_gym.core import poses as pose_utils
from fpg_gym.io import load_default_clips
from fpg_gym.io.recording import Recording
from fpg_gym.reconstruct import Reconstructor, TemporalConfig
from policies.sampler import SamplerSpec
from policies.training import collect_imitation_data, truth_latent

#: A supervised sampler of the env's default layout (20 latent axes, 30 candidates).
SPEC = SamplerSpec.for_layout("supervised", "mlp", action_mode="absolute")
SWAPPED = (12, 13, 14, 27, 28)  # frames whose sensor labels are left/right mirrored
NO_BODY = (20, 21)  # frames without a body


def _recording() -> Recording:
    """A walk whose sensor is the truth, with mirrored labels and lost frames."""
    clip = load_default_clips(["walk"])[0]
    truth = clip.positions[:36].astype(np.float32)
    sensor = truth.copy()
    for t in SWAPPED:
        sensor[t] = truth[t][skeleton.MIRROR_PERMUTATION]
    states = np.full((len(truth), skeleton.NUM_JOINTS), skeleton.TRACKED, np.int8)
    for t in NO_BODY:
        states[t] = 0
        sensor[t] = 0.0
    timestamps = np.arange(len(truth)) / 30.0
    return Recording(sensor, states, timestamps, ground_truth=truth)


def _target_errors(graph: Any, recording: Recording) -> tuple[np.ndarray, np.ndarray]:
    """Per frame: Eq. 13 error of the pose the truth target selects, with the reconstructor's
    placement (the fix) and with the raw sensor pose's (the old target)."""
    truth = recording.ground_truth
    assert truth is not None
    new, old = [], []
    reconstructor = Reconstructor(graph, ragdoll=False, temporal=TemporalConfig.off())
    try:
        for t in range(recording.num_frames):
            problem = reconstructor.prepare(
                recording.positions[t], recording.states[t], float(recording.timestamps[t])
            )
            placement = reconstructor.placement
            assert placement is not None
            z = truth_latent(problem, placement, truth[t])
            _, raw = pose_utils.normalise(recording.positions[t])
            z_old = problem.encode(pose_utils.into_placement(truth[t], raw))
            for target, out in ((z, new), (z_old, old)):
                pose = pose_utils.denormalise(problem.decode(target[None])[0], placement)
                out.append(float(metrics.frame_error(truth[t][None], pose[None])[0]))
            reconstructor.finish(z)
    finally:
        reconstructor.close()
    return np.array(new), np.array(old)


def test_truth_target_follows_the_reconstructors_heading(graph: Any) -> None:
    recording = _recording()
    new, old = _target_errors(graph, recording)
    odd = np.array(SWAPPED + NO_BODY)
    normal = np.setdiff1d(np.arange(recording.num_frames), odd)
    # On ordinary frames both targets are the same point.
    np.testing.assert_allclose(new[normal[1:]], old[normal[1:]], atol=0.02)
    # On the relabelled and lost frames the old target turns the pose away (decimetres of
    # error); the fixed one stays as close to the truth as on ordinary frames.
    assert np.median(new[odd]) < 1.5 * np.median(new[normal]) + 0.01
    assert np.median(old[odd]) > 3.0 * np.median(new[odd])


def test_follow_modes_need_no_search_and_check_their_arguments(graph: Any) -> None:
    recording = _recording()
    spec = SPEC
    data = collect_imitation_data(graph, [recording], spec, target="truth", follow="anchor")
    assert len(data) == recording.num_frames
    assert np.all(np.isfinite(data.actions))
    teacher = collect_imitation_data(graph, [recording], spec, target="truth", follow="truth")
    # Same first frame (nothing followed yet), then other histories.
    np.testing.assert_allclose(teacher.observations[0], data.observations[0])
    assert not np.allclose(teacher.observations[5:], data.observations[5:])
    with pytest.raises(ValueError, match="follow"):
        collect_imitation_data(graph, [recording], spec, target="best", follow="anchor")
    with pytest.raises(ValueError, match="follow"):
        collect_imitation_data(graph, [recording], spec, target="truth", follow="nope")


def test_train_config_checks_follow_and_reward() -> None:
    from policies.training import TrainConfig

    assert TrainConfig(kind="supervised", out="m", target="truth", follow="anchor").follow == (
        "anchor"
    )
    with pytest.raises(ValueError, match="follow"):
        TrainConfig(kind="supervised", out="m", target="best", follow="anchor")
    with pytest.raises(ValueError, match="reward"):
        TrainConfig(kind="rl", out="m", reward="smile")


def test_bones_target_scores_better_after_the_retarget(graph: Any) -> None:
    """The ``bones`` metric picks the latent point whose bone directions, at the frame's bone
    lengths, are the truth's: after the reconstructor's retarget Eq. 13 scores it better than
    the projected joints on average."""
    recording = _recording()
    truth = recording.ground_truth
    assert truth is not None
    errors: dict[str, list[float]] = {"joints": [], "bones": []}
    normal = [t for t in range(recording.num_frames) if t not in SWAPPED + NO_BODY]
    with Reconstructor(graph, ragdoll=False, temporal=TemporalConfig.off()) as reconstructor:
        for t in range(recording.num_frames):
            problem = reconstructor.prepare(
                recording.positions[t], recording.states[t], float(recording.timestamps[t])
            )
            placement = reconstructor.placement
            assert placement is not None
            for metric, out in errors.items():
                z = truth_latent(problem, placement, truth[t], metric)
                local = pose_utils.retarget(problem.decode(z[None])[0], problem.lengths)
                pose = pose_utils.denormalise(local, placement)
                out.append(float(metrics.frame_error(truth[t][None], pose[None])[0]))
            reconstructor.finish()
    joints, bones = np.array(errors["joints"])[normal], np.array(errors["bones"])[normal]
    assert bones.mean() < joints.mean()
    with pytest.raises(ValueError, match="metric"):
        truth_latent(problem, placement, truth[0], "angles")

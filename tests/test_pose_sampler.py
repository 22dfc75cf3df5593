"""The linear pose-space sampler (:mod:`policies.pose_sampler`): it learns a sensor's
systematic offset from the truth, in the pose, and its files are arrays and JSON only."""

from __future__ import annotations

from pathlib import Path
from typing import Any

import numpy as np
import pytest

from fpg_gym.core import metrics, skeleton
from fpg_gym.core import poses as pose_utils
from fpg_gym.core.errors import DataFormatError
from fpg_gym.io import load_default_clips
from fpg_gym.io.recording import Recording
from fpg_gym.reconstruct import Reconstructor, TemporalConfig
from fpg_gym.reconstruct.output_correction import (
    corrected_outputs,
    correction_features,
    smooth_corrections,
)
from policies.learned_optimizers import LearnedSampler
from policies.loading import load_sampler
from policies.output_correction import (
    CorrectionSource,
    RidgeOutputCorrection,
    correction_data,
    learn_correction,
)
from policies.pose_sampler import LINEAR_FEATURES, LinearPoseSampler, fit_linear
from policies.ridge import fit_ridge, ridge_sums
from policies.sampler import SamplerSpec
from policies.training import collect_imitation_data

#: The simulated sensor's systematic error: the head 7 cm forward of the truth's, in the
#: body's own frame (the kind of offset a Kinect's joint centres have from Vicon's).
HEAD = skeleton.JOINT_NAMES.index("Head")
FORWARD = 0.07


def _spec() -> SamplerSpec:
    return SamplerSpec.for_layout(
        "linear", "ridge", action_mode="absolute", features=list(LINEAR_FEATURES)
    )


def _recording(name: str, frames: int = 90) -> Recording:
    """A clip whose sensor is its truth with the head moved forward."""
    truth = load_default_clips([name])[0].positions[:frames].astype(np.float32)
    local, placement = pose_utils.normalise(truth)
    local = np.array(local, dtype=np.float64)
    local[:, HEAD, 2] += FORWARD  # +Z is forward in the normalised frame
    sensor = pose_utils.denormalise(local, placement).astype(np.float32)
    states = np.full((len(truth), skeleton.NUM_JOINTS), skeleton.TRACKED, np.int8)
    return Recording(sensor, states, np.arange(len(truth)) / 30.0, ground_truth=truth)


def _groups(graph: Any) -> list[tuple[np.ndarray, np.ndarray, np.ndarray]]:
    """Imitation data of three clips, one cross-validation group each."""
    groups = []
    for name in ("run", "jump", "dance_a"):
        data = collect_imitation_data(
            graph,
            [_recording(name)],
            _spec(),
            target="bones",
            follow="anchor",
            reconstructor_options={"temporal": TemporalConfig.off()},
        )
        groups.append((data.observations, data.actions, data.episodes))
    return groups


def _fit(groups: list[tuple[np.ndarray, np.ndarray, np.ndarray]]) -> LinearPoseSampler:
    spec = _spec()
    sampler, report = fit_linear(spec, groups)
    assert report["frames"] == sum(len(g[0]) for g in groups) and report["groups"] == 3
    chosen = report["cv_error"][f"{report['penalty']:g}"]
    assert chosen < report["anchor_error"]
    assert sampler.spec.hyperparameters["penalty"] == report["penalty"]
    # The pose weight: the most accurate of those whose means shake no more than the anchor's.
    weight = sampler.pose_weight
    assert weight == report["pose_weight"] and f"{weight:g}" in report["cv_pose"]
    steady = {w: r for w, r in report["cv_pose"].items() if r["shake"] <= report["anchor_shake"]}
    if steady:
        assert f"{weight:g}" in steady
        assert steady[f"{weight:g}"]["error"] == min(r["error"] for r in steady.values())
    return sampler


@pytest.fixture(scope="module")
def groups(graph: Any) -> list[tuple[np.ndarray, np.ndarray, np.ndarray]]:
    return _groups(graph)


@pytest.fixture(scope="module")
def sampler(groups: Any) -> LinearPoseSampler:
    return _fit(groups)


def _error(graph: Any, optimizer: Any, recording: Recording) -> float:
    with Reconstructor(graph, ragdoll=False, temporal=TemporalConfig.off()) as reconstructor:
        poses = reconstructor.reconstruct(recording, optimizer, rng=0).poses
    assert recording.ground_truth is not None
    return float(metrics.frame_error(recording.ground_truth, poses).mean())


def test_the_sampler_removes_a_systematic_sensor_offset(graph: Any, sampler: Any) -> None:
    held_out = _recording("walk")  # neither in the graph nor trained or validated on
    anchor = _error(graph, "closed-form", held_out)
    # The offset moves one bone of 19 by at most FORWARD: that much of Eq. 13 is its share.
    share = FORWARD / skeleton.NUM_BONES
    mean = _error(graph, LearnedSampler(sampler, samples=1), held_out)
    assert anchor - mean > 0.4 * share
    # learned: picks by posterior (the model's selection), near the mean; the lowest energy
    # picks points back towards the anchor, which fits the sensor.
    learned = _error(graph, LearnedSampler(sampler), held_out)
    by_energy = _error(graph, LearnedSampler(sampler, prior_weight=0.0, anchor=True), held_out)
    assert anchor - learned > 0.4 * share
    assert by_energy > learned


def test_fit_linear_checks_its_arguments() -> None:
    spec = _spec()
    rows = np.zeros((4, spec.observation_size), np.float32)
    actions = np.zeros((4, spec.latent_dim), np.float32)
    episodes = np.zeros(4, int)
    with pytest.raises(ValueError, match="at least 2"):
        fit_linear(spec, [(rows, actions, episodes)])
    with pytest.raises(ValueError, match="penalties"):
        fit_linear(spec, [(rows, actions, episodes)] * 2, penalties=[-1.0])
    with pytest.raises(ValueError, match="triples"):
        fit_linear(spec, [(rows, actions)] * 2)  # type: ignore[list-item]
    with pytest.raises(ValueError, match="pose_weights"):
        fit_linear(spec, [(rows, actions, episodes)] * 2, pose_weights=[float("nan")])


def test_files_round_trip_and_bad_arrays_are_refused(sampler: Any, tmp_path: Path) -> None:
    path = sampler.save(tmp_path / "linear")
    assert (tmp_path / "linear.npz").is_file() and path == tmp_path / "linear.json"
    loaded = load_sampler(tmp_path / "linear")
    assert isinstance(loaded, LinearPoseSampler)
    observations = np.random.default_rng(0).uniform(-0.5, 0.5, (3, sampler.spec.observation_size))
    observations[:, sampler.layout.slices["latent_mask"]] = 1.0
    for mine, theirs in zip(
        sampler.distribution(observations), loaded.distribution(observations), strict=True
    ):
        np.testing.assert_array_equal(mine, theirs)
    arrays = dict(np.load(tmp_path / "linear.npz", allow_pickle=False))
    arrays["weights"] = arrays["weights"][:-1]
    np.savez(tmp_path / "linear.npz", **arrays)
    with pytest.raises(DataFormatError, match="weights"):
        load_sampler(tmp_path / "linear")
    (tmp_path / "linear.npz").write_bytes(b"not an npz")
    with pytest.raises(DataFormatError, match="linear sampler"):
        load_sampler(tmp_path / "linear")
    (tmp_path / "linear.npz").unlink()
    with pytest.raises(FileNotFoundError, match=r"linear\.npz"):
        load_sampler(tmp_path / "linear")


def test_a_correction_travels_with_the_model_and_learned_applies_it(
    graph: Any, groups: Any, sampler: Any, tmp_path: Path
) -> None:
    """The output correction is learnt from the sampler's outputs, saved in its files (arrays
    and JSON), and ``learned:`` brings it to the reconstructor; ``correct_output=False`` leaves
    it out."""
    options = {"temporal": TemporalConfig.off()}
    recordings = [_recording(name, 45) for name in ("run", "jump", "dance_a")]
    bare = LearnedSampler(sampler, samples=1, correct_output=False)
    sources = [CorrectionSource(graph, options, [recording], bare) for recording in recordings]
    chosen, report = learn_correction(sources)
    frames = sum(len(recording.positions) for recording in recordings)
    assert report["groups"] == 3 and report["frames"] == frames
    if chosen is None:  # no setting beat the uncorrected outputs out of group
        assert min(report["cv_error"].values()) >= report["uncorrected_error"]
    else:
        assert f"{report['penalty']:g}/{report['smoothing']:g}" in report["cv_error"]
    # A correction of these outputs (one setting, no cross-validation) for the file round trip.
    with Reconstructor(graph, ragdoll=False, **options) as reconstructor:
        data = correction_data(reconstructor, recordings, LearnedSampler(sampler, samples=1))
        anchor = reconstructor.reconstruct(recordings[1], "closed-form", rng=0).poses
    # The steadiness a correction must keep: the anchor's jitter on each recording.
    assert len(data.reference_jitter) == 3
    expected = np.nanmean(metrics.jitter(anchor, timestamps=recordings[1].timestamps))
    assert data.reference_jitter[1] == pytest.approx(expected)
    correction = RidgeOutputCorrection(
        fit_ridge([ridge_sums(data.features, data.targets)], 100.0), 0.5, 100.0
    )
    copy = load_sampler(sampler.save(tmp_path / "plain"))
    assert copy.output_correction is None and LearnedSampler(copy).output_correction is None
    path = copy.with_correction(correction, report).save(tmp_path / "corrected")
    loaded = load_sampler(path)
    assert isinstance(loaded, LinearPoseSampler) and loaded.output_correction is not None
    assert loaded.output_correction.smoothing == correction.smoothing
    for name, value in correction.arrays.items():
        np.testing.assert_array_equal(loaded.output_correction.arrays[name], value)
    assert LearnedSampler(loaded).output_correction is loaded.output_correction
    assert LearnedSampler(loaded, correct_output=False).output_correction is None
    # learned: = its uncorrected output, corrected by the smoothed predictions.
    stream = _recording("walk", 30)
    with Reconstructor(graph, ragdoll=False, **options) as reconstructor:
        fixed = reconstructor.reconstruct(stream, LearnedSampler(loaded, samples=1), rng=0)
        plain = reconstructor.reconstruct(
            stream, LearnedSampler(loaded, samples=1, correct_output=False), rng=0
        )
    rows, local, placement = correction_features(
        plain.poses, stream.positions, stream.states, plain.arrays()["reliability"]
    )
    offsets = smooth_corrections(
        loaded.output_correction.predict(rows), np.zeros(len(rows)), correction.smoothing
    )
    expected = corrected_outputs(local, placement, offsets, np.zeros(len(rows)), stream.timestamps)
    np.testing.assert_allclose(fixed.poses, expected, atol=2e-5)
    # A file whose JSON names a correction its arrays lack is refused.
    arrays = dict(np.load(tmp_path / "corrected.npz", allow_pickle=False))
    arrays.pop("correction_weights")
    np.savez(tmp_path / "corrected.npz", **arrays)
    with pytest.raises(DataFormatError, match="correction_weights"):
        load_sampler(tmp_path / "corrected")


def test_a_linear_sampler_needs_absolute_anchored_actions() -> None:
    spec = SamplerSpec.for_layout("linear", "ridge", action_mode="delta")
    with pytest.raises(ValueError, match="absolute"):
        LinearPoseSampler(spec, {})


def test_train_sampler_cli_trains_a_linear_sampler(tmp_path: Path) -> None:
    """``fpg-gym train-sampler --kind linear``: numpy only, a model that loads, and refused
    settings named."""
    from fpg_gym.cli import main

    out = tmp_path / "linear"
    command = [
        "train-sampler", "--kind", "linear", "--target", "bones", "--follow", "anchor",
        "--graph", "default", "--clips", "run", "jump", "cartwheel", "--timesteps", "240",
        "--max-frames", "30", "--eval-episodes", "1", "--quiet", "--out", str(out),
    ]  # fmt: skip
    assert main(command) == 0
    sampler = load_sampler(out)
    assert isinstance(sampler, LinearPoseSampler) and (tmp_path / "linear.npz").is_file()
    assert sampler.spec.hyperparameters["target"] == "bones"
    assert "linear" in sampler.spec.training["history"][0]
    # The correction is learnt by default: a model, or none when cross-validation found none
    # better than the uncorrected outputs (then the evaluation has no uncorrected row).
    chosen = sampler.spec.training["history"][0]["correction"]
    assert (sampler.output_correction is None) == (chosen["penalty"] is None)
    evaluation = sampler.spec.training["evaluation"]
    assert ("learned, uncorrected (200)" in evaluation) == (chosen["penalty"] is not None)
    with pytest.raises(ValueError, match="kind 'linear'"):
        from policies.training import TrainConfig

        TrainConfig(kind="linear", out=str(out), target="best")
    with pytest.raises(ValueError, match="correction"):
        TrainConfig(kind="supervised", out=str(out), correction=False)


def test_the_closed_form_fitted_to_the_learned_pose_is_steadier(graph: Any, sampler: Any) -> None:
    """A pose weight fits the closed form, motion term included, to the learned pose: on an
    unseen clip its output shakes less than the learned offset moved into the latent space
    alone, and still removes the sensor's offset."""
    import copy

    held_out = _recording("walk")

    def run(weight: float) -> tuple[float, float]:
        chosen = copy.deepcopy(sampler)
        chosen.spec.hyperparameters["pose_weight"] = weight
        with Reconstructor(graph, ragdoll=False, temporal=TemporalConfig.off()) as reconstructor:
            poses = reconstructor.reconstruct(
                held_out, LearnedSampler(chosen, samples=1), rng=0
            ).poses
        assert held_out.ground_truth is not None
        error = float(metrics.frame_error(held_out.ground_truth, poses).mean())
        return error, float(np.nanmean(metrics.jitter(poses, fps=held_out.fps)))

    anchor = _error(graph, "closed-form", held_out)
    alone, weighted = run(0.0), run(0.25)
    assert weighted[1] < alone[1]
    assert anchor - weighted[0] > 0.4 * FORWARD / skeleton.NUM_BONES

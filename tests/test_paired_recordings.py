"""Training the linear sampler on paired recordings (``train-sampler --recordings``): groups
held out and cross-validated whole, each group's data collected with a graph and a sensor map
built without it, bad input named."""

from __future__ import annotations

import json
import shutil
from pathlib import Path
from typing import Any

import numpy as np
import pytest

from fpg_gym.core.errors import DataFormatError
from fpg_gym.definitions import DefinitionMap
from fpg_gym.graph import FilteredPoseGraph
from fpg_gym.io import Clip, load_default_clips, write_recording
from fpg_gym.io.recording import Recording, load_recording
from fpg_gym.simulate import simulate
from fpg_gym.simulate.occlude import occlusion_case_names
from policies.paired_recordings import (
    group_databases,
    group_pattern,
    paired_recordings,
    recording_paths,
    with_occlusions,
)

#: Embedded clips standing in for three "subjects" (the default graph is built from them; the
#: sampler learns the simulated sensor's error, not the poses).
SUBJECTS = {"s01": ("run", "jump"), "s02": ("dance_a", "cartwheel"), "s03": ("run", "jump")}


def _write(folder: Path, frames: int = 40) -> Path:
    """Simulated paired recordings named like UI-PRMD's imports, ``mMM_sSS_e01.npz``."""
    folder.mkdir(parents=True, exist_ok=True)
    for s, (subject, names) in enumerate(SUBJECTS.items()):
        for m, clip in enumerate(load_default_clips(list(names))):
            recording = simulate(clip, "front-many", seed=10 * s + m).head(frames)
            write_recording(folder / f"m{m + 1:02d}_{subject}_e01.npz", recording)
    return folder


def test_groups_are_held_out_whole(tmp_path: Path) -> None:
    folder = _write(tmp_path / "recordings")
    paired = paired_recordings([folder], pattern=r"_(s\d+)_", val_share=0.2, episodes=6)
    held = paired.info["validation_groups"]
    assert len(held) == 1 and set(paired.info["training_groups"]) | set(held) == set(SUBJECTS)
    assert {group for group, _ in paired.train} == set(paired.info["training_groups"])
    assert len(paired.train) == 4 and len(paired.validation) == 2
    # Without a pattern each recording is its own group.
    alone = paired_recordings([folder], val_share=0.2)
    assert len(alone.info["training_groups"]) + len(alone.info["validation_groups"]) == 6
    # val_share 0: every group trains, none is held out.
    every = paired_recordings([folder], pattern=r"_(s\d+)_", val_share=0.0)
    assert every.info["validation_groups"] == [] and every.validation == []
    assert len(every.train) == 6 and every.names == sorted(p.stem for p in folder.iterdir())
    with pytest.raises(ValueError, match="val_share"):
        paired_recordings([folder], val_share=1.0)


def _truth_graph(folder: Path) -> FilteredPoseGraph:
    """The graph of the recordings' ground truth, as build-graph builds it from an import's
    clips (one clip per recording, named by its file stem)."""
    clips = []
    for path in sorted(folder.glob("*.npz")):
        recording = load_recording(path)
        clips.append(Clip(path.stem, np.asarray(recording.ground_truth), recording.fps))
    return FilteredPoseGraph.build(clips, thres1=0.1, progress=False)


def test_each_group_gets_a_graph_and_map_built_without_it(tmp_path: Path) -> None:
    folder = _write(tmp_path / "recordings")
    paired = paired_recordings([folder], pattern=r"_(s\d+)_", val_share=0.0)
    recordings = {p.stem: load_recording(p) for p in sorted(folder.glob("*.npz"))}
    every = DefinitionMap.fit(
        np.concatenate([r.positions for r in recordings.values()]),
        np.concatenate([r.ground_truth for r in recordings.values()]),
        source="kinect-sim",
        target="truth",
    )
    databases = group_databases(paired, _truth_graph(folder), every)
    assert [db.group for db in databases] == sorted(SUBJECTS)
    for db in databases:
        others = [n for n in recordings if f"_{db.group}_" not in n]
        assert set(db.graph.clip_names) == set(others)
        assert db.graph.thres1 == 0.1
        expected = DefinitionMap.fit(
            np.concatenate([recordings[n].positions for n in others]),
            np.concatenate([recordings[n].ground_truth for n in others]),
            source="kinect-sim",
            target="truth",
        )
        assert db.sensor_map is not None and db.sensor_map.target == "truth"
        np.testing.assert_array_equal(db.sensor_map.offsets, expected.offsets)
    assert group_databases(paired, _truth_graph(folder), None)[0].sensor_map is None
    # A graph of other data (the embedded default) cannot be rebuilt without a group.
    from fpg_gym.graph import default_graph

    with pytest.raises(ValueError, match="no clip of the graph"):
        group_databases(paired, default_graph(), every)
    with pytest.raises(ValueError, match="database"):
        group_databases(paired, _truth_graph(folder), every.inverse())


def test_bad_recordings_and_patterns_are_named(tmp_path: Path) -> None:
    folder = _write(tmp_path / "recordings", frames=10)
    with pytest.raises(FileNotFoundError, match="missing: no such file"):
        recording_paths([tmp_path / "missing"])
    (tmp_path / "empty").mkdir()
    with pytest.raises(FileNotFoundError, match="holds no recordings"):
        recording_paths([tmp_path / "empty"])
    with pytest.raises(ValueError, match="no group"):
        group_pattern("s[0-9]+")
    with pytest.raises(ValueError, match="not a regular expression"):
        group_pattern("(s")
    with pytest.raises(ValueError, match="does not match"):
        paired_recordings([folder], pattern=r"_(x\d+)_")
    with pytest.raises(ValueError, match="at least 3"):
        paired_recordings([folder], pattern=r"(_)s")  # one group for all
    blind = folder / "m09_s09_e01.npz"
    source = Recording(
        np.zeros((5, 20, 3), np.float32), np.full((5, 20), 2, np.int8), np.arange(5) / 30.0
    )
    write_recording(blind, source)
    with pytest.raises(DataFormatError, match="no ground truth") as error:
        paired_recordings([folder], pattern=r"_(s\d+)_")
    assert "m09_s09_e01.npz" in str(error.value)


def test_training_recordings_are_also_given_occluded(tmp_path: Path) -> None:
    """Each training recording once more with an occlusion put in (the cases in turn, seeded),
    in its own group; the held-out recordings and the record unchanged."""
    folder = _write(tmp_path / "recordings")
    paired = paired_recordings([folder], pattern=r"_(s\d+)_", val_share=0.2, episodes=6)
    cases = ["legs", "forearm"]
    occluded = with_occlusions(paired, cases, seed=3)
    count = len(paired.train)
    assert occluded.train[:count] == paired.train and occluded.names[:count] == paired.names
    assert len(occluded.train) == 2 * count and len(occluded.names) == 2 * count
    assert occluded.validation == paired.validation and occluded.info == paired.info
    for i, ((group, copy), name) in enumerate(
        zip(occluded.train[count:], occluded.names[count:], strict=True)
    ):
        original = paired.train[i][1]
        case = cases[i % len(cases)]
        assert group == paired.train[i][0] and name == f"{paired.names[i]}~{case}"
        assert copy.metadata["occlusion"]["case"] == case
        assert copy.occluded is not None and copy.occluded.any()
        hidden = copy.occluded.any(axis=1)
        assert not np.array_equal(copy.positions[hidden], original.positions[hidden])
        np.testing.assert_array_equal(copy.positions[~hidden], original.positions[~hidden])
        np.testing.assert_array_equal(copy.ground_truth, original.ground_truth)
    again = with_occlusions(paired, cases, seed=3)
    for (_, a), (_, b) in zip(occluded.train, again.train, strict=True):
        np.testing.assert_array_equal(a.positions, b.positions)
    other = with_occlusions(paired, cases, seed=4)
    assert any(
        not np.array_equal(a.positions, b.positions)
        for (_, a), (_, b) in zip(occluded.train[count:], other.train[count:], strict=True)
    )
    assert with_occlusions(paired, [], seed=3) is paired
    with pytest.raises(ValueError, match=r"unknown case.*behind-the-sofa"):
        with_occlusions(paired, ["legs", "behind-the-sofa"], seed=3)


def test_train_sampler_learns_from_recordings(tmp_path: Path, capsys: Any) -> None:
    """``fpg-gym train-sampler --kind linear --recordings``: a model that loads, trained on the
    training groups only, with the held-out group in its record; cross-fitted by default (its
    graph must be the recordings' truth's), with --no-cross-fit on any graph, on every group
    with --val-share 0."""
    from fpg_gym.cli import main
    from policies.loading import load_sampler
    from policies.pose_sampler import LinearPoseSampler

    folder = _write(tmp_path / "recordings")
    out = tmp_path / "real"
    command = [
        "train-sampler", "--kind", "linear", "--target", "bones", "--follow", "anchor",
        "--graph", "default", "--recordings", str(folder), "--group-pattern", r"_(s\d+)_",
        "--sensor-blend", "0.5", "--eval-episodes", "2", "--quiet", "--out", str(out),
    ]  # fmt: skip
    assert main(command) == 2  # named, before any work
    assert "no clip of the graph" in capsys.readouterr().err
    assert not (tmp_path / "real.checkpoints").exists()
    assert main([*command, "--no-cross-fit"]) == 0
    sampler = load_sampler(out)
    assert isinstance(sampler, LinearPoseSampler)
    training = json.loads((tmp_path / "real.json").read_text())["training"]
    assert training["sensor_blend"] == 0.5 and len(training["validation_groups"]) == 1
    assert set(training["training_groups"]).isdisjoint(training["validation_groups"])
    assert all(name.endswith(".npz") for name in training["recordings"])
    assert training["cross_fit"] is False and training["evaluation"]
    assert training["occlusions"] == list(occlusion_case_names())  # by default
    # Cross-fitted, on every group: the graph of the recordings' truth, no final evaluation.
    graph = _truth_graph(folder).save(tmp_path / "truth.npz")
    every = [*command, "--graph", str(graph), "--val-share", "0", "--out", str(tmp_path / "all")]
    assert main(every) == 0
    training = json.loads((tmp_path / "all.json").read_text())["training"]
    assert training["cross_fit"] is True and training["validation_groups"] == []
    assert sorted(training["training_groups"]) == sorted(SUBJECTS)
    assert "evaluation" not in training
    none = [*command, "--no-cross-fit", "--occlusions", "none", "--out", str(tmp_path / "bare")]
    assert main(none) == 0
    assert json.loads((tmp_path / "bare.json").read_text())["training"]["occlusions"] == []
    assert main([*command, "--no-cross-fit", "--occlusions", "legs,sofa"]) == 2
    assert "occlusions: unknown case(s) sofa" in capsys.readouterr().err
    clips = ["train-sampler", "--kind", "linear", "--target", "bones", "--follow", "anchor"]
    assert main([*clips, "--occlusions", "legs", "--out", str(tmp_path / "clips")]) == 2
    assert "--occlusions: only with --recordings" in capsys.readouterr().err
    with pytest.raises(ValueError, match="only kind 'linear'"):
        from policies.training import TrainConfig

        TrainConfig(kind="supervised", out=str(out), recordings=[str(folder)])
    with pytest.raises(ValueError, match="only used with recordings"):
        TrainConfig(kind="linear", target="bones", out=str(out), group_pattern="(s)")
    with pytest.raises(ValueError, match="val_share"):
        TrainConfig(kind="linear", target="bones", out=str(out), val_share=0.0)


def test_train_sampler_json_summarises_the_recordings(
    tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    """Issue 39: ``--json`` with recordings given one by one (a shell glob gives hundreds: a
    30 KB line) lists them as a count, their folder and a hash. A packaged graph and map are
    taken by name, as every command takes them (issue 35)."""
    from fpg_gym.cli import main

    folder = _write(tmp_path / "recordings", frames=20)
    for path in list(folder.glob("*_e01.npz")):  # a second repetition of each
        shutil.copy(path, path.with_name(path.name.replace("_e01", "_e02")))
    files = sorted(str(p) for p in folder.glob("*.npz"))
    command = [
        "train-sampler", "--kind", "linear", "--target", "bones", "--follow", "anchor",
        "--graph", "uiprmd", "--sensor-map", "kinect-v2-to-vicon", "--no-cross-fit",
        "--recordings", *files,
        "--group-pattern", r"_(s\d+)_",
        "--eval-episodes", "2", "--quiet", "--json", "--out", str(tmp_path / "model"),
    ]  # fmt: skip
    assert main(command) == 0
    line = capsys.readouterr().out.strip().splitlines()[-1]
    summary = json.loads(line)["config"]["recordings"]
    assert summary["count"] == 12 and summary["folders"] == [str(folder)]
    assert len(summary["sha256"]) == 64 and "items" not in summary
    assert not any(name in line for name in files)
    assert json.loads(line)["config"]["clips"] is None
    assert json.loads(line)["config"]["graph"] == "uiprmd"


def test_train_sampler_help_names_every_occlusion_case(capsys: Any) -> None:
    """The --occlusions help lists the default cases by name (written out to keep the
    command's import light): it must name every case the benchmark has."""
    from fpg_gym.cli import main

    with pytest.raises(SystemExit):
        main(["train-sampler", "--help"])
    text = "".join(capsys.readouterr().out.split())  # argparse wraps at spaces and hyphens
    assert ",".join(occlusion_case_names()) in text

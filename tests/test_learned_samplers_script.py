"""``scripts/learned_samplers.py`` (``scripts/sampler_study``): its UI-PRMD fold trains the
linear sampler as ``fpg-gym train-sampler`` does (the same model); its tables pool seeds, give
paired changes against the closed-form anchor with bootstrap intervals, per subject and per set
of repetitions."""

from __future__ import annotations

import importlib
import json
import sys
from pathlib import Path
from types import SimpleNamespace
from typing import Any

import numpy as np
import pytest

REPO = Path(__file__).resolve().parents[1]


@pytest.fixture(scope="module")
def script() -> Any:
    """The study's modules (``scripts/sampler_study``): ``script.tables``, ``script.uiprmd``."""
    sys.path.insert(0, str(REPO / "scripts"))  # its package and its neighbour real_kinect.py
    try:
        tables = importlib.import_module("sampler_study.tables")
        uiprmd = importlib.import_module("sampler_study.uiprmd")
    finally:
        sys.path.remove(str(REPO / "scripts"))
    return SimpleNamespace(tables=tables, uiprmd=uiprmd)


def _rows(errors: dict[str, list[float]]) -> list[dict[str, Any]]:
    """Rows of :func:`_score`'s form: each episode's Eq. 13 error as given, its MPJPE twice
    that, the other figures constant."""
    figures = {"mpjpe_root": 0.1, "mpjpe_pa": 0.05, "jitter": 1.0, "spread_mm": 2.0}
    return [
        {
            "episode": f"m01_s01_e{i + 1:02d}",
            "method": method,
            "error": e,
            "mpjpe": 2 * e,
            **figures,
            "bone_error_mm": 5.0,
            "cpu_ms": 1.0,
        }
        for method, values in errors.items()
        for i, e in enumerate(values)
    ]


def test_table_pools_seeds_and_compares_with_the_anchor(script: Any) -> None:
    models = {"0": "/m/sampler_a_seed0", "1": "/m/sampler_a_seed1"}
    anchor = [0.10, 0.12, 0.08, 0.11]
    rows = _rows(
        {
            "raw": [0.2] * 4,
            "fpg:closed-form": anchor,
            "fpg:local-search": [0.1] * 4,
            f"fpg:learned:{models['0']}": [0.8 * e for e in anchor],
            f"fpg:learned:{models['1']}": [0.9 * e for e in anchor],
        }
    )
    table = script.tables.uiprmd_table([{"subject": "s01", "models": models, "rows": rows}])
    lines = {line.split(" | ")[0].lstrip("| "): line for line in table.splitlines()[2:]}
    assert set(lines) == {
        "raw", "closed-form", "local-search", "learned", "learned (seed 0)", "learned (seed 1)",
    }  # fmt: skip
    assert "-20.0 %" in lines["learned (seed 0)"] and "-10.0 %" in lines["learned (seed 1)"]
    cells = lines["learned"].split(" | ")
    assert cells[3].startswith("-15.0 %") and cells[5].startswith("-15.0 %")  # seeds pooled
    assert float(cells[2].split()[0]) == pytest.approx(np.mean(anchor) * 0.85, abs=1e-4)
    assert float(cells[4].split()[0]) == pytest.approx(2 * np.mean(anchor) * 0.85, abs=1e-4)
    assert cells[8:11] == ["1.00", "2.0", "5.0"]  # jitter, settled range, bone length error
    # Repetitions stand in for seeds: e01 and e04 in one set, e02 in another, e03 in a third.
    sets = script.tables.repetition_table([{"subject": "s01", "models": models, "rows": rows}])
    assert sets.count("-15.0 %") == 2 and "e02" not in sets  # one episode per set: no row


def test_subject_table_and_plot_take_each_fold_alone(script: Any, tmp_path: Path) -> None:
    models = {"0": "/m/sampler_a_seed0", "1": "/m/sampler_a_seed1"}
    folds = []
    for subject, factor in (("s02", 0.5), ("s01", 0.75)):
        anchor = [0.10, 0.12, 0.08]
        rows = _rows(
            {
                "fpg:closed-form": anchor,
                "fpg:local-search": [0.2] * 3,
                f"fpg:learned:{models['0']}": [factor * e for e in anchor],
                f"fpg:learned:{models['1']}": [factor * e for e in anchor],
            }
        )
        folds.append({"subject": subject, "models": models, "rows": rows})
    table = script.tables.uiprmd_subject_table(folds)
    lines = table.splitlines()[2:]
    assert [line.split(" | ")[0].lstrip("| ") for line in lines] == ["s01", "s02"]
    assert lines[0].count("-25.0 %") == 2 and lines[1].count("-50.0 %") == 2  # Eq. 13, MPJPE
    path = script.tables.plot_subjects(folds, tmp_path / "per_subject.png")
    assert path.read_bytes()[:8] == b"\x89PNG\r\n\x1a\n"


def _import(folder: Path) -> Path:
    """A small stand-in for an ``import-uiprmd`` folder: four subjects, two exercises each,
    one repetition of 30 frames; ``clips/`` holds each recording's ground truth."""
    from fpg_gym.io import Clip, load_default_clips, write_positions, write_recording
    from fpg_gym.simulate import simulate

    subjects = {
        "s01": ("run", "jump"),
        "s02": ("dance_a", "cartwheel"),
        "s03": ("jump", "run"),
        "s04": ("walk", "punch"),
    }
    (folder / "recordings").mkdir(parents=True)
    (folder / "clips").mkdir()
    for s, (subject, names) in enumerate(subjects.items()):
        for m, clip in enumerate(load_default_clips(list(names))):
            recording = simulate(clip, "front-many", seed=10 * s + m).head(30)
            stem = f"m{m + 1:02d}_{subject}_e01"
            write_recording(folder / "recordings" / f"{stem}.npz", recording)
            truth = Clip(stem, np.asarray(recording.ground_truth), recording.fps)
            write_positions(folder / "clips" / f"{stem}.npz", truth)
    return folder


def test_a_fold_trains_the_model_the_cli_trains(script: Any, tmp_path: Path) -> None:
    """Issue 35: the study's fold (s04 held out) and the documented commands (build-graph of
    the training subjects' clips, fit-map of their recordings, train-sampler --recordings
    --group-pattern --val-share 0) give the same model, array for array."""
    from fpg_gym.cli import main

    imported = _import(tmp_path / "ui")
    subjects = script.uiprmd.real_kinect.by_subject(imported / "recordings")
    task = {
        "out": str(tmp_path / "study"),
        "exclude_training": [],
        "thres1": 0.1,
        "train_reps": 0,
        "blend": 0.5,
        "correct": True,
        "command": "test",
    }
    training = ["s01", "s02", "s03"]
    trained, _, _ = script.uiprmd.train_linear(task, imported, subjects, "s04", training)
    clips = sorted(str(p) for p in (imported / "clips").glob("m*_s0[1-3]_*.npz"))
    recordings = sorted(str(p) for p in (imported / "recordings").glob("m*_s0[1-3]_*.npz"))
    graph, sensor_map, out = tmp_path / "G.npz", tmp_path / "M.json", tmp_path / "cli"
    assert main(["build-graph", *clips, "--thres1", "0.1", "--out", str(graph), "--quiet"]) == 0
    assert main(["fit-map", *recordings, "--out", str(sensor_map)]) == 0
    command = [
        "train-sampler", "--kind", "linear", "--target", "bones", "--follow", "anchor",
        "--graph", str(graph), "--recordings", *recordings, "--group-pattern", "_(s[0-9]+)_",
        "--sensor-map", str(sensor_map), "--sensor-blend", "0.5", "--val-share", "0",
        "--quiet", "--out", str(out),
    ]  # fmt: skip
    assert main(command) == 0
    study = Path(trained["models"]["linear"]).with_suffix(".npz")
    with np.load(study, allow_pickle=False) as a, np.load(f"{out}.npz", allow_pickle=False) as b:
        assert sorted(a.files) == sorted(b.files)
        for name in a.files:
            np.testing.assert_array_equal(a[name], b[name], err_msg=name)
    cli = json.loads(Path(f"{out}.json").read_text())
    mine = json.loads(study.with_suffix(".json").read_text())
    assert cli["hyperparameters"] == mine["hyperparameters"]
    assert cli["training"]["cross_fit"] and mine["training"]["training_groups"] == [
        "s01", "s02", "s03",
    ]  # fmt: skip

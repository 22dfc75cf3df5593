"""A stopped supervised training run goes on from its checkpoints (policies.checkpoints): the
same pairs and the same weights as an uninterrupted run, settings checked, files whole."""

from __future__ import annotations

import json
from pathlib import Path
from typing import Any

import numpy as np
import pytest

from policies.checkpoints import RunCheckpoints
from policies.imitation import ImitationData, collect_imitation_data
from tests.test_truth_target import SPEC

torch = pytest.importorskip("torch")

SETTINGS = {"kind": "supervised", "seed": 0, "epochs": 3}


class Stop(Exception):
    """Stands for Ctrl-C or a kill between two checkpoints."""


@pytest.fixture
def recordings(short_streams: list[Any]) -> list[Any]:
    return short_streams


def _same_pairs(a: ImitationData, b: ImitationData) -> None:
    for name in ("observations", "actions", "masks", "episodes", "search_energies"):
        np.testing.assert_array_equal(getattr(a, name), getattr(b, name), err_msg=name)


def test_stopped_collection_goes_on_to_the_same_pairs(
    graph: Any, recordings: list[Any], tmp_path: Path
) -> None:
    kwargs: dict[str, Any] = {"target": "search", "seed": 5, "batch": 1, "frames": 17}
    whole = collect_imitation_data(graph, recordings, SPEC, **kwargs)
    run = RunCheckpoints(tmp_path / "run.checkpoints", SETTINGS)
    saved: list[list[int]] = []

    def save_then_stop(episodes: list[int], pairs: ImitationData) -> None:
        run.save_chunk(episodes, pairs)
        saved.append(episodes)
        if len(saved) == 2:
            raise Stop

    with pytest.raises(Stop):
        collect_imitation_data(graph, recordings, SPEC, on_chunk=save_then_stop, **kwargs)
    again = RunCheckpoints(tmp_path / "run.checkpoints", SETTINGS)
    assert again.collected_episodes() == {0, 1}
    rest = collect_imitation_data(
        graph, recordings, SPEC, skip=again.collected_episodes(), **kwargs
    )
    np.testing.assert_array_equal(np.unique(rest.episodes), [2, 3])
    _same_pairs(again.merged_data(rest), whole)
    # Only whole files: no temporary file is left behind.
    assert not [p for p in (tmp_path / "run.checkpoints").iterdir() if p.name.startswith(".")]


def test_skip_is_checked(graph: Any, recordings: list[Any]) -> None:
    with pytest.raises(ValueError, match=r"skip: episode 9 is not in 0\.\.3"):
        collect_imitation_data(graph, recordings, SPEC, skip={9})


def test_other_settings_are_refused_unless_restarting(tmp_path: Path) -> None:
    folder = tmp_path / "m.checkpoints"
    run = RunCheckpoints(folder, SETTINGS)
    pairs = ImitationData.empty(4, 2)
    run.save_chunk([0, 1], pairs)
    (folder / "notes.txt").write_text("the user's own file\n")
    with pytest.raises(ValueError, match=r"other settings \(epochs differ\).*--restart"):
        RunCheckpoints(folder, {**SETTINGS, "epochs": 4})
    assert RunCheckpoints(folder, SETTINGS).collected_episodes() == {0, 1}
    lines: list[str] = []
    fresh = RunCheckpoints(folder, {**SETTINGS, "epochs": 4}, restart=True, log=lines.append)
    assert fresh.collected_episodes() == set()
    assert "started over (2 checkpoint files removed)" in lines[0]
    assert (folder / "notes.txt").is_file()  # nothing it did not write
    assert json.loads((folder / "run.json").read_text())["settings"]["epochs"] == 4


def _train(tmp_path: Path, name: str, stop_after: int | None = None, restart: bool = False) -> Any:
    """The tiny CLI configuration of test_policies, run in-process; optionally stopped once
    the fit state of epoch ``stop_after`` is on disk."""
    from policies.checkpoints import RunCheckpoints as Checkpoints
    from policies.training import TrainConfig, train_sampler

    config = TrainConfig(
        kind="supervised",
        out=str(tmp_path / name),
        clips=["run"],
        val_clips=["jump"],
        scenarios=["front-many"],
        timesteps=12,
        epochs=3,
        k=8,
        latent_dim=7,
        max_frames=6,
        eval_episodes=1,
        mirror=False,
        progress=False,
        restart=restart,
    )
    original = Checkpoints.save_fit

    def save_then_stop(self: Any, state: Any) -> None:
        original(self, state)
        if state.epoch == stop_after:
            raise Stop

    patch = pytest.MonkeyPatch()
    patch.setattr(Checkpoints, "save_fit", save_then_stop)
    try:
        return train_sampler(config, log=lambda _line: None)
    finally:
        patch.undo()


def test_a_stopped_training_goes_on_to_the_same_weights(tmp_path: Path) -> None:
    whole = _train(tmp_path, "whole")
    with pytest.raises(Stop):
        _train(tmp_path, "stopped", stop_after=2)
    state = json.loads((tmp_path / "stopped.checkpoints" / "fit.json").read_text())
    assert state["epoch"] == 2 and len(state["history"]) == 2
    assert whole.sampler.spec.training["frames"] == 12
    resumed = _train(tmp_path, "stopped")  # the same command again
    _same_weights(resumed.sampler, whole.sampler)
    assert resumed.sampler.spec.training["frames"] == 12  # the stored pairs, once
    # The model written, its data and fit state are removed; the evaluated samplers stay.
    left = sorted(p.name for p in (tmp_path / "stopped.checkpoints").iterdir())
    assert left and all(name.startswith("epoch-") for name in left)
    losses = [r["train_loss"] for r in whole.history]
    assert [r["train_loss"] for r in resumed.history] == losses
    # Starting over trains from scratch: the same weights again, by the long road.
    restarted = _train(tmp_path, "stopped", restart=True)
    _same_weights(restarted.sampler, whole.sampler)
    assert [r["train_loss"] for r in restarted.history] == losses


def _same_weights(a: Any, b: Any) -> None:
    expected, got = b.module.state_dict(), a.module.state_dict()
    assert expected.keys() == got.keys()
    for key in expected:
        assert torch.equal(expected[key], got[key]), key

"""Where the env's episodes come from: recordings given, or clips simulated in scenarios.

:class:`EpisodeSource` owns the recordings or the clips and scenarios of a
:class:`~fpg_gym.env.KinectPoseEnv`, draws an episode at ``reset`` from the env's
``np_random`` (every choice is drawn, whatever the options fix, so the random stream does not
depend on them) and simulates clip episodes through the episode planner
(:func:`fpg_gym.simulate.plan_episode`, :class:`~fpg_gym.simulate.EpisodeSimulator`: one
simulator per scenario; cached by seed below ``simulator_seeds``). The drawn ``seed`` is the
user's seed of the planner's seeding rule, so the episode ``walk/front-many/3`` is the stream
``fpg-gym compare --clips walk --scenarios front-many --seeds 3`` simulates.
"""

from __future__ import annotations

import os
from collections.abc import Sequence
from pathlib import Path
from typing import Any

import numpy as np

from fpg_gym.core.defaults import DEFAULT_EPISODE_SCENARIOS, DEFAULT_HOLDOUT_CLIPS
from fpg_gym.io import DEFAULT_CLIP_NAMES, load_default_clips, read_recording
from fpg_gym.io.clip import Clip
from fpg_gym.io.recording import Recording
from fpg_gym.simulate import EpisodeSimulator, get_scenario, plan_episode, unique_names

__all__ = ["RESET_OPTIONS", "EpisodeSource"]

#: Keys of ``reset(options=...)``.
RESET_OPTIONS: tuple[str, ...] = ("recording", "clip", "scenario", "seed")


def _recording_name(recording: Recording, fallback: object) -> str:
    """A recording's name: its metadata's ``name``, else its ``clip``, else ``fallback``."""
    return str(recording.metadata.get("name") or recording.metadata.get("clip") or fallback)


class EpisodeSource:
    """The recordings, or the clips and scenarios, an env draws its episodes from.

    Parameters
    ----------
    recordings : sequence of paths or Recording, optional
        Play these (exclusive with ``clips``).
    clips : sequence of str or Clip, optional
        Embedded clip names or clips to simulate (the held-out embedded clips by default).
    scenarios : sequence, optional
        Simulator scenarios for clip episodes (``front-many``, ``left45-many``, ``right45-many``
        by default).
    simulator_seeds : int, optional
        Draw episode seeds in ``[0, simulator_seeds)`` and cache their streams (None: any).
    needs_truth : bool
        Whether episodes must have ground truth (for the reward).
    reward_mode : str
        Named in the error when a recording has no ground truth.
    """

    def __init__(
        self,
        *,
        recordings: Sequence[str | os.PathLike[str] | Recording] | None = None,
        clips: Sequence[str | Clip] | None = None,
        scenarios: Sequence[Any] | None = None,
        simulator_seeds: int | None = None,
        needs_truth: bool = False,
        reward_mode: str = "energy",
    ) -> None:
        self.simulator_seeds = simulator_seeds
        self._needs_truth = needs_truth
        self.reward_mode = reward_mode
        self._recordings: list[Recording] = []
        self._recording_names: list[str] = []
        self._clips: list[Clip] = []
        self._scenarios: list[Any] = []
        self._simulated: dict[tuple[int, int, int], Recording] = {}
        self._simulator = EpisodeSimulator()
        if recordings is not None:
            self._load_recordings(recordings)
        else:
            self._load_clips(DEFAULT_HOLDOUT_CLIPS if clips is None else clips)
            self._load_scenarios(DEFAULT_EPISODE_SCENARIOS if scenarios is None else scenarios)

    @property
    def names(self) -> list[str]:
        """Names of the recordings (or clips) episodes are drawn from."""
        return list(self._recording_names)

    @property
    def scenario_names(self) -> list[str]:
        """Names of the scenarios episodes are simulated in (empty with recordings)."""
        return [s.name for s in self._scenarios]

    def close(self) -> None:
        """Release the simulators' pybullet clients (idempotent)."""
        self._simulator.close()

    def _load_recordings(self, recordings: Sequence[str | os.PathLike[str] | Recording]) -> None:

        if isinstance(recordings, (str, os.PathLike, Recording)):
            recordings = [recordings]
        names = []
        for i, item in enumerate(recordings):
            if isinstance(item, Recording):
                rec = item
                names.append(_recording_name(rec, i))
            elif isinstance(item, (str, os.PathLike)):
                rec = read_recording(Path(item))
                names.append(Path(item).name)
            else:
                raise TypeError(
                    f"recordings[{i}]: expected a path or a Recording, got {type(item).__name__}"
                )
            self._recordings.append(rec)
        if not self._recordings:
            raise ValueError("recordings: expected at least one recording, got none")
        self._recording_names = unique_names(names)
        if self._needs_truth:
            missing = [
                name
                for name, rec in zip(self._recording_names, self._recordings, strict=True)
                if rec.ground_truth is None
            ]
            if missing:
                raise ValueError(
                    f"reward_mode={self.reward_mode!r} needs ground truth, but recording(s) "
                    f"{missing} have none; use reward_mode='energy' or simulated recordings"
                )

    def _load_clips(self, clips: Sequence[str | Clip]) -> None:

        if isinstance(clips, (str, Clip)):
            clips = [clips]
        names = [c for c in clips if isinstance(c, str)]
        unknown = sorted(set(names) - set(DEFAULT_CLIP_NAMES))
        if unknown:
            raise ValueError(
                f"clips: unknown embedded clip name(s) {unknown}; expected some of "
                + ", ".join(DEFAULT_CLIP_NAMES)
                + " or Clip objects"
            )
        embedded = {c.name: c for c in load_default_clips(tuple(dict.fromkeys(names)))}
        for i, item in enumerate(clips):
            if isinstance(item, Clip):
                self._clips.append(item)
            elif isinstance(item, str):
                self._clips.append(embedded[item])
            else:
                raise TypeError(
                    f"clips[{i}]: expected a clip name or a Clip, got {type(item).__name__}"
                )
        if not self._clips:
            raise ValueError("clips: expected at least one clip, got none")
        self._recording_names = unique_names([c.name for c in self._clips])

    def _load_scenarios(self, scenarios: Sequence[Any]) -> None:

        if isinstance(scenarios, str):
            scenarios = [scenarios]
        self._scenarios = [get_scenario(s) for s in scenarios]
        if not self._scenarios:
            raise ValueError("scenarios: expected at least one scenario, got none")
        self._simulator = EpisodeSimulator(self._scenarios)  # one per scenario, reused

    def draw(
        self, rng: np.random.Generator, options: dict[str, Any]
    ) -> tuple[Recording, dict[str, Any]]:
        """An episode: its recording and ``recording``, ``clip``, ``scenario``, ``seed``,
        ``num_frames``, ``has_ground_truth``; ``options`` as ``reset(options=...)`` takes them.
        """
        unknown = sorted(set(options) - set(RESET_OPTIONS))
        if unknown:
            raise ValueError(
                f"reset options: unknown key(s) {unknown}; expected some of {list(RESET_OPTIONS)}"
            )
        # Draw every choice first, whatever the options fix: the random stream stays the same.
        if self._recordings:
            index = int(rng.integers(len(self._recordings)))
        else:
            index = int(rng.integers(len(self._clips)))
            s_index = int(rng.integers(len(self._scenarios)))
            seed = int(rng.integers(self.simulator_seeds or 2**31 - 1))
        choice = options.get("recording")
        if isinstance(choice, Recording):  # any env plays a recording given here
            if set(options) - {"recording"}:
                raise ValueError("reset options: a Recording comes alone (no clip/scenario/seed)")
            name = _recording_name(choice, "given")
            if self._needs_truth and choice.ground_truth is None:
                raise ValueError(
                    f"reset options: recording {name!r} has no ground truth, which "
                    f"reward_mode={self.reward_mode!r} needs"
                )
            recording = choice
            episode: dict[str, Any] = {"recording": name, "clip": "", "scenario": "", "seed": -1}
        elif self._recordings:
            wrong = sorted(set(options) - {"recording"})
            if wrong:
                raise ValueError(
                    f"reset options: {wrong} apply to clip episodes; this env plays recordings "
                    "(use {'recording': index or name})"
                )
            if choice is not None:
                index = self._index_of(choice, "recording")
            recording, name = self._recordings[index], self._recording_names[index]
            episode = {"recording": name, "clip": "", "scenario": "", "seed": -1}
        else:
            if choice is not None:
                raise ValueError(
                    "reset options: a recording name applies to recording episodes; this env "
                    "simulates clips (use 'clip', 'scenario', 'seed', or give a Recording)"
                )
            if options.get("clip") is not None:
                index = self._index_of(options["clip"], "clip")
            if options.get("scenario") is not None:
                names = self.scenario_names
                wanted = getattr(options["scenario"], "name", options["scenario"])
                if wanted not in names:
                    raise ValueError(
                        f"reset options: scenario {wanted!r} is not one of this env's "
                        f"scenarios {names}"
                    )
                s_index = names.index(wanted)
            if options.get("seed") is not None:
                seed = int(options["seed"])
                if seed < 0:
                    raise ValueError(f"reset options: seed must be >= 0, got {seed}")
            recording = self._simulate(index, s_index, seed)
            name = self._recording_names[index]
            scenario_name = self._scenarios[s_index].name
            episode = {
                "recording": f"{name}/{scenario_name}/{seed}",
                "clip": name,
                "scenario": scenario_name,
                "seed": seed,
            }
        episode["num_frames"] = recording.num_frames
        episode["has_ground_truth"] = recording.ground_truth is not None
        return recording, episode

    def _simulate(self, index: int, s_index: int, seed: int) -> Recording:
        """The simulated stream of clip ``index`` in scenario ``s_index`` (cached when the seed
        is below ``simulator_seeds``)."""
        key = (index, s_index, seed)
        recording = self._simulated.get(key)
        if recording is None:
            episode = plan_episode(
                self._recording_names[index], self._scenarios[s_index].name, seed
            )
            recording = self._simulator.simulate(self._clips[index], episode)
            if self.simulator_seeds is not None and seed < self.simulator_seeds:
                self._simulated[key] = recording
        return recording

    def _index_of(self, choice: Any, what: str) -> int:
        names = self._recording_names
        if isinstance(choice, (int, np.integer)) and not isinstance(choice, bool):
            if not 0 <= int(choice) < len(names):
                raise ValueError(
                    f"reset options: {what} index {int(choice)} out of range [0, {len(names)})"
                )
            return int(choice)
        if isinstance(choice, (str, os.PathLike)):
            key = str(choice)
            for candidate in (key, Path(key).name):
                if candidate in names:
                    return names.index(candidate)
        raise ValueError(
            f"reset options: unknown {what} {choice!r}; expected an index or one of {names}"
        )

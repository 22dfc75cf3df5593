"""Simulated episodes: which clip, scenario and simulator seed, and their Kinect streams.

The one planner of simulated episodes, used by the env (:mod:`fpg_gym.env_episodes`), by
``fpg-gym compare`` and the demo (:mod:`fpg_gym.experiments.planning`), by ``fpg-gym bench``
and by sampler training (:mod:`policies.training`).

**The seeding rule.** An episode is a clip (by name), a scenario (by name) and the user's seed
``n`` (``--seeds``, ``reset(options={"seed": n})``); the simulator's seed is

    sim_seed = SeedSequence([n, crc32(clip), crc32(scenario)]).generate_state(1)[0]

(:func:`episode_seed`, the project's one seeding rule :func:`fpg_gym.core.seeding.derive_seed`). It
depends on the three values only, not on the order or the length of the lists the episode was
planned from, and different clips or scenarios with the same ``n`` get unrelated noise. So
``walk`` in ``front-many`` with seed 0 is the same stream in the env, in a comparison and in
training.

Examples
--------
>>> plan = plan_episodes(["walk", "kick"], ["front-many"], [0, 1])
>>> [(e.clip, e.seed) for e in plan]  # seed outermost, then clip, then scenario
[('walk', 0), ('kick', 0), ('walk', 1), ('kick', 1)]
>>> plan[0] == plan_episode("walk", "front-many", 0)
True
>>> plan[0].sim_seed == episode_seed(0, "walk", "front-many") != plan[1].sim_seed
True
"""

from __future__ import annotations

from collections.abc import Iterable, Mapping, Sequence
from dataclasses import dataclass

from tqdm.auto import tqdm

from fpg_gym.core.seeding import derive_seed
from fpg_gym.io.clip import Clip
from fpg_gym.io.recording import Recording
from fpg_gym.simulate.scenarios import Scenario, get_scenario
from fpg_gym.simulate.scene import RayCaster
from fpg_gym.simulate.simulator import KinectSimulator

__all__ = [
    "EpisodeSimulator",
    "PlannedEpisode",
    "episode_seed",
    "plan_episode",
    "plan_episodes",
    "simulate_clips",
    "simulate_plan",
    "unique_names",
]


def episode_seed(seed: int, *names: str) -> int:
    """The simulator (and optimiser) seed of an episode: the user's ``seed`` and the names.

    The project's seeding rule, :func:`fpg_gym.core.seeding.derive_seed`:
    ``SeedSequence([seed, crc32(name_1), crc32(name_2), ...]).generate_state(1)[0]``, a
    non-negative 32-bit integer; for a simulated episode the names are the clip and the scenario
    (a comparison seeds the optimisers on a recording file with its stem alone).

    Parameters
    ----------
    seed : int
        The user's seed (non-negative).
    *names : str

    Returns
    -------
    int

    Raises
    ------
    ValueError
        If ``seed`` is not a non-negative integer.
    """
    return derive_seed(seed, *names)


@dataclass(frozen=True)
class PlannedEpisode:
    """One simulated episode.

    Attributes
    ----------
    clip : str
        The clip's name.
    scenario : str
        The simulator scenario's name.
    seed : int
        The user's seed.
    sim_seed : int
        The simulator's seed, ``episode_seed(seed, clip, scenario)`` (see the module docstring).
    """

    clip: str
    scenario: str
    seed: int
    sim_seed: int


def plan_episode(clip: str, scenario: str, seed: int) -> PlannedEpisode:
    """The episode of ``clip`` in ``scenario`` with the user's ``seed`` (the seeding rule)."""
    return PlannedEpisode(str(clip), str(scenario), int(seed), episode_seed(seed, clip, scenario))


def plan_episodes(
    clips: Sequence[str], scenarios: Sequence[str], seeds: Sequence[int]
) -> list[PlannedEpisode]:
    """Every clip x scenario x seed, seed outermost, then clip, then scenario.

    Parameters
    ----------
    clips : sequence of str
        Clip names.
    scenarios : sequence of str
        Scenario names.
    seeds : sequence of int
        The user's seeds.

    Returns
    -------
    list of PlannedEpisode
    """
    return [
        plan_episode(clip, scenario, seed)
        for seed in seeds
        for clip in clips
        for scenario in scenarios
    ]


def unique_names(names: Iterable[str]) -> list[str]:
    """Names made unique by a ``#i`` suffix on repeats (``walk``, ``walk#1``, ...)."""
    seen: dict[str, int] = {}
    out = []
    for name in names:
        count = seen.get(name, 0)
        seen[name] = count + 1
        out.append(name if count == 0 else f"{name}#{count}")
    return out


class EpisodeSimulator:
    """Simulates planned episodes with one :class:`KinectSimulator` per scenario, reused, all
    casting their rays in one pybullet client (:class:`~fpg_gym.simulate.scene.RayCaster`).

    Parameters
    ----------
    scenarios : sequence of str or Scenario, optional
        Scenarios by the names episodes give (custom :class:`Scenario` objects go here); other
        names are looked up with :func:`~fpg_gym.simulate.get_scenario`.

    Raises
    ------
    ValueError
        If two different scenarios share a name, or a name is unknown.
    """

    def __init__(self, scenarios: Sequence[str | Scenario] = ()) -> None:
        self._scenarios: dict[str, Scenario] = {}
        for item in scenarios:
            scenario = get_scenario(item)
            known = self._scenarios.setdefault(scenario.name, scenario)
            if known is not scenario and known.to_dict() != scenario.to_dict():
                raise ValueError(
                    f"scenarios: two different scenarios are named {scenario.name!r}; "
                    "expected one scenario per name"
                )
        self._simulators: dict[str, KinectSimulator] = {}
        self._caster: RayCaster | None = None

    def simulator(self, scenario: str) -> KinectSimulator:
        """The (cached) simulator of a scenario name."""
        simulator = self._simulators.get(scenario)
        if simulator is None:  # one per scenario, one pybullet client for all
            spec = self._scenarios.get(scenario) or get_scenario(scenario)
            if self._caster is None and spec.occlusion_effects:
                self._caster = RayCaster()
            caster = self._caster if spec.occlusion_effects else None
            simulator = self._simulators[scenario] = KinectSimulator(spec, caster=caster)
        return simulator

    def simulate(
        self, clip: Clip, episode: PlannedEpisode, max_frames: int | None = None
    ) -> Recording:
        """The recording of ``episode`` (``clip`` is its clip), first ``max_frames`` frames."""
        recording = self.simulator(episode.scenario).simulate(clip, seed=episode.sim_seed)
        return recording.head(max_frames)

    def close(self) -> None:
        """Release the simulators' pybullet client (idempotent)."""
        for simulator in self._simulators.values():
            simulator.close()
        self._simulators = {}
        if self._caster is not None:
            self._caster.close()
            self._caster = None

    def __enter__(self) -> EpisodeSimulator:
        return self

    def __exit__(self, *exc: object) -> None:
        self.close()


def simulate_plan(
    plan: Sequence[PlannedEpisode],
    clips: Mapping[str, Clip],
    *,
    max_frames: int | None = None,
    scenarios: Sequence[str | Scenario] = (),
    progress: bool = False,
) -> list[Recording]:
    """The recordings of a plan, in its order (one simulator per scenario).

    Parameters
    ----------
    plan : sequence of PlannedEpisode
    clips : mapping of str to Clip
        The clips by the names the plan uses.
    max_frames : int, optional
        Keep the first frames of each recording.
    scenarios : sequence of str or Scenario, optional
        Custom scenarios (see :class:`EpisodeSimulator`).
    progress : bool
        Show a progress bar.

    Returns
    -------
    list of Recording

    Raises
    ------
    KeyError
        If the plan names a clip that ``clips`` lacks.
    """
    missing = sorted({e.clip for e in plan} - set(clips))
    if missing:
        raise KeyError(f"clips: the plan names clip(s) {missing} that are not given")
    bar = tqdm(plan, desc="simulating", unit="episode", disable=not progress, leave=False)
    with EpisodeSimulator(scenarios) as simulator:
        return [simulator.simulate(clips[e.clip], e, max_frames) for e in bar]


def simulate_clips(
    clips: Sequence[Clip],
    scenarios: Sequence[str],
    seeds: Sequence[int],
    *,
    max_frames: int | None = None,
    progress: bool = False,
) -> list[Recording]:
    """Recordings of every clip x scenario x seed (the order of :func:`plan_episodes`).

    Clips are planned by name; repeated names become ``name#1``, ``name#2`` ... (as in the env).
    """
    by_name = dict(zip(unique_names(c.name for c in clips), clips, strict=True))
    plan = plan_episodes(list(by_name), scenarios, seeds)
    return simulate_plan(plan, by_name, max_frames=max_frames, progress=progress)

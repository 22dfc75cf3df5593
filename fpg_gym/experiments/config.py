"""What a comparison runs: an episode (:class:`EpisodeSpec`) and the run's settings
(:class:`CompareConfig`)."""

from __future__ import annotations

import re
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

from fpg_gym.core.defaults import DEFAULT_EPISODE_SCENARIOS
from fpg_gym.definitions import load_map, packaged_map_names
from fpg_gym.graph import GRAPH_NAMES
from fpg_gym.io.files import file_digest
from fpg_gym.methods import BASELINE, parse_method
from fpg_gym.simulate import PlannedEpisode
from policies.loading import LEARNED_PREFIXES, model_digest

_SAFE = re.compile(r"[^A-Za-z0-9._+-]+")


def safe_name(text: str) -> str:
    """A file-name-safe form of ``text`` (``:`` and spaces become ``_``)."""
    return _SAFE.sub("_", text).strip("_") or "x"


@dataclass(frozen=True)
class EpisodeSpec:
    """One episode: a clip simulated in a scenario with a seed, or a recording file.

    Attributes
    ----------
    id : str
        Unique, file-name safe (``clip__scenario__s0``).
    clip : str
        Clip name (or the recording's file stem).
    scenario : str
        Simulator scenario (``""`` for a recording file).
    seed : int
        The user's seed (``--seeds``).
    sim_seed : int
        Seed of the simulator and of the optimisers on this episode (every method gets the
        same one: paired comparisons): :func:`fpg_gym.simulate.episode_seed` of ``seed``, the
        clip and the scenario names (of ``seed`` and the file stem for a recording file).
    recording : str
        Recording file of an input episode (``""`` for simulated ones).
    key : str
        Content key: a hash of the input (the recording file's bytes, or the clip's poses and
        rate) and of the episode's settings (scenario, seeds, frame cap). A rerun reuses an
        episode's files and finished rows only when its key is unchanged (``""``: unknown).
    """

    id: str
    clip: str
    scenario: str
    seed: int
    sim_seed: int
    recording: str = ""
    key: str = ""

    @property
    def planned(self) -> PlannedEpisode:
        """The simulated episode this is (:mod:`fpg_gym.simulate.episodes`)."""
        return PlannedEpisode(self.clip, self.scenario, self.seed, self.sim_seed)


#: Where ``compare`` runs its tasks (:attr:`CompareConfig.backend`).
BACKENDS: tuple[str, ...] = ("local", "ray")


@dataclass
class CompareConfig:
    """Everything ``fpg-gym compare`` needs (the CLI fills it from its arguments).

    Attributes
    ----------
    out : str
        Output folder.
    methods : list of str
        Method names (:mod:`fpg_gym.methods`); canonicalised.
    graph : str
        ``"default"`` (the embedded graph without the evaluated embedded clips) or a ``.npz``.
    clips : list of str
        Mocap files/folders, ``"default"`` (the embedded held-out clips
        :data:`fpg_gym.core.defaults.DEFAULT_HOLDOUT_CLIPS`), embedded clip names (``walk`` or
        ``default:walk``).
    inputs : list of str
        Recording files (``.npz`` with ground truth for errors; other formats give timing and
        smoothness only).
    scenarios : list of str
        Simulator scenarios for ``clips``.
    seeds : list of int
    budget : int
        Energy evaluations per frame (2,000).
    k : int
        Candidates per frame (30).
    max_frames : int or None
        Cap on frames per episode (the first ones).
    workers : int
        Processes; 1 runs in this process (local backend).
    batch : int
        Episodes of one reconstruction method reconstructed side by side in one process, their
        searches batched (:func:`fpg_gym.reconstruct.streams.run_streams`; same rows as one by
        one, timings aside); 1 runs them one by one.
    backend : {"local", "ray"}
        Where the tasks run: this machine's processes, or a Ray cluster (``fpg-gym
        [distributed]``; :mod:`fpg_gym.experiments.distributed`).
    address : str or None
        Ray cluster address (``ray.init(address=...)``; None: ``RAY_ADDRESS`` or a local Ray
        started for the run).
    baseline : str
        Method the others are tested against (:data:`fpg_gym.methods.BASELINE`).
    units : str
        BVH units for ``clips``.
    sensor_map, output_map : str or None
        Joint-definition map files (:class:`fpg_gym.definitions.DefinitionMap`) for the
        reconstruction methods (``ReconstructorConfig.sensor_map`` / ``output_map``).
    sensor_blend : float or None
        ``ReconstructorConfig.sensor_blend`` of the reconstruction methods (None: the
        preset's).
    calibrate_output : bool
        ``ReconstructorConfig.calibrate_output`` (False).
    calibration_map : str or None
        Map file for ``ReconstructorConfig.calibration_map``.
    input_format : str or None
        Format of the ``inputs`` (:data:`fpg_gym.io.kinect.KINECT_FORMATS`); None guesses it
        per file.
    sensor : str or None
        The sensor of the episodes (None: what their recordings say,
        :func:`fpg_gym.reconstruct.presets.sensor_of`).
    preset : str
        ``"auto"`` or ``"papers"`` (:mod:`fpg_gym.reconstruct.presets`); the map and blend
        settings above, when given, replace it.
    """

    out: str
    methods: list[str]
    graph: str = "default"
    clips: list[str] = field(default_factory=list)
    inputs: list[str] = field(default_factory=list)
    scenarios: list[str] = field(default_factory=list)
    seeds: list[int] = field(default_factory=lambda: [0])
    budget: int = 2000
    k: int = 30
    max_frames: int | None = None
    workers: int = 1
    batch: int = 8
    backend: str = "local"
    address: str | None = None
    baseline: str = BASELINE.name
    units: str = "auto"
    sensor_map: str | None = None
    output_map: str | None = None
    sensor_blend: float | None = None
    calibrate_output: bool = False
    calibration_map: str | None = None
    input_format: str | None = None
    sensor: str | None = None
    preset: str = "auto"

    def __post_init__(self) -> None:
        self.methods = [parse_method(m).name for m in self.methods]
        if not self.methods:
            raise ValueError("methods: no method to run")
        self.baseline = parse_method(self.baseline).name
        if self.budget < 0:
            raise ValueError(f"budget: expected >= 0 evaluations per frame, got {self.budget}")
        if self.k < 1:
            raise ValueError(f"k: expected >= 1 candidates, got {self.k}")
        if self.max_frames is not None and self.max_frames < 3:
            raise ValueError(f"max_frames: expected at least 3 frames, got {self.max_frames}")
        if not self.clips and not self.inputs:
            raise ValueError("give --clips (with --scenarios) and/or --inputs")
        if self.clips and not self.scenarios:
            self.scenarios = list(DEFAULT_EPISODE_SCENARIOS)
        if self.calibrate_output and self.output_map:
            raise ValueError("calibrate_output and output_map: give one (both set the output map)")
        if self.calibration_map and not self.calibrate_output:
            raise ValueError("calibration_map: only used with calibrate_output")
        if self.batch < 1:
            raise ValueError(f"batch: expected >= 1 episodes side by side, got {self.batch}")
        if self.backend not in BACKENDS:
            raise ValueError(
                f"backend: expected one of {', '.join(BACKENDS)}, got {self.backend!r}"
            )
        if self.address is not None and self.backend != "ray":
            raise ValueError("address: only used with backend 'ray'")
        if not self.seeds:
            raise ValueError("seeds: at least one seed")
        if any(s < 0 for s in self.seeds):
            raise ValueError(f"seeds: expected non-negative integers, got {self.seeds}")
        repeated = sorted({s for s in self.seeds if self.seeds.count(s) > 1})
        if repeated:
            raise ValueError(
                f"seeds: {', '.join(map(str, repeated))} given more than once; each seed is "
                "one set of episodes, counted once"
            )
        if isinstance(self.workers, bool) or not isinstance(self.workers, int) or self.workers < 1:
            raise ValueError(f"workers: expected an integer >= 1, got {self.workers!r}")

    def resume_key(self) -> dict[str, Any]:
        """Settings that must match for a rerun to reuse finished rows: files by their
        content (the graph, the maps), not by their path."""
        return {
            "graph": self.graph if self.graph in GRAPH_NAMES else _file_digest(self.graph),
            "budget": self.budget,
            "k": self.k,
            "max_frames": self.max_frames,
            "units": self.units,
            "sensor_map": _file_digest(self.sensor_map),
            "output_map": _file_digest(self.output_map),
            "sensor_blend": self.sensor_blend,
            "sensor": self.sensor,
            "preset": self.preset,
            **({"calibrate_output": True} if self.calibrate_output else {}),
            **(
                {"calibration_map": _file_digest(self.calibration_map)}
                if self.calibration_map
                else {}
            ),
        }

    def method_keys(self) -> dict[str, str]:
        """A content key per method whose optimiser reads files (``learned:MODEL``): the
        SHA-256 of the model's files, so that a rerun recomputes that method's rows when the
        model changed (the other methods' rows are kept)."""
        keys: dict[str, str] = {}
        for name in self.methods:
            optimizer = parse_method(name).optimizer or ""
            prefix, _, model = optimizer.partition(":")
            if prefix in LEARNED_PREFIXES:
                keys[name] = model_digest(model)
        return keys

    def tuning_options(self) -> dict[str, Any]:
        """The explicit map and blend settings (they replace the preset when any is given)."""
        options: dict[str, Any] = {}
        if self.sensor_blend is not None:
            options["sensor_blend"] = self.sensor_blend
        if self.sensor_map:
            options["sensor_map"] = load_map(self.sensor_map)
        if self.output_map:
            options["output_map"] = load_map(self.output_map)
        if self.calibrate_output:
            options["calibrate_output"] = True
        if self.calibration_map:
            options["calibration_map"] = load_map(self.calibration_map)
        return options


def _file_digest(path: str | None) -> str | None:
    """SHA-256 of a file's bytes (None for no file): settings that name a file are keyed by
    its content, so an edited map or graph is not mistaken for the one a finished row used."""
    if not path:
        return None
    if not Path(path).suffix and path in packaged_map_names():
        return f"packaged:{path}"
    return file_digest(path)

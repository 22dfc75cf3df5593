"""The settings of a training run (:class:`TrainConfig`, ``fpg-gym train-sampler``'s
arguments): their checks, the settings a stopped run's checkpoints must match, and the
reconstructor options of the data and the evaluation."""

from __future__ import annotations

from collections.abc import Callable, Sequence
from dataclasses import asdict, dataclass, field
from pathlib import Path
from typing import Any

import numpy as np

from fpg_gym.core.validation import check_integer, check_number
from fpg_gym.definitions import load_map
from fpg_gym.io import find_mocap_files
from fpg_gym.io.files import file_digest
from fpg_gym.reconstruct.closed_form import DEFAULT_STYLE
from fpg_gym.simulate.occlude import check_occlusion_cases, occlusion_case_names
from policies.imitation import BACKENDS, FOLLOW, TARGETS, TRUTH_TARGETS
from policies.paired_recordings import group_pattern, recording_paths
from policies.rl import RL_REWARDS
from policies.sampler import DEFAULT_FEATURES

__all__ = ["TrainConfig", "config_dict"]

#: :class:`TrainConfig` fields that change neither the data nor the weights.
_RUN_INDEPENDENT = (
    "out",
    "tensorboard",
    "workers",
    "backend",
    "address",
    "progress",
    "restart",
    "eval_every",
    "eval_episodes",
)


@dataclass
class TrainConfig:
    """Settings of :func:`~policies.training.train_sampler` (``fpg-gym train-sampler``'s arguments).

    Attributes
    ----------
    kind : {"supervised", "rl", "linear"}
    out : str
        Model path (``MODEL``: writes ``MODEL.json`` + ``MODEL.pt``; checkpoints in
        ``MODEL.checkpoints/``).
    algo : {"ppo", "sac"}
        RL algorithm (rl only).
    graph : str
        ``"default"`` (embedded, without the held-out clips) or a graph ``.npz``.
    clips : list of str, optional
        Training clips (see :func:`~policies.training.data.training_clips`); a seeded
        ``val_share`` of them is held out for the periodic evaluation unless ``val_clips`` is
        given.
    val_clips : list of str, optional
    scenarios : list of str, optional
        Simulator scenarios (default front-many, left45-many, right45-many).
    timesteps : int, optional
        Env steps (rl, default 100,000) or training frames collected (supervised, default
        20,000).
    seed : int
    target : {"best", "search", "truth", "bones"}
        Supervised target (:func:`~policies.imitation.collect_imitation_data`).
    follow : {"search", "anchor", "truth"}
        What the supervised data's stream continues from
        (:func:`~policies.imitation.collect_imitation_data`; ``"anchor"`` and ``"truth"`` need
        target ``"truth"`` or ``"bones"`` and run no search).
    reward : {"energy", "energy-gain", "error", "combined", "smooth"}
        The RL env's reward (rl; the error modes learn the simulated ground truth; see
        :class:`~fpg_gym.env.KinectPoseEnv` and :class:`policies.rl.EnergyGain`).
    error_weight : float
        Weight of the error in the ``"combined"`` reward.
    smooth_weight : float
        Weight of the output's acceleration (m/s²) in the ``"smooth"`` reward.
    epochs : int
        Supervised epochs.
    eval_every : int, optional
        Periodic evaluation (and checkpoint) every this many env steps (rl, default
        timesteps / 10) or epochs (supervised, default epochs / 5).
    eval_episodes : int
        Held-out episodes evaluated (the first ones of val clips x scenarios).
    max_frames : int, optional
        Frames per episode (the first ones).
    k, latent_dim, action_scale, action_mode : the env's settings.
    features : list of str
        Observation fields the model reads.
    anchor : {"quadratic", "none"}
        What the Gaussian is centred on (:class:`~policies.sampler.FeatureMap`).
    anchor_style : float
        Ridge of the quadratic anchor.
    mirror : bool
        Add the left/right mirror image of every training clip (data augmentation).
    hyperparameters : dict
        Network / algorithm overrides.
    tensorboard : str, optional
        TensorBoard log folder (used only when tensorboard is installed).
    units : str
        BVH units.
    workers : int
        Processes the supervised data's episodes are split between (1: this process; the data
        is the same for any value, :func:`~policies.imitation.collect_imitation_data`), or
        with ``backend="ray"`` the Ray tasks they fill.
    backend : {"local", "ray"}
        Where the supervised data is collected: here and local processes, or Ray
        (``fpg-gym[distributed]``).
    address : str, optional
        Ray cluster address (``backend="ray"``; None: ``RAY_ADDRESS`` or a local instance).
    progress : bool
    restart : bool
        Supervised: start over instead of going on from the checkpoints of a stopped run with
        the same settings (:mod:`policies.checkpoints`); needed when the folder holds a run
        with other settings.
    recordings : list of str, optional
        Kind ``"linear"``: learn from these paired recordings (files or folders of sensor
        streams with ground truth, :mod:`policies.paired_recordings`) instead of simulated
        streams of clips; a seeded ``val_share`` of their groups is held out (0: none, every
        group trains and there is no final evaluation).
    cross_fit : bool
        With ``recordings``: collect each training group's data (and its output correction's)
        with a graph and a sensor map built from the other training groups' recordings, as a
        new subject's are built without it (:func:`policies.paired_recordings.group_databases`;
        True); False: with ``graph`` and ``sensor_map``, which contain every group.
    occlusions : list of str
        With ``recordings``: each training recording is also learnt from once with one of these
        occlusion cases put in (in turn; :func:`policies.paired_recordings.with_occlusions`;
        every case of :mod:`fpg_gym.simulate.occlude` by default, empty for none); the graphs
        and maps are built from the recordings as they are.
    group_pattern : str, optional
        With ``recordings``: regular expression on the file names whose first group names a
        recording's group (e.g. its subject); each recording is its own group otherwise.
    sensor_map : str, optional
        Joint-definition map of the sensor (``fpg-gym fit-map``), for the data and the
        evaluation, as ``fpg-gym reconstruct --sensor-map`` uses it.
    sensor_blend : float
        The reconstructor's ``sensor_blend`` for the data and the evaluation (0).
    correction : bool
        Kind ``"linear"``: learn a correction of the reconstructor's output from the fitted
        sampler's own outputs of the training recordings or streams, its settings
        cross-validated over the same groups (:mod:`policies.output_correction`; True).
    """

    kind: str
    out: str
    algo: str = "ppo"
    graph: str = "default"
    clips: list[str] | None = None
    val_clips: list[str] | None = None
    val_share: float = 0.2
    scenarios: list[str] | None = None
    timesteps: int | None = None
    seed: int = 0
    target: str = "best"
    follow: str = "search"
    reward: str = "energy"
    error_weight: float = 1.0
    smooth_weight: float = 0.002
    epochs: int = 40
    eval_every: int | None = None
    eval_episodes: int = 6
    max_frames: int | None = None
    k: int = 30
    latent_dim: int = 20
    action_scale: float = 3.0
    action_mode: str = "absolute"
    features: list[str] = field(default_factory=lambda: list(DEFAULT_FEATURES))
    anchor: str = "quadratic"
    anchor_style: float = DEFAULT_STYLE
    mirror: bool = True
    hyperparameters: dict[str, Any] = field(default_factory=dict)
    tensorboard: str | None = None
    units: str = "auto"
    workers: int = 1
    backend: str = "local"
    address: str | None = None
    progress: bool = True
    restart: bool = False
    recordings: list[str] | None = None
    group_pattern: str | None = None
    sensor_map: str | None = None
    sensor_blend: float = 0.0
    correction: bool = True
    cross_fit: bool = True
    occlusions: list[str] = field(default_factory=lambda: list(occlusion_case_names()))

    def __post_init__(self) -> None:
        if self.kind not in ("supervised", "rl", "linear"):
            raise ValueError(f"kind: expected 'supervised', 'rl' or 'linear', got {self.kind!r}")
        if self.kind == "linear" and (
            self.target not in TRUTH_TARGETS or self.action_mode != "absolute"
        ):
            raise ValueError(
                "kind 'linear' learns the ground truth in absolute actions: target 'bones' or "
                f"'truth' and action_mode 'absolute' (got {self.target!r}, {self.action_mode!r})"
            )
        if self.algo not in ("ppo", "sac"):
            raise ValueError(f"algo: expected 'ppo' or 'sac', got {self.algo!r}")
        check_integer(self.seed, "seed", low=0)
        check_integer(self.k, "k", low=1)
        check_integer(self.latent_dim, "latent_dim", low=1)
        if self.eval_every is not None:
            check_integer(self.eval_every, "eval_every", low=1)
        check_number(self.action_scale, "action_scale", low=0, low_open=True)
        if self.target not in TARGETS:
            raise ValueError(f"target: expected one of {TARGETS}, got {self.target!r}")
        if self.follow not in FOLLOW or (
            self.follow != "search" and self.target not in TRUTH_TARGETS
        ):
            raise ValueError(
                f"follow: expected one of {FOLLOW} ('anchor' and 'truth' with target 'truth' "
                "or 'bones'), "
                f"got {self.follow!r} with target {self.target!r}"
            )
        if self.reward not in RL_REWARDS:
            raise ValueError(f"reward: expected one of {RL_REWARDS}, got {self.reward!r}")
        if self.timesteps is not None and self.timesteps < 1:
            raise ValueError(f"timesteps: expected >= 1, got {self.timesteps}")
        if self.epochs < 1:
            raise ValueError(f"epochs: expected >= 1, got {self.epochs}")
        if self.eval_episodes < 1:
            raise ValueError(f"eval_episodes: expected >= 1, got {self.eval_episodes}")
        if self.max_frames is not None and self.max_frames < 2:
            raise ValueError(f"max_frames: expected >= 2, got {self.max_frames}")
        if self.workers < 1:
            raise ValueError(f"workers: expected >= 1, got {self.workers}")
        if not (0.0 < self.val_share < 1.0 or (self.val_share == 0.0 and self.recordings)):
            raise ValueError(
                f"val_share: expected a share in (0, 1) (0 only with recordings), got "
                f"{self.val_share}"
            )
        if self.backend not in BACKENDS:
            raise ValueError(f"backend: expected one of {BACKENDS}, got {self.backend!r}")
        if self.recordings is not None:
            if self.kind != "linear":
                raise ValueError(
                    "recordings: only kind 'linear' learns from paired recordings "
                    f"(got {self.kind!r})"
                )
            if self.clips is not None or self.val_clips is not None:
                raise ValueError("recordings: give clips or recordings, not both")
        elif self.group_pattern is not None:
            raise ValueError("group_pattern: only used with recordings")
        group_pattern(self.group_pattern)  # a regular expression with a group
        check_occlusion_cases(self.occlusions)
        if not (np.isfinite(self.sensor_blend) and 0.0 <= self.sensor_blend <= 1.0):
            raise ValueError(f"sensor_blend: expected a value in [0, 1], got {self.sensor_blend}")
        if not self.correction and self.kind != "linear":
            raise ValueError(
                f"correction: only kind 'linear' learns an output correction (got {self.kind!r})"
            )
        if self.kind == "rl" and (self.backend != "local" or self.workers != 1):
            raise ValueError(
                "backend and workers: they split the supervised data collection; "
                "--kind rl runs one environment here"
            )

    def run_settings(self) -> dict[str, Any]:
        """The settings that decide a supervised run's data and weights (what its checkpoints
        must match): every field but where and how it runs (output, progress, TensorBoard,
        workers, backend, periodic evaluation), with the graph file's SHA-256."""
        settings = asdict(self)
        for name in _RUN_INDEPENDENT:
            settings.pop(name)
        if self.recordings is None:  # only recordings are occluded
            settings.pop("occlusions")
        if self.graph != "default" and Path(self.graph).is_file():
            settings["graph_sha256"] = file_digest(self.graph)
        if self.sensor_map is not None and Path(self.sensor_map).is_file():
            settings["sensor_map_sha256"] = file_digest(self.sensor_map)
        # The data's content, not its names: an edited take under the same path is new data.
        for name, items, find in (
            ("clips", self.clips, find_mocap_files),
            ("val_clips", self.val_clips, find_mocap_files),
            ("recordings", self.recordings, recording_paths),
        ):
            if items is not None:
                settings[f"{name}_sha256"] = _content_digests(items, find)
        return settings

    def reconstructor_options(self) -> dict[str, Any]:
        """The reconstructor settings of the data and the evaluation: ``sensor_blend`` and the
        ``sensor_map`` read from its file (or a packaged map by name)."""
        options: dict[str, Any] = {"sensor_blend": self.sensor_blend}
        if self.sensor_map is not None:
            options["sensor_map"] = load_map(self.sensor_map)
        return options

    @property
    def total_timesteps(self) -> int:
        """``timesteps`` or the kind's default."""
        if self.timesteps is not None:
            return int(self.timesteps)
        return 100_000 if self.kind == "rl" else 20_000


def _content_digests(
    items: Sequence[str], find: Callable[[Sequence[str]], list[Path]]
) -> list[str]:
    """SHA-256 of every file ``items`` name (folders expanded by ``find``), in order; an item
    that names no file (``default``, an embedded clip's name) stands for itself."""
    digests: list[str] = []
    for item in items:
        if Path(item).exists():
            digests.extend(file_digest(path) for path in find([item]))
        else:
            digests.append(str(item))
    return digests


def config_dict(config: TrainConfig) -> dict[str, Any]:
    """``config`` as plain data (for JSON summaries)."""
    data = asdict(config)
    data["total_timesteps"] = config.total_timesteps
    return data

"""Training data, evaluation and the training driver behind ``fpg-gym train-sampler``.

* :func:`training_clips` / :func:`split_clips`: the clips a sampler learns from and the held-out
  ones it is validated on (by whole clips, seeded). By default the embedded DeepMimic clips of
  the default graph (:data:`fpg_gym.io.DEFAULT_CLIP_NAMES` less
  :data:`fpg_gym.core.defaults.DEFAULT_HOLDOUT_CLIPS`): never the evaluation clips.
* :func:`simulate_episodes`: Kinect streams simulated from clips x scenarios x seeds.
* :func:`collect_imitation_data`: (observation, target action) pairs for the supervised sampler,
  rolled through the :class:`~fpg_gym.reconstruct.Reconstructor` with the papers' local search.
* :func:`evaluate_agents`: mean energy, mean error, Err0.2, evaluations and ms per frame of
  optimisers (a learned sampler through :mod:`policies.learned_optimizers`) on episodes.
* :func:`train_sampler`: the whole run (:class:`TrainConfig` -> :class:`TrainResult`).
"""

from __future__ import annotations

import importlib.metadata as md
import importlib.util
import time
from collections.abc import Callable, Sequence
from dataclasses import asdict, dataclass, field
from dataclasses import fields as dataclass_fields
from dataclasses import replace as dataclass_replace
from pathlib import Path
from typing import Any

import numpy as np

from fpg_gym.core import metrics
from fpg_gym.core.defaults import DEFAULT_EPISODE_SCENARIOS, DEFAULT_HOLDOUT_CLIPS
from fpg_gym.core.poses import mirror
from fpg_gym.core.validation import check_integer, check_number
from fpg_gym.definitions import load_map
from fpg_gym.graph import GRAPH_NAMES, load_graph
from fpg_gym.io import DEFAULT_CLIP_NAMES, Clip, find_mocap_files, resolve_clips
from fpg_gym.io.files import file_digest
from fpg_gym.reconstruct import Reconstructor, TemporalConfig
from fpg_gym.reconstruct.batched import run_streams
from fpg_gym.reconstruct.closed_form import DEFAULT_STYLE
from fpg_gym.runtime.ray_session import check_address, require_ray
from fpg_gym.simulate import simulate_clips
from fpg_gym.simulate.occlude import check_occlusion_cases, occlusion_case_names
from optimizers.local_search import LocalSearch
from optimizers.random_search import RandomSearch
from policies.checkpoints import RunCheckpoints
from policies.imitation import (
    BACKENDS,
    FOLLOW,
    TARGETS,
    TRUTH_TARGETS,
    ImitationData,
    collect_imitation_data,
    frame_caps,
    truth_latent,
)
from policies.learned_optimizers import LearnedSampler, LearnedSearch
from policies.loading import load_sampler
from policies.output_correction import CorrectionSource, learn_correction
from policies.paired_recordings import (
    GroupDatabase,
    PairedRecordings,
    group_databases,
    group_pattern,
    paired_recordings,
    recording_paths,
    with_occlusions,
)
from policies.pose_sampler import (
    LINEAR_FEATURES,
    LinearPoseSampler,
    describe_fit,
    fit_linear,
)
from policies.rl import RL_REWARDS, UNTRAINED_CHECKPOINT, train_rl, zero_action
from policies.sampler import (
    DEFAULT_FEATURES,
    AnchorSampler,
    GaussianSampler,
    SamplerSpec,
    import_learn,
    model_paths,
)
from policies.supervised import SupervisedSampler, fit_supervised

__all__ = [
    "FOLLOW",
    "TARGETS",
    "ImitationData",
    "TrainConfig",
    "TrainResult",
    "collect_imitation_data",
    "default_training_clip_names",
    "evaluate_agents",
    "mirror_clip",
    "simulate_episodes",
    "split_clips",
    "train_sampler",
    "training_clips",
    "truth_latent",
]


def default_training_clip_names() -> list[str]:
    """The embedded clips of the default graph (all but the held-out evaluation clips)."""

    return [n for n in DEFAULT_CLIP_NAMES if n not in DEFAULT_HOLDOUT_CLIPS]


def training_clips(
    items: Sequence[str] | None, *, units: str = "auto", progress: bool = False
) -> list[Any]:
    """Clips named by ``--clips``: None or ``"default"`` for :func:`default_training_clip_names`,
    embedded clip names, mocap files or folders (as ``fpg-gym compare --clips``)."""

    names: list[str] = []
    for item in items or ["default"]:
        if str(item) == "default":
            names.extend(default_training_clip_names())
        else:
            names.append(str(item))
    clips, _ = resolve_clips(names, units=units, progress=progress)
    unique: dict[str, Any] = {}
    for clip in clips:
        unique.setdefault(clip.name, clip)
    if not unique:
        raise ValueError("--clips: no clip to train on")
    return list(unique.values())


def mirror_clip(clip: Any) -> Any:
    """The left/right mirror image of a clip (``name~mirror``), for data augmentation."""

    return Clip(
        name=f"{clip.name}~mirror",
        positions=mirror(clip.positions).astype(np.float32),
        fps=clip.fps,
        source=clip.source,
        metadata={**clip.metadata, "mirrored": True},
    )


def split_clips(
    clips: Sequence[Any], share: float = 0.2, seed: int = 0
) -> tuple[list[Any], list[Any]]:
    """``(training, validation)``: a seeded ``share`` of the clips (at least one, by whole
    clips) held out for validation; with a single clip both are that clip."""
    if not 0.0 < share < 1.0:
        raise ValueError(f"share: expected a value in (0, 1), got {share}")
    if len(clips) < 2:
        return list(clips), list(clips)
    order = np.random.default_rng(seed).permutation(len(clips))
    count = max(1, round(share * len(clips)))
    held = sorted(int(i) for i in order[:count])
    kept = sorted(int(i) for i in order[count:])
    return [clips[i] for i in kept], [clips[i] for i in held]


def simulate_episodes(
    clips: Sequence[Any],
    scenarios: Sequence[str],
    seeds: Sequence[int],
    *,
    max_frames: int | None = None,
) -> list[Any]:
    """Recordings of every clip x scenario x seed (first ``max_frames`` frames), in that
    order (seed outermost), seeded by the episode planner's rule
    (:func:`fpg_gym.simulate.simulate_clips`)."""

    return simulate_clips(clips, scenarios, seeds, max_frames=max_frames)


# --------------------------------------------------------------------------- evaluation


def evaluate_agents(
    graph: Any,
    recordings: Sequence[Any],
    agents: dict[str, Any],
    *,
    k: int = 30,
    latent_dim: int = 20,
    seed: int = 0,
    progress: bool = False,
    reconstructor_options: dict[str, Any] | None = None,
) -> dict[str, dict[str, float]]:
    """Reconstruct ``recordings`` with each agent (an optimiser name or object) and summarise.

    The reconstructors run the env's per-frame problem (temporal stage off, no ragdoll) with
    ``reconstructor_options`` on top (a sensor map, a sensor blend...).

    Returns, per agent: ``mean_energy``, ``mean_error`` (FPG Eq. 13, m) with
    ``error_ci_low``/``error_ci_high`` (its 95 % bootstrap interval over the recordings,
    :func:`fpg_gym.core.metrics.bootstrap_mean_ci`: a few episodes give a wide one), ``err02``
    (share of frames with error >= 0.2 m), ``jitter`` (the output's mean joint acceleration, m/s²,
    :func:`fpg_gym.core.metrics.jitter`, averaged over the recordings), ``evaluations`` and ``ms``
    per frame, ``frames``. Errors need ground truth (NaN otherwise).
    """

    # One reconstructor per recording: the recordings run side by side, their searches batched
    # (fpg_gym.reconstruct.batched; each stream as alone with seed + i).
    reconstructors = [
        Reconstructor(
            graph,
            **{
                "k": k,
                "latent_dim": latent_dim,
                "ragdoll": False,
                "temporal": TemporalConfig.off(),
                **(reconstructor_options or {}),
            },
        )
        for _ in recordings
    ]
    out: dict[str, dict[str, float]] = {}
    try:
        for name, agent in agents.items():
            energies: list[np.ndarray] = []
            errors: list[np.ndarray] = []
            jitters: list[float] = []
            evaluations: list[np.ndarray] = []
            ms: list[np.ndarray] = []
            seeds = [seed + i for i in range(len(recordings))]
            results = run_streams(reconstructors, recordings, agent, seeds)
            for recording, result in zip(recordings, results, strict=True):
                arrays = result.arrays()
                energies.append(arrays["energy"])
                evaluations.append(arrays["evaluations"])
                ms.append(arrays["ms_per_frame"])
                if len(result.poses) >= 3:
                    jitters.append(
                        float(np.nanmean(metrics.jitter(result.poses, fps=recording.fps)))
                    )
                truth = recording.head(len(result.poses)).ground_truth
                if truth is not None:
                    errors.append(metrics.frame_error(truth, result.poses))
            err = np.concatenate(errors) if errors else np.array([np.nan])
            low, high = (
                metrics.bootstrap_mean_ci(
                    [np.mean(e) for e in errors], weights=[len(e) for e in errors], rng=seed
                )
                if errors
                else (np.nan, np.nan)
            )
            out[name] = {
                "mean_energy": float(np.mean(np.concatenate(energies))),
                "mean_error": float(np.mean(err)),
                "error_ci_low": low,
                "error_ci_high": high,
                "err02": metrics.err_ratio(err) if errors else np.nan,
                "jitter": float(np.mean(jitters)) if jitters else np.nan,
                "evaluations": float(np.mean(np.concatenate(evaluations))),
                "ms": float(np.mean(np.concatenate(ms))),
                "frames": int(sum(len(e) for e in energies)),
            }
            if progress:
                print(_format_row(name, out[name]), flush=True)
    finally:
        for reconstructor in reconstructors:
            reconstructor.close()
    return out


def _format_row(name: str, row: dict[str, float]) -> str:
    return (
        f"  {name:<22} energy {row['mean_energy']:.4f}  error {row['mean_error']:.4f} m  "
        f"Err0.2 {100 * row['err02']:.1f} %  jitter {row['jitter']:.2f} m/s²  "
        f"evals {row['evaluations']:.0f}  "
        f"{row['ms']:.2f} ms/frame"
    )


def format_evaluation(table: dict[str, dict[str, float]]) -> str:
    """A markdown table of :func:`evaluate_agents`' output."""
    lines = [
        "| agent | mean energy | mean error (m) [95 % CI over episodes] | Err0.2 (%) "
        "| jitter (m/s²) | evaluations/frame | ms/frame |",
        "| --- | --- | --- | --- | --- | --- | --- |",
    ]
    for name, row in table.items():
        lines.append(
            f"| {name} | {row['mean_energy']:.4f} | {row['mean_error']:.4f} "
            f"[{row.get('error_ci_low', np.nan):.4f}, {row.get('error_ci_high', np.nan):.4f}] | "
            f"{100 * row['err02']:.1f} | {row['jitter']:.2f} | {row['evaluations']:.0f} | "
            f"{row['ms']:.2f} |"
        )
    return "\n".join(lines)


# --------------------------------------------------------------------------- driver


#: Cross-validation groups of the linear sampler's training episodes (:func:`_train_linear`).
LINEAR_GROUPS = 5

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
    """Settings of :func:`train_sampler` (``fpg-gym train-sampler``'s arguments).

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
        Training clips (see :func:`training_clips`); a seeded ``val_share`` of them is held out
        for the periodic evaluation unless ``val_clips`` is given.
    val_clips : list of str, optional
    scenarios : list of str, optional
        Simulator scenarios (default front-many, left45-many, right45-many).
    timesteps : int, optional
        Env steps (rl, default 100,000) or training frames collected (supervised, default
        20,000).
    seed : int
    target : {"best", "search", "truth", "bones"}
        Supervised target (:func:`collect_imitation_data`).
    follow : {"search", "anchor", "truth"}
        What the supervised data's stream continues from (:func:`collect_imitation_data`;
        ``"anchor"`` and ``"truth"`` need target ``"truth"`` or ``"bones"`` and run no
        search).
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
        is the same for any value, :func:`collect_imitation_data`), or with ``backend="ray"``
        the Ray tasks they fill.
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


@dataclass
class TrainResult:
    """What :func:`train_sampler` did.

    Attributes
    ----------
    model : str
        Path of the model's JSON.
    sampler : GaussianSampler
    history : list of dict
        Periodic evaluations (and, supervised, every epoch's losses).
    evaluation : dict
        Final evaluation on the held-out episodes (see :func:`evaluate_agents`).
    seconds : dict
        Wall time per phase (``data``, ``train``, ``evaluate``, ``total``).
    """

    model: str
    sampler: GaussianSampler
    history: list[dict[str, Any]]
    evaluation: dict[str, dict[str, float]]
    seconds: dict[str, float]


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


def _load_graph(name: str) -> Any:
    """``--graph``: a file, ``default`` (the embedded graph without the held-out clips) or a
    packaged graph by name (:data:`fpg_gym.graph.GRAPH_NAMES`)."""
    if name not in GRAPH_NAMES and not Path(name).is_file():
        raise FileNotFoundError(f"--graph: {name}: no such file")
    return load_graph(name, exclude=DEFAULT_HOLDOUT_CLIPS)


def _held_out_clash(graph_name: str, clips: Sequence[Any]) -> list[str]:
    """Training clips that are evaluation clips of the default protocol."""

    if graph_name != "default":
        return []
    return sorted({c.name for c in clips} & set(DEFAULT_HOLDOUT_CLIPS))


def train_sampler(config: TrainConfig, *, log: Callable[[str], None] | None = None) -> TrainResult:
    """Train a sampler as ``config`` says: data / env, training with periodic held-out
    evaluation and checkpoints, save, final evaluation (learned, learned+search and the
    baselines none / random-search(200) / local-search on the held-out episodes).

    Raises
    ------
    ValueError
        Bad settings, or training clips that are the default protocol's evaluation clips.
    optimizers.MissingDependency
        torch / stable-baselines3 missing (``pip install 'fpg-gym[learn]'``).
    fpg_gym.ray_session.RayUnavailable
        ``backend="ray"`` without Ray (``pip install 'fpg-gym[distributed]'``).
    """

    if config.kind != "linear":  # the linear sampler needs numpy only
        import_learn("torch")
    if config.kind == "rl":
        import_learn("stable_baselines3")
    if config.backend == "ray":
        require_ray()  # before any work
        check_address(config.address)  # a dead address fails now, not after minutes
    say = log or (lambda text: print(text, flush=True))
    started = time.perf_counter()
    seconds: dict[str, float] = {}
    scenarios = list(config.scenarios or DEFAULT_EPISODE_SCENARIOS)
    graph = _load_graph(config.graph)
    options = config.reconstructor_options()
    paired = None
    databases: list[GroupDatabase] | None = None
    if config.recordings is not None:
        paired = paired_recordings(
            config.recordings,
            pattern=config.group_pattern,
            val_share=config.val_share,
            episodes=config.eval_episodes,
            max_frames=config.max_frames,
            seed=config.seed,
            log=say,
        )
        validation = paired.validation
        held = (
            f"{len(validation)} held-out recordings of the groups "
            f"{', '.join(paired.info['validation_groups'])}"
            if validation
            else "no group held out (--val-share 0: no final evaluation)"
        )
        say(
            f"train-sampler: linear (target {config.target}), "
            f"{len(paired.train)} training recordings in "
            f"{len(paired.info['training_groups'])} groups, {held}, "
            + ("each group's data with a graph and sensor map without it, " * config.cross_fit)
            + f"seed {config.seed}"
        )
        training_data: dict[str, Any] = {
            **paired.info,
            "cross_fit": config.cross_fit,
            "occlusions": list(config.occlusions),
        }
        if config.cross_fit:  # before any other work: a graph that cannot be cross-fitted
            t0 = time.perf_counter()
            databases = group_databases(
                paired, graph, options.get("sensor_map"), source=config.graph
            )
            say(
                f"cross-fitting: {len(databases)} graphs and sensor maps, each without its "
                f"group ({time.perf_counter() - t0:.1f} s)"
            )
        if config.occlusions:  # after the databases: they are built from the real streams
            paired = with_occlusions(paired, config.occlusions, config.seed)
            say(
                f"occlusions: each training recording also with one of "
                f"{', '.join(config.occlusions)} put in ({len(paired.train)} recordings)"
            )
    else:
        clips = training_clips(config.clips, units=config.units, progress=config.progress)
        if config.val_clips:
            val_clips = training_clips(config.val_clips, units=config.units)
            train_clips = clips
        else:
            train_clips, val_clips = split_clips(clips, config.val_share, config.seed)
        clash = _held_out_clash(config.graph, list(train_clips) + list(val_clips))
        if config.mirror:
            train_clips = list(train_clips) + [mirror_clip(c) for c in train_clips]
        if clash:
            raise ValueError(
                f"--clips {clash}: these are the held-out evaluation clips of the default "
                "graph; train on other clips (the default: the clips the default graph is "
                "built from)"
            )
        say(
            f"train-sampler: {config.kind}"
            + (f" ({config.algo})" if config.kind == "rl" else f" (target {config.target})")
            + f", {len(train_clips)} training clips, {len(val_clips)} validation clips, "
            f"scenarios {','.join(scenarios)}, {config.total_timesteps} timesteps, "
            f"seed {config.seed}"
        )
        val_seeds = [10_000 + config.seed]
        validation = simulate_episodes(
            val_clips, scenarios, val_seeds, max_frames=config.max_frames
        )[: config.eval_episodes]
        training_data = {
            "clips": [c.name for c in train_clips],
            "validation_clips": [c.name for c in val_clips],
            "scenarios": scenarios,
        }
    if config.kind == "linear":  # before any work: the fit cross-validates over whole units
        _check_linear_units(
            [group for group, _ in paired.train]
            if paired is not None
            else [c.name.removesuffix("~mirror") for c in train_clips]
        )
    out_json, stem = model_paths(config.out)
    checkpoints = stem.with_name(stem.name + ".checkpoints")
    # A supervised run goes on from a stopped one's files (or refuses other settings) now,
    # before any work.
    run = (
        RunCheckpoints(checkpoints, config.run_settings(), restart=config.restart, log=say)
        if config.kind in ("supervised", "linear")
        else None
    )
    training_info: dict[str, Any] = {
        "graph": config.graph,
        **training_data,
        "sensor_map": config.sensor_map,
        "sensor_blend": config.sensor_blend,
        # Recordings: every frame unless timesteps caps them.
        "timesteps": config.timesteps if paired is not None else config.total_timesteps,
        "seed": config.seed,
        "max_frames": config.max_frames,
        "versions": _versions(config.kind),
    }

    def evaluate(sampler: GaussianSampler, agents: dict[str, Any] | None = None) -> dict[str, Any]:
        table = evaluate_agents(
            graph,
            validation,
            agents or {"mean": LearnedSampler(sampler, samples=1)},
            k=config.k,
            latent_dim=config.latent_dim,
            seed=config.seed,
            reconstructor_options=options,
        )
        return table

    if run is not None and config.kind == "linear":
        source = paired if paired is not None else train_clips
        sampler, history = _train_linear(
            config, graph, source, scenarios, options, run, seconds, say, databases
        )
    elif run is not None:
        sampler, history = _train_supervised(
            config,
            graph,
            train_clips,
            scenarios,
            options,
            training_info,
            evaluate,
            checkpoints,
            run,
            seconds,
            say,
        )
    else:
        t0 = time.perf_counter()
        sampler, history = train_rl(
            graph=graph,
            clips=train_clips,
            scenarios=scenarios,
            algo=config.algo,
            timesteps=config.total_timesteps,
            seed=config.seed,
            k=config.k,
            latent_dim=config.latent_dim,
            action_scale=config.action_scale,
            action_mode=config.action_mode,
            max_frames=config.max_frames,
            features=config.features,
            anchor=config.anchor,
            anchor_style=config.anchor_style,
            hyperparameters=config.hyperparameters,
            reward_mode=config.reward,
            error_weight=config.error_weight,
            smooth_weight=config.smooth_weight,
            evaluate=evaluate,
            eval_every=config.eval_every or max(config.total_timesteps // 10, 1),
            checkpoints=checkpoints,
            tensorboard=_tensorboard_dir(config.tensorboard, say),
            progress=config.progress,
            log=say,
        )
        seconds["train"] = time.perf_counter() - t0
        training_info["reward"] = config.reward
        if config.reward == "combined":
            training_info["error_weight"] = config.error_weight
        if config.reward == "smooth":
            training_info["smooth_weight"] = config.smooth_weight
    sampler.spec.training = {**training_info, "seconds": dict(seconds), "history": history}
    t0 = time.perf_counter()
    if not validation:  # every group trained (val_share 0): nothing left to score
        seconds["total"] = time.perf_counter() - started
        sampler.spec.training["seconds"] = dict(seconds)
        path = sampler.save(out_json)
        if run is not None:
            run.finish()
        say(f"saved {path} ({sampler.spec.weights}); no held-out group, no final evaluation")
        return TrainResult(str(path), sampler, history, {}, seconds)

    final = evaluate(
        sampler,
        {
            "none (x0)": "none",
            "random-search (200)": RandomSearch(samples=100, iterations=2),
            "local-search (2000)": "local-search",
            "anchor only (1)": LearnedSampler(AnchorSampler(sampler.spec), samples=1),
            "mean action (1)": LearnedSampler(sampler, samples=1),
            "learned (200)": LearnedSampler(sampler),
            "learned+search (200)": LearnedSearch(sampler),
            **(
                {"learned, uncorrected (200)": LearnedSampler(sampler, correct_output=False)}
                if getattr(sampler, "output_correction", None) is not None
                else {}
            ),
            **(_policy_references(sampler, checkpoints) if config.kind == "rl" else {}),
        },
    )
    seconds["evaluate"] = time.perf_counter() - t0
    seconds["total"] = time.perf_counter() - started
    sampler.spec.training["seconds"] = dict(seconds)
    sampler.spec.training["evaluation"] = final
    path = sampler.save(out_json)
    if run is not None:
        run.finish()  # the model is written: its data and fit state are no longer needed
    say(f"saved {path} ({sampler.spec.weights})")
    say(f"final evaluation on {len(validation)} held-out episodes:\n" + format_evaluation(final))
    return TrainResult(str(path), sampler, history, final, seconds)


def _policy_references(sampler: Any, checkpoints: Path) -> dict[str, Any]:
    """What an RL sampler's proposals must beat, at the same 200 evaluations: the local
    search alone, and ``learned+search`` with the untrained policy (its step-0 checkpoint) and
    with the zero action (:func:`policies.rl.zero_action`)."""
    rows: dict[str, Any] = {
        "local-search (200)": LocalSearch(iterations=2),
        "zero action, learned+search (200)": LearnedSearch(zero_action(sampler)),
    }
    untrained = checkpoints / f"{UNTRAINED_CHECKPOINT}.json"
    if untrained.is_file():
        rows["untrained, learned+search (200)"] = LearnedSearch(load_sampler(untrained))
    return rows


def _imitation_spec(
    config: TrainConfig, kind: str, algo: str, features: Sequence[str], **hyperparameters: Any
) -> SamplerSpec:
    """The spec of a sampler trained on imitation pairs (supervised or linear)."""
    return SamplerSpec.for_layout(
        kind,
        algo,
        config.latent_dim,
        config.k,
        features=list(features),
        anchor=config.anchor,
        anchor_style=config.anchor_style,
        action_mode=config.action_mode,
        action_scale=config.action_scale,
        hyperparameters={
            **config.hyperparameters,
            "target": config.target,
            "follow": config.follow,
            **hyperparameters,
        },
    )


def _imitation_pairs(
    config: TrainConfig,
    graph: Any,
    train_clips: Sequence[Any],
    scenarios: Sequence[str],
    options: dict[str, Any],
    spec: SamplerSpec,
    run: RunCheckpoints,
    seconds: dict[str, float],
    say: Callable[[str], None],
) -> tuple[ImitationData, np.ndarray, list[Any]]:
    """The supervised and linear samplers' training pairs: simulated streams of the training
    clips, collected (or read back from a stopped run's checkpoints) as ``config`` says with
    the reconstructor ``options``; the index in ``train_clips`` of each episode's clip; and
    the streams (in episode order)."""

    t0 = time.perf_counter()
    frames_per_pass = sum(
        min(c.num_frames, config.max_frames or c.num_frames) for c in train_clips
    ) * len(scenarios)
    passes = max(1, -(-config.total_timesteps // max(frames_per_pass, 1)))
    seeds = [config.seed * 1000 + i for i in range(passes)]
    recordings = simulate_episodes(train_clips, scenarios, seeds, max_frames=config.max_frames)
    order = np.random.default_rng(config.seed).permutation(len(recordings))
    recordings = [recordings[i] for i in order]
    # Each episode's clip (simulate_episodes: seed outermost, then clip, then scenario).
    clip_of_episode = (order // len(scenarios)) % len(train_clips)
    data = _collect_pairs(
        config,
        [(np.arange(len(recordings)), graph, options)],
        recordings,
        spec,
        run,
        frames=config.total_timesteps,
        started=t0,
        seconds=seconds,
        say=say,
    )
    return data, clip_of_episode, recordings


def _collect_pairs(
    config: TrainConfig,
    setups: Sequence[tuple[np.ndarray, Any, dict[str, Any]]],
    recordings: Sequence[Any],
    spec: SamplerSpec,
    run: RunCheckpoints,
    *,
    frames: int | None,
    started: float,
    seconds: dict[str, float],
    say: Callable[[str], None],
) -> ImitationData:
    """Imitation pairs of ``recordings`` (at most ``frames``, in recording order), collected
    as ``config`` says, each ``(episodes, graph, reconstructor options)`` of ``setups`` its
    recordings with its graph and options; or read back from a stopped run's checkpoints.
    Episodes are numbered by their index in ``recordings``."""
    collected = run.collected_episodes()
    if collected:
        say(f"{run.folder}: going on from {len(collected)} collected episodes")
    caps = frame_caps(recordings, frames)
    parts = []
    for episodes, graph, options in setups:
        episodes = np.asarray(episodes, dtype=np.int64)

        def save(chunk: Sequence[int], pairs: ImitationData, ids: np.ndarray = episodes) -> Any:
            """A chunk's pairs saved under the episodes' numbers in ``recordings``."""
            pairs = dataclass_replace(pairs, episodes=ids[pairs.episodes])
            return run.save_chunk(ids[np.asarray(chunk)].tolist(), pairs)

        part = collect_imitation_data(
            graph,
            [recordings[e].head(max(caps[e], 1)) for e in episodes],
            spec,
            target=config.target,
            follow=config.follow,
            seed=config.seed,
            progress=config.progress,
            reconstructor_options=options,
            workers=config.workers,
            backend=config.backend,
            address=config.address,
            skip=[i for i, e in enumerate(episodes) if e in collected or caps[e] == 0],
            on_chunk=save,
        )
        parts.append(dataclass_replace(part, episodes=episodes[part.episodes]))
    data = run.merged_data(_in_episode_order(parts))
    seconds["data"] = time.perf_counter() - started
    say(
        f"imitation data: {len(data)} frames from {len(set(data.episodes.tolist()))} episodes "
        f"in {seconds['data']:.1f} s"
    )
    return data


def _in_episode_order(parts: Sequence[ImitationData]) -> ImitationData:
    """The pairs of ``parts`` ordered by episode (each episode's frames in order)."""
    merged = ImitationData.concatenate(parts)
    order = np.argsort(merged.episodes, kind="stable")
    return ImitationData(*(getattr(merged, f.name)[order] for f in dataclass_fields(merged)))


def _train_linear(
    config: TrainConfig,
    graph: Any,
    source: PairedRecordings | Sequence[Any],
    scenarios: Sequence[str],
    options: dict[str, Any],
    run: RunCheckpoints,
    seconds: dict[str, float],
    say: Callable[[str], None],
    databases: Sequence[GroupDatabase] | None = None,
) -> tuple[GaussianSampler, list[dict[str, Any]]]:
    """The linear pose-space sampler (:mod:`policies.pose_sampler`) on the training
    recordings of paired ``source``, its settings chosen by cross-validation over their
    groups (one per group; with ``databases``, each group's data collected with its graph and
    sensor map, :func:`policies.paired_recordings.group_databases`), or on simulated streams
    of the clips ``source``, over groups of whole clips; with ``config.correction``, its
    output correction learnt from its own outputs of the same recordings, reconstructed as
    their data were, cross-validated over the same groups."""

    spec = _imitation_spec(config, "linear", "ridge", LINEAR_FEATURES)
    if isinstance(source, PairedRecordings):
        names = np.array([group for group, _ in source.train])
        recordings = [recording for _, recording in source.train]
        if databases is not None:
            setups = [
                (names == db.group, db.graph, {**options, "sensor_map": db.sensor_map})
                for db in databases
            ]
        else:
            setups = [(np.ones(len(names), dtype=bool), graph, options)]
        data = _collect_pairs(
            config,
            [(np.flatnonzero(mine), own, opts) for mine, own, opts in setups],
            recordings,
            spec,
            run,
            frames=config.timesteps,
            started=time.perf_counter(),
            seconds=seconds,
            say=say,
        )
        unit = names[data.episodes]
        # Cross-validation over the recordings' own groups (subjects: each left out whole).
        sampler, history, groups = _fit_linear_groups(spec, data, unit, seconds, say, None)
        setup_of = {int(e): setup for setup in setups for e in np.flatnonzero(setup[0])}
    else:
        data, clip_of_episode, recordings = _imitation_pairs(
            config, graph, source, scenarios, options, spec, run, seconds, say
        )
        # Whole clips per group (a clip and its mirror image together), so that
        # cross-validation scores each setting on motions its fit did not see.
        group_of_clip = np.array([c.name.removesuffix("~mirror") for c in source])
        unit = group_of_clip[clip_of_episode[data.episodes]]
        sampler, history, groups = _fit_linear_groups(spec, data, unit, seconds, say, LINEAR_GROUPS)
        setup_of = {int(e): (None, graph, options) for e in np.unique(data.episodes)}
    if config.correction:
        # The correction's groups are the sampler's, its recordings reconstructed by the
        # sampler with the graph and options their data were collected with.
        t0 = time.perf_counter()
        first = np.unique(data.episodes, return_index=True)
        episode_group = dict(zip(first[0].tolist(), groups[first[1]].tolist(), strict=True))
        optimizer = LearnedSampler(sampler, samples=1, correct_output=False)
        sources = []
        for chosen in np.unique(groups).tolist():
            episodes = [e for e, g in episode_group.items() if g == chosen]
            _, own, opts = setup_of[episodes[0]]  # a group's episodes share their setup
            sources.append(
                CorrectionSource(own, opts, [recordings[e] for e in episodes], optimizer)
            )
        correction, report = learn_correction(sources, progress=config.progress, log=say)
        sampler.with_correction(correction, report)
        seconds["correction"] = time.perf_counter() - t0
        history[0]["correction"] = report
    return sampler, history


def _check_linear_units(units: Sequence[str]) -> None:
    """Refuse fewer than 2 distinct training clips or groups (the linear fit cross-validates
    its settings over them; a clip's mirror image is the same unit)."""
    distinct = sorted(set(units))
    if len(distinct) < 2:
        raise ValueError(
            "kind 'linear': cross-validation needs at least 2 training clips or groups, got "
            f"{len(distinct)} ({', '.join(distinct) or 'none'}) once the held-out share "
            "(--val-share) is set apart; give more --clips (or --recordings groups), or "
            "--val-clips"
        )


def _fit_linear_groups(
    spec: SamplerSpec,
    data: ImitationData,
    unit: np.ndarray,
    seconds: dict[str, float],
    say: Callable[[str], None],
    most: int | None,
) -> tuple[LinearPoseSampler, list[dict[str, Any]], np.ndarray]:
    """:func:`fit_linear` on ``data``, cross-validated over groups of whole units (``unit``:
    each frame's clip or recording group, a label): one per unit, or at most ``most``, the
    units dealt in sorted order; also each frame's group."""
    units, index = np.unique(unit, return_inverse=True)
    _check_linear_units(units.tolist())
    group = index % min(most or len(units), len(units))
    groups = [
        (data.observations[take], data.actions[take], data.episodes[take])
        for take in (group == g for g in np.unique(group))
    ]
    t0 = time.perf_counter()
    sampler, report = fit_linear(spec, groups)
    seconds["train"] = time.perf_counter() - t0
    say(f"{describe_fit(report)} ({seconds['train']:.1f} s)")
    return sampler, [{"linear": report}], group


def _train_supervised(
    config: TrainConfig,
    graph: Any,
    train_clips: Sequence[Any],
    scenarios: Sequence[str],
    options: dict[str, Any],
    training_info: dict[str, Any],
    evaluate: Callable[..., dict[str, Any]],
    checkpoints: Path,
    run: RunCheckpoints,
    seconds: dict[str, float],
    say: Callable[[str], None],
) -> tuple[GaussianSampler, list[dict[str, Any]]]:

    spec = _imitation_spec(config, "supervised", "mlp", config.features, epochs=config.epochs)
    data, _, _ = _imitation_pairs(
        config, graph, train_clips, scenarios, options, spec, run, seconds, say
    )
    # Validation pairs: a tenth of the episodes, by whole episodes.
    episode_ids = np.unique(data.episodes)
    rng = np.random.default_rng(config.seed + 1)
    held = rng.permutation(episode_ids)[: max(1, len(episode_ids) // 10)]
    is_val = np.isin(data.episodes, held) if len(episode_ids) > 1 else np.zeros(len(data), bool)
    train = ~is_val
    train_observations = data.observations[train]
    # Features and anchors of the training pairs, computed once (fit_supervised reuses them).
    transformed = spec.feature_map().transform(train_observations)
    features = transformed[0]
    mean = features.mean(axis=0)
    scale = np.maximum(features.std(axis=0), 1e-3)
    sampler = SupervisedSampler.create(spec, mean, scale, seed=config.seed)
    eval_every = config.eval_every or max(config.epochs // 5, 1)
    fit_keys = ("batch_size", "learning_rate", "weight_decay", "loss", "weighting")
    fit_args = {k: config.hyperparameters[k] for k in fit_keys if k in config.hyperparameters}
    tensorboard = _tensorboard_writer(config.tensorboard, say)

    def on_epoch(record: dict[str, Any]) -> None:
        epoch = int(record["epoch"])
        if tensorboard is not None:
            for key in ("train_loss", "val_loss"):
                if key in record:
                    tensorboard.add_scalar(f"supervised/{key}", record[key], epoch)
        if epoch % eval_every == 0 or epoch == config.epochs:
            table = evaluate(sampler)["mean"]
            record.update({f"eval_{k}": v for k, v in table.items()})
            path = sampler.save(checkpoints / f"epoch-{epoch:04d}")
            say(
                f"epoch {epoch}: train loss {record['train_loss']:.3f}, validation loss "
                f"{record.get('val_loss', float('nan')):.3f}, MSE "
                f"{record.get('val_mse', float('nan')):.4f}; held-out mean action: energy "
                f"{table['mean_energy']:.4f}, error {table['mean_error']:.4f} m "
                f"(checkpoint {path.name})"
            )
            if tensorboard is not None:
                tensorboard.add_scalar("eval/mean_energy", table["mean_energy"], epoch)
                tensorboard.add_scalar("eval/mean_error", table["mean_error"], epoch)

    fit = run.load_fit()
    if fit is not None:
        say(f"{checkpoints}: going on from epoch {fit.epoch}")
    t0 = time.perf_counter()
    try:
        history = fit_supervised(
            sampler,
            train_observations,
            data.actions[train],
            data.masks[train],
            epochs=config.epochs,
            seed=config.seed,
            validation=(data.observations[is_val], data.actions[is_val], data.masks[is_val])
            if is_val.any()
            else None,
            on_epoch=on_epoch,
            progress=config.progress,
            transformed=transformed,
            state=fit,
            on_state=run.save_fit,
            **fit_args,
        )
    finally:
        if tensorboard is not None:
            tensorboard.close()
    seconds["train"] = time.perf_counter() - t0
    best = [r["epoch"] for r in history if r.get("best")]
    if best:
        say(
            f"kept the weights of epoch {best[0]} (lowest validation MSE); spread x "
            f"{history[-1].get('std_scale', 1.0):.2f} (calibrated on the validation pairs)"
        )
    training_info["frames"] = len(data)
    training_info["target"] = config.target
    return sampler, history


def _tensorboard_available() -> bool:

    return importlib.util.find_spec("tensorboard") is not None


def _tensorboard_dir(folder: str | None, say: Callable[[str], None]) -> str | None:
    if folder is None:
        return None
    if not _tensorboard_available():
        say("train-sampler: tensorboard is not installed; no TensorBoard logs are written")
        return None
    return folder


def _tensorboard_writer(folder: str | None, say: Callable[[str], None]) -> Any:
    if _tensorboard_dir(folder, say) is None:
        return None
    from torch.utils.tensorboard import SummaryWriter

    return SummaryWriter(log_dir=folder)


def _versions(kind: str) -> dict[str, str]:

    names = ["fpg-gym", "numpy", "torch"] + (
        ["stable-baselines3", "gymnasium"] if kind == "rl" else []
    )
    out = {}
    for name in names:
        try:
            out[name] = md.version(name)
        except md.PackageNotFoundError:
            out[name] = "unknown"
    return out


def config_dict(config: TrainConfig) -> dict[str, Any]:
    """``config`` as plain data (for JSON summaries)."""
    data = asdict(config)
    data["total_timesteps"] = config.total_timesteps
    return data

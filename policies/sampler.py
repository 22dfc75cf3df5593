"""The common interface of learned candidate samplers, their files, and loading by path.

A *sampler* maps the observation of a frame (:mod:`fpg_gym.env_observation`) to a Gaussian over
the frame's whitened latent space, in the env's action units: a mean and a standard deviation
per axis (``(L,)`` each, ``L`` = the env's ``latent_dim``). An action ``a`` selects the latent
point ``z = action_scale * a`` (``"absolute"`` action mode, the samplers' default) or
``z = x0 + action_scale * a`` (``"delta"``). Two kinds share the interface
(:class:`GaussianSampler`):

* ``"supervised"`` (:mod:`policies.supervised`): a torch MLP trained to imitate the search
  optimum (or the ground truth) with a Gaussian likelihood;
* ``"rl"`` (:mod:`policies.rl`): a stable-baselines3 PPO or SAC policy trained on
  ``fpg_gym/KinectPose-v0`` with the energy reward.

A sampler acts in the env loop (``predict(obs, deterministic=True)``, so
:func:`fpg_gym.episodes.run_episode` runs it) and outside it: :meth:`GaussianSampler.observe`
builds a :class:`~fpg_gym.reconstruct.SearchProblem`'s observation with the same
:meth:`~fpg_gym.env_observation.ObservationLayout.build` the env uses, which is what the
optimiser adapter ``learned:PATH`` (:mod:`policies.learned_optimizers`) does.

Features
--------
A model does not read the whole observation vector but the *features* of :class:`FeatureMap`:
chosen fields of the layout, concatenated, with two ``context`` entries set to zero because a
search problem alone does not know them (:data:`MASKED_CONTEXT`: ``no_body``, which the
reconstructor keeps private, and ``progress``, ``t / T``, which needs the episode's length).
The env's observation and the problem's observation then give the model the same input.

Anchor
------
The Gaussian is centred on an *anchor* computed from the observation alone, and a model learns
only the offset from it and the spread. The default anchor (:func:`quadratic_anchor`) is the
closed-form minimiser of the energy's quadratic terms (control and motion, with a ridge for the
style term): one small linear solve per frame. Alone (one evaluation) it already reaches a
lower energy than the papers' 2,000-evaluation local search on the held-out episodes (see the
README); :class:`AnchorSampler` is that baseline. Absolute action coordinates are the default
because the observation clips coordinates relative to a far-out ``x0`` (about 10 % of the
embedded frames), which a delta-mode anchor would inherit.

Files
-----
``MODEL.json`` describes every model (:class:`SamplerSpec`: kind, observation layout and size,
features, action mode and scale, hyper-parameters, training summary). The weights lie beside it:
``MODEL.pt`` for both kinds: the network's ``state_dict``, tensors only, saved with
``torch.save`` and loaded with ``torch.load(..., weights_only=True)``
(:func:`load_weights_file`); the network is rebuilt from the JSON. A model file is data that
users share: loading one never runs code from it. Anything else is refused with a
:class:`~fpg_gym.core.errors.DataFormatError`, stable-baselines3's ``.zip`` format (whose entries
are unpickled on load, which earlier versions of fpg-gym wrote for RL samplers) included.
:func:`policies.loading.load_sampler` takes ``MODEL``, ``MODEL.json`` or ``MODEL.pt``.

torch and stable-baselines3 are the optional extra ``fpg-gym[learn]``: this module imports
neither; :func:`import_learn` raises :class:`~optimizers.MissingDependency` naming the extra.
"""

from __future__ import annotations

import json
import os
import warnings
from collections.abc import Mapping, Sequence
from dataclasses import asdict, dataclass, field
from pathlib import Path
from typing import Any

import gymnasium as gym
import numpy as np

from fpg_gym.core.errors import DataFormatError, import_optional
from fpg_gym.core.jsonable import jsonable
from fpg_gym.core.outputs import write_text
from fpg_gym.core.validation import check_number
from fpg_gym.env_observation import CONTEXT_NAMES, LATENT_LIMIT, ObservationLayout
from fpg_gym.io.files import read_json
from fpg_gym.io.npz import check_zip
from fpg_gym.reconstruct.closed_form import DEFAULT_STYLE, quadratic_minimiser
from fpg_gym.reconstruct.energy import EnergyWeights
from optimizers import MissingDependency

__all__ = [
    "ANCHORS",
    "DEFAULT_FEATURES",
    "FEATURE_SETS",
    "FORMAT",
    "INSTALL_HINT",
    "KINDS",
    "LATENT_FEATURES",
    "MASKED_CONTEXT",
    "PAPER_WEIGHTS",
    "AnchorSampler",
    "FeatureMap",
    "GaussianSampler",
    "SamplerSpec",
    "import_learn",
    "model_paths",
    "problem_observation",
    "quadratic_anchor",
]

#: ``format`` of a sampler's JSON file.
FORMAT = "fpg-gym-sampler"
#: Version of the JSON format (2: the RL sampler's weights are a tensor file, no longer SB3's
#: ``.zip``; version 1 supervised files are read as before).
FORMAT_VERSION = 2
#: Suffix of every weights file (a torch ``state_dict`` of tensors).
WEIGHTS_SUFFIX = ".pt"
#: Bounds on what a JSON may ask to build (a hostile file must not exhaust memory).
MAX_LAYER_WIDTH = 8192
#: Largest magnitude of a model's number (weights, biases, scales, settings): a trained model's
#: values are far smaller; 1e300 or a value beyond float32 is a corrupt or forged file.
MAX_MODEL_VALUE = 1e6
MAX_LAYERS = 16
MAX_LATENT_DIM = 1024
MAX_CANDIDATES = 4096
#: Sampler kinds.
KINDS: tuple[str, ...] = ("supervised", "rl", "linear")
#: What to install for learned samplers.
INSTALL_HINT = "pip install 'fpg-gym[learn]'"
#: ``context`` entries a SearchProblem cannot give: zeroed in every model input.
MASKED_CONTEXT: tuple[str, ...] = ("no_body", "progress")
#: Observation fields a model reads by default: all of them.
DEFAULT_FEATURES: tuple[str, ...] = (
    "kinect",
    "reliability",
    "reliability_terms",
    "prediction",
    "previous",
    "bone_lengths",
    "latent_mean",
    "latent_basis",
    "latent_std",
    "latent_mask",
    "x0",
    "z_kinect",
    "z_prediction",
    "z_candidates",
    "candidate_scores",
    "candidate_mask",
    "context",
)

#: A smaller feature set: everything in latent (action) coordinates, the reliabilities and the
#: context, without the poses and the basis (1,044 of the 2,304 values at the defaults).
LATENT_FEATURES: tuple[str, ...] = (
    "reliability",
    "reliability_terms",
    "latent_std",
    "latent_mask",
    "x0",
    "z_kinect",
    "z_prediction",
    "z_candidates",
    "candidate_scores",
    "candidate_mask",
    "context",
)
#: Named feature sets (``fpg-gym train-sampler --features``).
FEATURE_SETS: dict[str, tuple[str, ...]] = {"all": DEFAULT_FEATURES, "latent": LATENT_FEATURES}


def import_learn(module: str) -> Any:
    """Import ``module`` (``"torch"``, ``"stable_baselines3"``...) of the ``learn`` extra.

    Raises
    ------
    optimizers.MissingDependency
        When it is not installed; the message names ``pip install 'fpg-gym[learn]'``.
    """
    top = module.split(".")[0]
    return import_optional(
        module,
        MissingDependency(
            f"learned samplers need torch and stable-baselines3 ({top} is not installed): "
            f"{INSTALL_HINT}"
        ),
    )


# --------------------------------------------------------------------------- features


#: Anchors a sampler's Gaussian may be centred on (see :class:`FeatureMap`).
ANCHORS: tuple[str, ...] = ("none", "quadratic")
#: The papers' energy weights (Shum Eq. 10): control, style, kinematic, motion.
PAPER_WEIGHTS: tuple[float, float, float, float] = EnergyWeights().paper_terms()


def quadratic_anchor(
    parts: Mapping[str, np.ndarray],
    *,
    action_scale: float,
    delta: bool,
    energy_weights: Sequence[float] = PAPER_WEIGHTS,
    style: float = DEFAULT_STYLE,
) -> np.ndarray:
    """:func:`fpg_gym.reconstruct.closed_form.quadratic_minimiser` from observation parts, as
    actions: the closed-form minimiser of the energy's quadratic terms (``Ec``, ``Em``, a ridge
    standing in for ``Es``) in each frame's latent space, one batched ``(L, L)`` solve.

    Parameters
    ----------
    parts : mapping
        :meth:`ObservationLayout.split` of observations ``(n, N)``.
    action_scale : float
    delta : bool
        Actions relative to ``x0`` (``"delta"``) or absolute.
    energy_weights : 4 floats
        ``w_c, w_s, w_k, w_m`` (the env's).
    style : float
        Ridge weight as a multiple of ``w_s / J`` (2).

    Returns
    -------
    ndarray, shape (n, L), float64
        The actions that select the minimiser (zero on unused axes), clipped to the
        observation's latent bounds.
    """

    n = parts["kinect"].shape[0]
    mask = parts["latent_mask"] > 0.5
    z = quadratic_minimiser(
        parts["kinect"].reshape(n, -1),
        parts["reliability"],
        parts["latent_mean"].reshape(n, -1),
        parts["latent_basis"],
        parts["latent_std"],
        prediction=parts["prediction"].reshape(n, -1),
        has_prediction=parts["context"][:, CONTEXT_NAMES.index("has_prediction")] > 0.5,
        mask=mask,
        weights=energy_weights,
        style=style,
    )
    action = z / float(action_scale)
    if delta:
        action = action - parts["x0"].astype(np.float64)
    return np.where(mask, np.clip(action, -LATENT_LIMIT, LATENT_LIMIT), 0.0)


class FeatureMap:
    """The model input of an observation, and the anchor its Gaussian is centred on.

    Features: the chosen fields of the observation, with :data:`MASKED_CONTEXT` zeroed, then
    (with an anchor) the anchor's ``L`` action coordinates. The anchor (``"quadratic"``:
    :func:`quadratic_anchor`; ``"none"``: zero) is computed from the observation alone, so it
    is the same in the env loop and in the optimiser adapter; a model outputs its Gaussian's
    mean *relative to the anchor*.

    Parameters
    ----------
    layout : ObservationLayout
        The env's observation layout.
    fields : sequence of str
        Field names of ``layout`` (in this order), default :data:`DEFAULT_FEATURES`.
    anchor : {"none", "quadratic"}
    action_scale : float
    delta : bool
        The env's action mode is ``"delta"``.
    energy_weights : 4 floats
        The env's energy weights (for the anchor).
    anchor_style : float
        ``style`` of :func:`quadratic_anchor`.

    Attributes
    ----------
    indices : ndarray of int
        Positions of the field features in the observation vector.
    size : int
        Number of features.
    low, high : ndarray, shape (size,)
        Bounds of the features.
    """

    def __init__(
        self,
        layout: ObservationLayout,
        fields: Sequence[str] = DEFAULT_FEATURES,
        *,
        anchor: str = "none",
        action_scale: float = 3.0,
        delta: bool = True,
        energy_weights: Sequence[float] = PAPER_WEIGHTS,
        anchor_style: float = DEFAULT_STYLE,
    ) -> None:

        unknown = [f for f in fields if f not in layout.slices]
        if unknown or not fields:
            raise ValueError(
                f"features: unknown observation field(s) {unknown}; expected some of "
                f"{', '.join(layout.slices)}"
            )
        if anchor not in ANCHORS:
            raise ValueError(f"anchor: expected one of {ANCHORS}, got {anchor!r}")
        self.layout = layout
        self.fields = tuple(fields)
        self.anchor_kind = anchor
        self.action_scale = float(action_scale)
        self.delta = bool(delta)
        self.energy_weights = tuple(float(w) for w in energy_weights)
        self.anchor_style = float(anchor_style)
        parts = [np.arange(layout.slices[f].start, layout.slices[f].stop) for f in self.fields]
        self.indices = np.concatenate(parts)
        context = layout.slices["context"]
        masked = [context.start + CONTEXT_NAMES.index(name) for name in MASKED_CONTEXT]
        self._masked = np.flatnonzero(np.isin(self.indices, masked))
        extra = layout.latent_dim if anchor != "none" else 0
        self.size = len(self.indices) + extra
        limit = np.full(extra, LATENT_LIMIT, np.float32)
        self.low = np.concatenate([layout.low[self.indices], -limit])
        self.high = np.concatenate([layout.high[self.indices], limit])
        self.low[self._masked] = 0.0
        self.high[self._masked] = 0.0

    def _check(self, observation: np.ndarray) -> np.ndarray:
        obs = np.asarray(observation, dtype=np.float32)
        if obs.ndim == 0 or obs.shape[-1] != self.layout.size:
            raise ValueError(
                f"observation: expected shape (..., {self.layout.size}) (the layout this model "
                f"was trained on: latent_dim={self.layout.latent_dim}, "
                f"k={self.layout.candidates}), got {np.shape(observation)}"
            )
        return obs

    def transform(self, observation: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """Features ``(..., size)`` float32 and anchor actions ``(..., L)`` float64 of
        observations ``(..., layout.size)``.

        Raises
        ------
        ValueError
            If the observation's last axis is not the layout's size (a model trained on
            another observation layout).
        """
        obs = self._check(observation)
        batch = obs.shape[:-1]
        flat = obs.reshape(-1, obs.shape[-1])
        fields = flat[:, self.indices]
        fields[:, self._masked] = 0.0
        if self.anchor_kind == "none":
            anchor = np.zeros((len(flat), self.layout.latent_dim))
            features = fields
        else:
            anchor = quadratic_anchor(
                self.layout.split(flat),
                action_scale=self.action_scale,
                delta=self.delta,
                energy_weights=self.energy_weights,
                style=self.anchor_style,
            )
            features = np.concatenate([fields, anchor.astype(np.float32)], axis=1)
        return (
            features.reshape(*batch, self.size),
            anchor.reshape(*batch, self.layout.latent_dim),
        )

    def __call__(self, observation: np.ndarray) -> np.ndarray:
        """Features ``(..., size)`` float32 of observations ``(..., layout.size)``."""
        return self.transform(observation)[0]

    def split(self, features: np.ndarray) -> dict[str, np.ndarray]:
        """The named parts ``(n, size_of_field)`` float64 of feature rows ``(n, size)``, the
        inverse of :meth:`transform`'s concatenation: each field flat, and the anchor actions
        ``(n, L)`` under ``"anchor"`` (zero without an anchor)."""
        rows = np.asarray(features, dtype=np.float64)
        parts: dict[str, np.ndarray] = {}
        start = 0
        for name in self.fields:
            size = self.layout.slices[name].stop - self.layout.slices[name].start
            parts[name] = rows[:, start : start + size]
            start += size
        dim = self.layout.latent_dim
        parts["anchor"] = (
            rows[:, start : start + dim] if start < rows.shape[1] else (np.zeros((len(rows), dim)))
        )
        return parts

    def wrap(self, env: Any) -> SamplerFeatures:
        """``env`` seen through this map (a Gymnasium wrapper): observations become features
        and an action ``a`` becomes ``anchor + a`` (the env should not clip actions then)."""
        return SamplerFeatures(env, self)


class SamplerFeatures(gym.Wrapper):
    """An env seen through a :class:`FeatureMap`: observations replaced by the sampler's
    features, actions taken relative to its anchor (:meth:`FeatureMap.wrap`)."""

    def __init__(self, env: Any, feature_map: FeatureMap) -> None:
        super().__init__(env)
        self.feature_map = feature_map
        self.observation_space = gym.spaces.Box(feature_map.low, feature_map.high, dtype=np.float32)
        self._anchor = np.zeros(feature_map.layout.latent_dim)

    def _features(self, observation: Any) -> np.ndarray:
        features, self._anchor = self.feature_map.transform(observation)
        return np.asarray(features, dtype=np.float32)

    def reset(self, **kwargs: Any) -> tuple[np.ndarray, dict[str, Any]]:
        """Reset the env; the first observation as features."""
        observation, info = self.env.reset(**kwargs)
        return self._features(observation), info

    def step(self, action: Any) -> tuple[np.ndarray, Any, bool, bool, dict[str, Any]]:
        """Step with ``anchor + action``; the next observation as features."""
        full = self._anchor + np.asarray(action, dtype=np.float64)
        observation, reward, terminated, truncated, info = self.env.step(full)
        return self._features(observation), reward, terminated, truncated, info


def problem_observation(
    problem: Any,
    layout: ObservationLayout,
    *,
    action_scale: float,
    delta: bool = True,
    frame_dt: float = 1.0 / 30.0,
) -> np.ndarray:
    """The env observation of a :class:`~fpg_gym.reconstruct.SearchProblem` ``(layout.size,)``.

    The env's own builder (:meth:`ObservationLayout.build`) with the two context entries a
    problem cannot give (:data:`MASKED_CONTEXT`) left at zero; :class:`FeatureMap` zeroes them
    in the env's observations too.
    """
    return layout.build(
        problem,
        action_scale=action_scale,
        delta=delta,
        no_body=False,
        progress=0.0,
        frame_dt=frame_dt,
    )


# --------------------------------------------------------------------------- files


@dataclass
class SamplerSpec:
    """The JSON description of a sampler model (``MODEL.json``).

    Attributes
    ----------
    kind : {"supervised", "rl"}
    algo : str
        ``"mlp"`` (supervised), ``"ppo"`` or ``"sac"`` (rl).
    latent_dim, candidates, observation_size : int
        The env's observation layout the model was trained on (``L``, ``K``, ``N``).
    features : list of str
        Observation fields read (see :class:`FeatureMap`).
    anchor : {"none", "quadratic"}
        What the Gaussian's mean is relative to (:class:`FeatureMap`).
    anchor_style : float
        Ridge of the quadratic anchor (:func:`quadratic_anchor`).
    energy_weights : list of 4 floats
        The env's energy weights (control, style, kinematic, motion).
    action_mode : {"delta", "absolute"}
    action_scale : float
    frame_dt : float
        Nominal frame interval of the observation's ``dt_frames``.
    hyperparameters : dict
        Everything needed to rebuild the model (network sizes, ...).
    training : dict
        What it was trained on, for how long, and its evaluation summary.
    weights : str
        File name of the weights, beside the JSON.
    """

    kind: str
    algo: str
    latent_dim: int
    candidates: int
    observation_size: int
    features: list[str] = field(default_factory=lambda: list(DEFAULT_FEATURES))
    anchor: str = "quadratic"
    anchor_style: float = DEFAULT_STYLE
    energy_weights: list[float] = field(default_factory=lambda: list(PAPER_WEIGHTS))
    action_mode: str = "delta"
    action_scale: float = 3.0
    frame_dt: float = 1.0 / 30.0
    hyperparameters: dict[str, Any] = field(default_factory=dict)
    training: dict[str, Any] = field(default_factory=dict)
    weights: str = ""

    def __post_init__(self) -> None:
        if self.kind not in KINDS:
            raise ValueError(f"kind: expected one of {KINDS}, got {self.kind!r}")
        for name, bound in (("latent_dim", MAX_LATENT_DIM), ("candidates", MAX_CANDIDATES)):
            value = getattr(self, name)
            if isinstance(value, bool) or not isinstance(value, int) or not 1 <= value <= bound:
                raise ValueError(f"{name}: expected an integer in 1..{bound}, got {value!r}")
        if self.action_mode not in ("delta", "absolute"):
            raise ValueError(f"action_mode: expected 'delta' or 'absolute', got {self.action_mode}")
        if self.anchor not in ANCHORS:
            raise ValueError(f"anchor: expected one of {ANCHORS}, got {self.anchor!r}")
        if not isinstance(self.energy_weights, list | tuple) or len(self.energy_weights) != 4:
            raise ValueError(f"energy_weights: expected 4 weights, got {self.energy_weights}")
        for index, weight in enumerate(self.energy_weights):
            check_number(weight, f"energy_weights[{index}]", low=0, high=MAX_MODEL_VALUE)
        check_number(self.action_scale, "action_scale", low=0, high=1e3, low_open=True)
        check_number(self.anchor_style, "anchor_style", low=0, high=MAX_MODEL_VALUE)
        check_number(self.frame_dt, "frame_dt", low=1e-3, high=1.0)
        if not isinstance(self.features, list | tuple) or not all(
            isinstance(f, str) for f in self.features
        ):
            raise ValueError(f"features: expected a list of field names, got {self.features!r}")
        for name in ("hyperparameters", "training"):
            if not isinstance(getattr(self, name), dict):
                raise ValueError(f"{name}: expected a JSON object, got {getattr(self, name)!r}")
        size = ObservationLayout.of(self.latent_dim, self.candidates).size
        if size != self.observation_size:
            raise ValueError(
                f"observation_size {self.observation_size} does not match latent_dim "
                f"{self.latent_dim} and candidates {self.candidates} (expected {size})"
            )

    @classmethod
    def for_layout(
        cls, kind: str, algo: str, latent_dim: int = 20, candidates: int = 30, **kwargs: Any
    ) -> SamplerSpec:
        """The spec of a model for the env's observation layout of ``latent_dim`` axes and
        ``candidates`` candidates (its ``observation_size`` follows from them)."""
        return cls(
            kind=kind,
            algo=algo,
            latent_dim=latent_dim,
            candidates=candidates,
            observation_size=ObservationLayout.of(latent_dim, candidates).size,
            **kwargs,
        )

    @classmethod
    def for_env(cls, env: Any, kind: str, algo: str, **kwargs: Any) -> SamplerSpec:
        """The spec of a model for ``env`` (a :class:`~fpg_gym.env.KinectPoseEnv`, wrapped or
        not)."""
        base = env.unwrapped
        return cls(
            kind=kind,
            algo=algo,
            latent_dim=int(base.latent_dim),
            candidates=int(base.candidates),
            observation_size=int(base.layout.size),
            energy_weights=list(base.weights.paper_terms()),
            action_mode=str(base.action_mode),
            action_scale=float(base.action_scale),
            frame_dt=float(base.reconstructor.config.frame_dt),
            **kwargs,
        )

    @property
    def layout(self) -> ObservationLayout:
        """The observation layout the model was trained on."""
        return ObservationLayout.of(self.latent_dim, self.candidates)

    def feature_map(self) -> FeatureMap:
        """The model's :class:`FeatureMap`."""
        return FeatureMap(
            self.layout,
            self.features,
            anchor=self.anchor,
            action_scale=self.action_scale,
            delta=self.action_mode == "delta",
            energy_weights=self.energy_weights,
            anchor_style=self.anchor_style,
        )

    def check_env(self, env: Any) -> None:
        """Raise ``ValueError`` unless ``env``'s observation and actions are this model's (and
        warn when an anchored sampler meets an env that clips actions)."""
        base = env.unwrapped
        size = int(base.layout.size)
        if size != self.observation_size:
            raise ValueError(
                f"this sampler was trained on observations of size {self.observation_size} "
                f"(latent_dim={self.latent_dim}, k={self.candidates}); the env's have size "
                f"{size} (latent_dim={base.latent_dim}, k={base.candidates})"
            )
        if base.action_mode != self.action_mode or float(base.action_scale) != self.action_scale:
            raise ValueError(
                f"this sampler acts in action_mode={self.action_mode!r}, action_scale="
                f"{self.action_scale}; the env has {base.action_mode!r}, {base.action_scale}"
            )
        if self.anchor != "none" and getattr(base, "clip_actions", False):
            warnings.warn(
                "this sampler's actions are offsets from its anchor and often lie beyond the "
                "action box, which this env clips: make it with clip_actions=False to act on "
                "them exactly",
                UserWarning,
                stacklevel=2,
            )

    def to_json(self) -> dict[str, Any]:
        """The JSON object (with ``format``, ``version`` and the layout's field table)."""
        data = asdict(self)
        data["observation_fields"] = [
            {"name": row["name"], "start": row["start"], "stop": row["stop"]}
            for row in self.layout.table()
        ]
        return {"format": FORMAT, "version": FORMAT_VERSION, **data}

    def save(self, path: str | os.PathLike[str]) -> Path:
        """Write the JSON to ``path``."""
        return write_text(path, json.dumps(jsonable(self.to_json()), indent=2) + "\n")

    @classmethod
    def load(cls, path: str | os.PathLike[str]) -> SamplerSpec:
        """Read a sampler's JSON.

        Raises
        ------
        DataFormatError
            Not a sampler file, an unknown version, or values out of range.
        """
        source = Path(path)
        data = read_json(source)
        if not isinstance(data, dict) or data.get("format") != FORMAT:
            raise DataFormatError(
                source, f"not an fpg-gym sampler description (format {FORMAT!r})", field="format"
            )
        version = data.get("version", 0)
        if isinstance(version, bool) or not isinstance(version, int):
            raise DataFormatError(source, f"expected an integer, got {version!r}", field="version")
        if version > FORMAT_VERSION:
            raise DataFormatError(
                source,
                f"sampler format version {version} is newer than this fpg-gym reads "
                f"({FORMAT_VERSION})",
                field="version",
            )
        names = {f.name for f in cls.__dataclass_fields__.values()}
        try:
            spec = cls(**{k: v for k, v in data.items() if k in names})
        except (TypeError, ValueError) as error:
            raise DataFormatError(source, f"bad sampler description ({error})") from None
        if not isinstance(spec.hyperparameters, dict):
            raise DataFormatError(source, "expected a JSON object", field="hyperparameters")
        try:
            spec.feature_map()  # the observation fields it reads, known and fitting the layout
        except (TypeError, ValueError) as error:
            raise DataFormatError(source, str(error), field="features") from None
        return spec


def check_layer_widths(widths: Any, name: str, source: str | os.PathLike[str] = "") -> list[int]:
    """``widths`` as a list of layer widths, checked: at most :data:`MAX_LAYERS` integers in
    1..:data:`MAX_LAYER_WIDTH` (a JSON must not make the loader allocate without bound).

    Raises
    ------
    DataFormatError
        Naming ``source`` and the field ``name``.
    """
    if (
        not isinstance(widths, list | tuple)
        or len(widths) > MAX_LAYERS
        or any(
            isinstance(w, bool) or not isinstance(w, int) or not 1 <= w <= MAX_LAYER_WIDTH
            for w in widths
        )
    ):
        raise DataFormatError(
            source,
            f"expected a list of at most {MAX_LAYERS} layer widths in 1..{MAX_LAYER_WIDTH}, got "
            f"{widths!r}",
            field=name,
        )
    return [int(w) for w in widths]


def load_weights_file(path: str | os.PathLike[str]) -> dict[str, Any]:
    """The ``state_dict`` in a weights file: ``torch.load(..., weights_only=True)``, which
    rebuilds tensors and plain containers only and never runs code from the file.

    Raises
    ------
    DataFormatError
        If the file is not a ``.pt`` tensor file: an SB3 ``.zip`` (pickled entries), a
        pickle of Python objects, or anything that is not a mapping of names to tensors.
    """
    torch = import_learn("torch")
    source = Path(path)
    refuse = (
        "only tensor files are loaded (a torch state_dict saved by fpg-gym train-sampler, "
        "read with weights_only=True)"
    )
    if source.suffix != WEIGHTS_SUFFIX:
        raise DataFormatError(
            source,
            f"{refuse}; a '{source.suffix}' file is refused"
            + (
                " (stable-baselines3 .zip models hold pickled Python objects, which could run "
                "code; retrain the sampler with this fpg-gym: `fpg-gym train-sampler --kind rl`)"
                if source.suffix == ".zip"
                else ""
            ),
        )
    check_zip(source)  # declared sizes within the memory ceiling, before torch inflates it
    try:
        state = torch.load(source, map_location="cpu", weights_only=True)
    except Exception as error:  # the weights-only unpickler's errors vary (UnpicklingError, ...)
        first = str(error).strip().splitlines()[0] if str(error).strip() else type(error).__name__
        raise DataFormatError(source, f"{refuse}; this file is not one ({first[:300]})") from None
    if not isinstance(state, Mapping) or not all(
        isinstance(k, str) and isinstance(v, torch.Tensor) for k, v in state.items()
    ):
        raise DataFormatError(source, f"{refuse}; expected a mapping of names to tensors")
    for name, tensor in state.items():
        if tensor.is_floating_point() or tensor.is_complex():
            check_model_values(source, name, tensor.detach().double().numpy())
    return dict(state)


def check_model_values(source: str | os.PathLike[str], name: str, values: Any) -> None:
    """Refuse a model array holding NaN, inf or a magnitude beyond :data:`MAX_MODEL_VALUE`.

    Raises
    ------
    DataFormatError
        Naming ``source`` and the array ``name``.
    """
    array = np.asarray(values, dtype=np.float64)
    if not np.all(np.isfinite(array)):
        raise DataFormatError(source, "NaN or inf in a model's numbers", field=name)
    largest = float(np.abs(array).max(initial=0.0))
    if largest > MAX_MODEL_VALUE:
        raise DataFormatError(
            source,
            f"a value of {largest:g}: not a trained model's (expected magnitudes up to "
            f"{MAX_MODEL_VALUE:g})",
            field=name,
        )


def load_weights_into(
    module: Any, path: str | os.PathLike[str], defaults: Mapping[str, Any] | None = None
) -> None:
    """Load a weights file (:func:`load_weights_file`) into a torch module, strictly.

    ``defaults`` gives tensors that files written before they existed lack.

    Raises
    ------
    DataFormatError
        If the file is refused, or its tensors do not fit the module built from the JSON.
    """
    state = load_weights_file(path)
    for name, value in (defaults or {}).items():
        state.setdefault(name, value)
    try:
        module.load_state_dict(state, strict=True)
    except (RuntimeError, ValueError) as error:
        raise DataFormatError(
            path, f"the tensors do not fit the network in the JSON ({error})"
        ) from None


def model_paths(path: str | os.PathLike[str]) -> tuple[Path, Path]:
    """``(MODEL.json, stem)`` of a model path given as ``MODEL``, ``MODEL.json``, ``.pt`` or
    ``.zip``."""
    p = Path(path)
    stem = p.with_suffix("") if p.suffix in (".json", ".pt", ".zip") else p
    return stem.with_name(stem.name + ".json"), stem


# --------------------------------------------------------------------------- interface


class GaussianSampler:
    """A learned Gaussian over the latent space, in action units (see the module docstring).

    Subclasses implement :meth:`gaussian_features` (features -> mean relative to the anchor,
    std) and :meth:`save`; :meth:`gaussian` adds the anchor (:class:`FeatureMap`).

    Parameters
    ----------
    spec : SamplerSpec
    seed : int, optional
        Seed of :meth:`predict`'s own generator (``deterministic=False``).
    """

    def __init__(self, spec: SamplerSpec, seed: int | None = 0) -> None:
        self.spec = spec
        self.features = spec.feature_map()
        self.layout = self.features.layout
        self.rng = np.random.default_rng(seed)

    # ---------------------------------------------------------------- to override

    def gaussian_features(self, features: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """Mean (relative to the anchor) and std ``(n, L)`` float64 of feature rows ``(n, F)``."""
        raise NotImplementedError

    def save(self, path: str | os.PathLike[str]) -> Path:
        """Write ``MODEL.json`` and the weights; returns the JSON's path."""
        raise NotImplementedError

    # ---------------------------------------------------------------- shared

    @property
    def kind(self) -> str:
        """``"supervised"`` or ``"rl"``."""
        return self.spec.kind

    def distribution(self, observation: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """Mean, std and anchor (action units) of an observation ``(N,)`` -> ``(L,)`` each,
        or of a batch ``(n, N)`` -> ``(n, L)`` each (the anchor is zero without one).

        Raises
        ------
        ValueError
            If the observation does not have the model's size.
        """
        obs = np.asarray(observation, dtype=np.float32)
        single = obs.ndim == 1
        features, anchor = self.features.transform(np.atleast_2d(obs))
        if features.ndim != 2:
            raise ValueError(f"observation: expected (N,) or (n, N), got shape {obs.shape}")
        offset, std = self.gaussian_features(features)
        mean = anchor + offset
        if single:
            return mean[0], std[0], anchor[0]
        return mean, std, anchor

    def gaussian(self, observation: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """Mean and std (action units) of an observation ``(N,)`` -> ``(L,)`` each, or of a
        batch ``(n, N)`` -> ``(n, L)`` each (see :meth:`distribution`)."""
        mean, std, _ = self.distribution(observation)
        return mean, std

    def predict(
        self,
        observation: np.ndarray,
        state: Any = None,
        episode_start: Any = None,
        deterministic: bool = True,
    ) -> tuple[np.ndarray, None]:
        """SB3-style ``(action, None)``: the mean, or a sample from the sampler's own generator
        (``seed`` at construction).

        Not clipped: an anchored Gaussian's mean may lie beyond the action box (the point the
        anchor selects usually does), so make the env with ``clip_actions=False`` to act on it
        exactly, as the RL sampler's training env is.
        """
        mean, std = self.gaussian(observation)
        action = mean if deterministic else mean + std * self.rng.standard_normal(mean.shape)
        return np.asarray(action, dtype=np.float32), None

    def observe(self, problem: Any) -> np.ndarray:
        """The observation ``(N,)`` of a search problem (:func:`problem_observation`).

        Raises
        ------
        ValueError
            If the problem has more latent axes or candidates than the model's layout.
        """
        if problem.dim > self.spec.latent_dim or len(problem.nodes) > self.spec.candidates:
            raise ValueError(
                f"search problem with {problem.dim} latent axes and {len(problem.nodes)} "
                f"candidates does not fit this sampler's observation (latent_dim="
                f"{self.spec.latent_dim}, k={self.spec.candidates}); use the reconstructor "
                "settings the sampler was trained with"
            )
        return problem_observation(
            problem,
            self.layout,
            action_scale=self.spec.action_scale,
            delta=self.spec.action_mode == "delta",
            frame_dt=self.spec.frame_dt,
        )

    def latent_gaussian(self, problem: Any) -> tuple[np.ndarray, np.ndarray, np.ndarray | None]:
        """The model's Gaussian in ``problem``'s whitened latent space: mean and std ``(d,)``,
        and the anchor's point ``(d,)`` (None without an anchor). Actions map to points by
        ``z = x0 + scale * a`` (delta) or ``z = scale * a`` (absolute)."""
        mean, std, anchor = self.distribution(self.observe(problem))
        d = int(problem.dim)
        scale = self.spec.action_scale
        origin = np.asarray(problem.x0, dtype=np.float64) if self.spec.action_mode == "delta" else 0
        point = None if self.spec.anchor == "none" else origin + scale * anchor[:d]
        return origin + scale * mean[:d], scale * std[:d], point

    def __repr__(self) -> str:
        return (
            f"{type(self).__name__}(kind={self.kind!r}, algo={self.spec.algo!r}, "
            f"observation_size={self.spec.observation_size}, features={self.features.size})"
        )


class AnchorSampler(GaussianSampler):
    """The anchor alone: zero offset and a constant spread (a baseline, nothing learned).

    With ``spec.anchor == "quadratic"`` its mean is :func:`quadratic_anchor`'s point, the
    closed-form minimiser of the energy's quadratic terms; it shows how much of a learned
    sampler's result the anchor already gives.

    Parameters
    ----------
    spec : SamplerSpec
    std : float
        Standard deviation on every axis, in action units (0.1).
    """

    def __init__(self, spec: SamplerSpec, std: float = 0.1, seed: int | None = 0) -> None:
        super().__init__(spec, seed)
        self.std = float(std)

    def gaussian_features(self, features: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """Zero offset, constant std."""
        shape = (len(features), self.spec.latent_dim)
        return np.zeros(shape), np.full(shape, self.std)

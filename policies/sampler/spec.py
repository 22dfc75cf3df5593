"""A sampler's JSON description (``MODEL.json``, :class:`SamplerSpec`): its format, the
bounds a file's values must keep, reading and writing it."""

from __future__ import annotations

import json
import os
import warnings
from dataclasses import asdict, dataclass, field
from pathlib import Path
from typing import Any

from fpg_gym.core.errors import DataFormatError
from fpg_gym.core.jsonable import jsonable
from fpg_gym.core.outputs import write_text
from fpg_gym.core.validation import check_number
from fpg_gym.env_observation import ObservationLayout
from fpg_gym.io.files import read_json
from fpg_gym.reconstruct.closed_form import DEFAULT_STYLE
from policies.sampler.features import ANCHORS, DEFAULT_FEATURES, PAPER_WEIGHTS, FeatureMap

__all__ = ["FORMAT", "FORMAT_VERSION", "KINDS", "MAX_MODEL_VALUE", "SamplerSpec"]

#: ``format`` of a sampler's JSON file.
FORMAT = "fpg-gym-sampler"
#: Version of the JSON format (2: the RL sampler's weights are a tensor file, no longer SB3's
#: ``.zip``; version 1 supervised files are read as before).
FORMAT_VERSION = 2
#: Largest magnitude of a model's number (weights, biases, scales, settings): a trained model's
#: values are far smaller; 1e300 or a value beyond float32 is a corrupt or forged file.
MAX_MODEL_VALUE = 1e6
#: Bounds on the observation layout a JSON may ask for (a hostile file must not exhaust memory).
MAX_LATENT_DIM = 1024
MAX_CANDIDATES = 4096
#: Sampler kinds.
KINDS: tuple[str, ...] = ("supervised", "rl", "linear")


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

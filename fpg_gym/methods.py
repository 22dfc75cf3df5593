"""Reconstruction methods by name: the reference filters and the two reconstruction pipelines.

One name picks everything a run of a Kinect stream needs; ``fpg-gym compare --methods`` and
``fpg-gym demo`` take these names, and :func:`run_method` runs one on a recording.

Grammar::

    METHOD  = BASE [":" OPTION] ["+map"] ["+prior"] ["+ragdoll"]

=========  ===================  =============================================================
base       option               method
=========  ===================  =============================================================
``raw``    (none)               the sensor's positions as they are
``holt``   Holt preset          Kinect SDK joint filter (:class:`fpg_gym.filters.HoltFilter`):
                                ``default``, ``smoothed``, ``very-smoothed``, ``sample``,
                                ``none`` (see :data:`fpg_gym.filters.HOLT_PRESETS`)
``kalman`` Kalman preset        constant-velocity Kalman filter per joint
                                (:class:`fpg_gym.filters.KalmanFilter`): ``default``, ``fast``
``one-euro`` One Euro preset    speed-adaptive low-pass filter per joint
                                (:class:`fpg_gym.filters.OneEuroFilter`, Casiez et al. 2012)
``shum``   optimiser name       Shum 2013: brute-force selection (Eq. 9) + an optimiser
``fpg``    optimiser name       FPG 2016: graph selection + an optimiser
=========  ===================  =============================================================

The option of ``shum``/``fpg`` is a registered optimiser (``optimizers.available()``:
``local-search`` — the papers' search, the default —, ``random-search``, ``cma-es``, ``none``,
or a parametrised name such as ``learned:PATH`` / ``learned+search:PATH``, so
``fpg:learned+search:runs/sampler+ragdoll`` is valid: only trailing ``+prior``/``+ragdoll`` are
suffixes); the option of a filter is its preset (the SDK's documented default when omitted).
``+map`` (filters only) first moves the sensor's joints into the definitions the
reconstructions are output in (the runner's sensor map, composed with its output map, or the
calibration map: :func:`fpg_gym.definitions.sensor_to_output_map`): ``raw+map`` is the sensor
through a fitted definition map and ``holt+map`` the same with the SDK's filter, the cheap
baselines a Kinect user with paired data already has. ``+prior`` (``shum``/``fpg`` only, beyond
the papers) adds the latent prior term ``Ep`` with
the weight chosen on a validation split (:meth:`EnergyWeights.with_prior
<fpg_gym.reconstruct.EnergyWeights.with_prior>`). ``+ragdoll``
sends the method's output through the pybullet PD ragdoll
(:class:`fpg_gym.physics.ragdoll.Ragdoll`) as a final filter — for ``shum``/``fpg`` inside the
:class:`~fpg_gym.reconstruct.Reconstructor` (Shum §VII, FPG §7), for a filter on its output
(see :class:`RagdollStage`).

Canonical names (:attr:`Method.name`) spell the optimiser of a reconstruction method and omit a
filter's default preset: ``fpg`` is ``fpg:local-search``, ``holt:default`` is ``holt``.

The baseline of every comparison is :data:`BASELINE` (``fpg:local-search``: graph selection and
the papers' local search, no ragdoll).

Examples
--------
>>> from fpg_gym.methods import parse_method
>>> parse_method("fpg").name
'fpg:local-search'
>>> parse_method("holt:smoothed+ragdoll").ragdoll
True
"""

from __future__ import annotations

import time
from collections.abc import Iterable, Sequence
from dataclasses import dataclass, field, replace
from typing import Any

import numpy as np

from fpg_gym.core import skeleton
from fpg_gym.core.metrics import bones_tracked
from fpg_gym.core.poses import FloorShift, RecordingLike, bone_lengths
from fpg_gym.core.seeding import as_generator
from fpg_gym.definitions import sensor_to_output_map
from fpg_gym.filters import PRESETS, make_filter
from fpg_gym.physics.ragdoll import Ragdoll
from fpg_gym.reconstruct import EnergyWeights, ReconstructionResult, Reconstructor
from fpg_gym.reconstruct.config import RagdollFactory
from fpg_gym.reconstruct.streams import run_streams
from optimizers import make

__all__ = [
    "BASELINE",
    "FILTER_BASES",
    "METHOD_BASES",
    "RECONSTRUCTION_BASES",
    "SELECTOR_OF_BASE",
    "Method",
    "MethodResult",
    "MethodRunner",
    "RagdollStage",
    "expand_methods",
    "parse_method",
    "parse_methods",
    "ragdoll_factory",
]

FILTER_BASES: tuple[str, ...] = ("raw", "holt", "kalman", "one-euro")
RECONSTRUCTION_BASES: tuple[str, ...] = ("shum", "fpg")
METHOD_BASES: tuple[str, ...] = FILTER_BASES + RECONSTRUCTION_BASES
#: Candidate selector of each reconstruction base (``fpg-gym compare --selectors`` uses these).
SELECTOR_OF_BASE: dict[str, str] = {"shum": "brute-force", "fpg": "graph"}
BASE_OF_SELECTOR: dict[str, str] = {v: k for k, v in SELECTOR_OF_BASE.items()}
DEFAULT_OPTIMIZER = "local-search"
RAGDOLL_SUFFIX = "+ragdoll"
PRIOR_SUFFIX = "+prior"
MAP_SUFFIX = "+map"


@dataclass(frozen=True)
class Method:
    """A parsed method name (see the module docstring).

    Attributes
    ----------
    base : str
        One of :data:`METHOD_BASES`.
    option : str
        Filter preset (``""`` for the default) or optimiser name (reconstruction methods).
    ragdoll : bool
        Whether the output goes through the ragdoll.
    prior : bool
        Whether the energy has the latent prior term (``shum``/``fpg`` only).
    mapped : bool
        Whether a filter's input first goes through the sensor -> output definition map.
    """

    base: str
    option: str = ""
    ragdoll: bool = False
    prior: bool = False
    mapped: bool = False

    def __post_init__(self) -> None:
        if self.base not in METHOD_BASES:
            raise ValueError(
                f"method: unknown base {self.base!r}; expected one of {', '.join(METHOD_BASES)}"
            )
        if self.prior and self.base in FILTER_BASES:
            raise ValueError(f"method {self.base}: '+prior' applies to shum and fpg only")
        if self.mapped and self.base not in FILTER_BASES:
            raise ValueError(
                f"method {self.base}: '+map' applies to the filters only (a reconstruction maps "
                "with --sensor-map)"
            )

    @property
    def is_filter(self) -> bool:
        """True for the reference filters (:data:`FILTER_BASES`)."""
        return self.base in FILTER_BASES

    @property
    def selector(self) -> str | None:
        """``"graph"`` (fpg), ``"brute-force"`` (shum) or None (filters)."""
        return SELECTOR_OF_BASE.get(self.base)

    @property
    def optimizer(self) -> str | None:
        """The optimiser of a reconstruction method (None for filters)."""
        if self.is_filter:
            return None
        return self.option or DEFAULT_OPTIMIZER

    @property
    def filter_name(self) -> str | None:
        """The :func:`fpg_gym.filters.make_filter` name (``"holt:smoothed"``) or None."""
        if not self.is_filter:
            return None
        return f"{self.base}:{self.option}" if self.option else self.base

    @property
    def name(self) -> str:
        """Canonical name (optimiser spelled out, default filter preset omitted)."""
        core = self.filter_name if self.is_filter else f"{self.base}:{self.optimizer}"
        mapped = MAP_SUFFIX if self.mapped else ""
        prior = PRIOR_SUFFIX if self.prior else ""
        return f"{core}{mapped}{prior}{RAGDOLL_SUFFIX if self.ragdoll else ''}"

    def with_ragdoll(self, ragdoll: bool) -> Method:
        """The same method with or without the ragdoll."""
        return replace(self, ragdoll=ragdoll)

    def __str__(self) -> str:
        return self.name


def parse_method(text: str) -> Method:
    """Parse ``BASE[:OPTION][+map][+prior][+ragdoll]`` (see the module docstring).

    Filter presets are checked here; optimiser names are checked when the optimiser is made
    (third-party optimisers may register later).

    Raises
    ------
    ValueError
        Empty text, an unknown base, an unknown filter preset or a ``+`` suffix other than
        ``+map``, ``+prior`` and ``+ragdoll``.
    """

    raw = str(text).strip()
    if not raw:
        raise ValueError("method: empty name")
    # An optimiser option may hold '+' and ':' (learned+search:PATH): only trailing '+map',
    # '+prior' and '+ragdoll' are suffixes, and a '+' before the option is an error.
    body, plus, prior, mapped = raw, False, False, False
    while True:
        lowered = body.lower()
        if lowered.endswith(RAGDOLL_SUFFIX) and not plus:
            body, plus = body[: -len(RAGDOLL_SUFFIX)], True
        elif lowered.endswith(PRIOR_SUFFIX) and not prior:
            body, prior = body[: -len(PRIOR_SUFFIX)], True
        elif lowered.endswith(MAP_SUFFIX) and not mapped:
            body, mapped = body[: -len(MAP_SUFFIX)], True
        else:
            break
    head, _, rest = body.partition(":")
    if "+" in head or (head.strip().lower() in FILTER_BASES and "+" in rest):
        suffix = body[body.index("+") + 1 :]
        raise ValueError(
            f"method {raw!r}: the suffixes are '+map', '+prior' and '+ragdoll', got '+{suffix}'"
        )
    base, _, option = body.partition(":")
    base, option = base.strip().lower(), option.strip()
    if base not in METHOD_BASES:
        raise ValueError(
            f"method {raw!r}: unknown base {base!r}; expected one of {', '.join(METHOD_BASES)} "
            "(e.g. raw, holt:smoothed, holt+map, one-euro, shum:local-search, fpg:cma-es+ragdoll)"
        )
    if base in FILTER_BASES:
        option = option.lower()
        if option == "default":
            option = ""
        if option and option not in PRESETS[base]:
            known = ", ".join(PRESETS[base]) or "none"
            raise ValueError(f"method {raw!r}: unknown {base} preset {option!r}; presets: {known}")
    elif option == DEFAULT_OPTIMIZER:
        option = ""
    return Method(base, option, plus, prior, mapped)  # Method rejects misplaced suffixes


def parse_methods(texts: Iterable[str]) -> list[Method]:
    """Parse comma-separated method lists (``["raw,holt", "fpg"]``), keeping order, no repeats."""
    result: list[Method] = []
    seen: set[str] = set()
    for text in texts:
        for item in str(text).split(","):
            if not item.strip():
                continue
            method = parse_method(item)
            if method.name not in seen:
                seen.add(method.name)
                result.append(method)
    return result


def expand_methods(
    methods: Sequence[str] = (),
    optimizers: Sequence[str] = (),
    selectors: Sequence[str] = ("graph",),
    ragdoll: str = "off",
) -> list[Method]:
    """The method list of ``fpg-gym compare``.

    Parameters
    ----------
    methods : sequence of str
        Method names (comma-separated lists allowed).
    optimizers : sequence of str
        Each optimiser adds ``fpg:OPT`` and/or ``shum:OPT`` for the given ``selectors``.
    selectors : sequence of str
        ``"graph"`` (fpg) and/or ``"brute-force"`` (shum), for ``optimizers``.
    ragdoll : {"off", "on", "both"}
        ``"on"`` adds the ragdoll to every method, ``"both"`` runs each with and without it;
        ``"off"`` keeps the names as given (a ``+ragdoll`` suffix still counts).

    Returns
    -------
    list of Method
        In order: the given methods, then optimiser x selector; duplicates dropped.

    Raises
    ------
    ValueError
        Unknown selector or ragdoll mode, or no method at all.
    """
    if ragdoll not in ("off", "on", "both"):
        raise ValueError(f"ragdoll: expected 'off', 'on' or 'both', got {ragdoll!r}")
    names = [item for text in methods for item in str(text).split(",") if item.strip()]
    for selector in selectors:
        if selector not in BASE_OF_SELECTOR:
            raise ValueError(f"selector: expected 'graph' or 'brute-force', got {selector!r}")
    for optimizer in optimizers:
        for opt in str(optimizer).split(","):
            if opt.strip():
                names.extend(f"{BASE_OF_SELECTOR[s]}:{opt.strip()}" for s in selectors)
    parsed = parse_methods(names)
    if ragdoll == "on":
        parsed = [m.with_ragdoll(True) for m in parsed]
    elif ragdoll == "both":
        parsed = [v for m in parsed for v in (m.with_ragdoll(False), m.with_ragdoll(True))]
    unique: dict[str, Method] = {}
    for method in parsed:
        unique.setdefault(method.name, method)
    if not unique:
        raise ValueError("no method to run: give --methods and/or --optimizers")
    return list(unique.values())


# --------------------------------------------------------------------------- running


@dataclass
class MethodResult:
    """The output of one method on one recording.

    Attributes
    ----------
    poses : ndarray, shape (T, 20, 3), float32
        Output poses in the recording's camera space (T may be short of the input's length
        when interrupted).
    ms : ndarray, shape (T,)
        Computation time of each frame (milliseconds), ragdoll included.
    stage_ms : dict of str to ndarray (T,)
        Per-stage times: the reconstructor's stages, or ``filter`` (+ ``ragdoll``).
    evaluations : ndarray (T,) or None
        Energy evaluations per frame (reconstruction methods).
    energy : ndarray (T,) or None
        Energy of the chosen pose per frame (reconstruction methods).
    interrupted : bool
    info : dict
        Extra facts (recoveries, ragdoll divergences, the filter's parameters, ...).
    """

    poses: np.ndarray
    ms: np.ndarray
    stage_ms: dict[str, np.ndarray] = field(default_factory=dict)
    evaluations: np.ndarray | None = None
    energy: np.ndarray | None = None
    interrupted: bool = False
    info: dict[str, Any] = field(default_factory=dict)

    @property
    def num_frames(self) -> int:
        """Frames produced."""
        return len(self.poses)


def ragdoll_factory(ragdoll: bool | RagdollFactory | None) -> RagdollFactory | None:
    """The reconstructor's ``ragdoll=`` from a flag: ``True`` is the pybullet
    :class:`~fpg_gym.physics.ragdoll.Ragdoll` (built from the user's bone lengths), False/None
    no ragdoll, a factory itself (:class:`~fpg_gym.reconstruct.Reconstructor` imports no
    physics: the ragdoll is injected from here).

    Examples
    --------
    >>> Reconstructor(graph, ragdoll=ragdoll_factory(True))               # doctest: +SKIP
    """
    if ragdoll is True:
        return Ragdoll
    return ragdoll if callable(ragdoll) else None


def reference_bone_lengths(positions: np.ndarray, states: np.ndarray) -> np.ndarray:
    """Median length of each bone over the frames where both its joints are tracked, ``(19,)``.

    Bones never tracked at both ends take the median over all frames. This is the calibration
    of :class:`RagdollStage` for the filters; it looks at the whole stream (an offline
    calibration), where the reconstructor estimates the lengths online.
    """
    lengths = bone_lengths(positions)  # (T, 19)
    both = bones_tracked(np.asarray(states) >= skeleton.TRACKED)
    masked = np.where(both, lengths, np.nan)
    seen = both.any(axis=0)
    result = np.median(lengths, axis=0)
    if seen.any():
        result[seen] = np.nanmedian(masked[:, seen], axis=0)
    return np.maximum(result, 0.01)


class RagdollStage:
    """The ragdoll as a final filter on any stream of camera-space poses.

    Mirrors what :class:`~fpg_gym.reconstruct.Reconstructor` does with its ragdoll: camera space
    has no floor, so the poses are shifted down by a floor height estimated as the lowest joint
    seen so far (a running minimum); the body is reset on the first frame and tracks the
    following ones. The ragdoll gets the stream's bone lengths from
    :func:`reference_bone_lengths`; every stream starts from freshly built physics
    (:meth:`Ragdoll.rebuild`), so a stream's output does not depend on the ones before it.
    """

    def __init__(self) -> None:
        self._ragdoll: Any = None

    def run(
        self, poses: np.ndarray, lengths: np.ndarray
    ) -> tuple[np.ndarray, np.ndarray, dict[str, Any]]:
        """Track ``poses`` ``(T, 20, 3)``; return the output poses, ms per frame and info."""

        lengths = np.asarray(lengths, dtype=np.float64)
        if self._ragdoll is None:
            self._ragdoll = Ragdoll(bone_lengths=lengths)
        else:
            self._ragdoll.rebuild(lengths)
        body = self._ragdoll
        poses = np.asarray(poses, dtype=np.float64)
        out = np.empty(poses.shape, dtype=np.float32)
        ms = np.empty(len(poses))
        floor = FloorShift()
        for t, target in enumerate(poses):
            t0 = time.perf_counter()
            world = floor.down(target)
            out[t] = floor.up(body.reset(world) if t == 0 else body.track(world))
            ms[t] = 1000.0 * (time.perf_counter() - t0)
        # Freshly rebuilt for this stream, so its counter holds this stream's divergences.
        info = {"ragdoll_divergences": int(body.info["divergences"])}
        return out, ms, info

    def close(self) -> None:
        """Release the pybullet client."""
        if self._ragdoll is not None:
            self._ragdoll.close()
            self._ragdoll = None


def _method_result(result: ReconstructionResult) -> MethodResult:
    """A reconstruction's poses, per-frame times and counts as a :class:`MethodResult`."""
    arrays = result.arrays()
    names = [str(n) for n in arrays["stage_names"]]
    stages = np.asarray(arrays["ms_stages"], dtype=np.float64).reshape(len(result.poses), -1)
    info: dict[str, Any] = {
        "recoveries": int(np.sum(arrays["recovered"])),
        "bone_settling": dict(result.bones),
    }
    if any(r.ragdoll for r in result.records):
        info["ragdoll_divergences"] = sum(
            int(r.ragdoll.get("new_divergences", 0)) for r in result.records if r.ragdoll
        )
    return MethodResult(
        poses=np.asarray(result.poses, dtype=np.float32),
        ms=np.asarray(arrays["ms_per_frame"], dtype=np.float64),
        stage_ms={name: stages[:, i] for i, name in enumerate(names)},
        evaluations=np.asarray(arrays["evaluations"], dtype=np.float64),
        energy=np.asarray(arrays["energy"], dtype=np.float64),
        interrupted=bool(result.interrupted),
        info=info,
    )


class MethodRunner:
    """Runs methods on recordings against one pose graph.

    Keeps one :class:`~fpg_gym.reconstruct.Reconstructor` per (selector, ragdoll) and one
    ragdoll for the filters, so a worker that runs many episodes builds each once.

    Parameters
    ----------
    graph : FilteredPoseGraph, optional
        Needed by ``shum`` and ``fpg`` (filters run without one).
    budget : int, optional
        Energy evaluations per frame (the reconstructor's ``max_evaluations``; 2,000).
    reconstructor_options : dict, optional
        Further :class:`~fpg_gym.reconstruct.ReconstructorConfig` fields (e.g. ``k``).
    """

    def __init__(
        self,
        graph: Any = None,
        *,
        budget: int | None = 2000,
        reconstructor_options: dict[str, Any] | None = None,
    ) -> None:
        self.graph = graph
        self.budget = budget
        self.options = dict(reconstructor_options or {})
        self._reconstructors: dict[tuple[str, bool, bool], Any] = {}
        # More reconstructors of each kind for run_many (one per stream of a batch).
        self._pools: dict[tuple[str, bool, bool], list[Reconstructor]] = {}
        self._ragdoll_stage: RagdollStage | None = None

    def _reconstructor(self, selector: str, ragdoll: bool, prior: bool = False) -> Any:

        key = (selector, ragdoll, prior)
        if key not in self._reconstructors:
            if self.graph is None:
                raise ValueError("a pose graph is needed for the shum and fpg methods")
            options = dict(self.options)
            if prior:
                options["weights"] = EnergyWeights.with_prior()
            self._reconstructors[key] = Reconstructor(
                self.graph,
                ragdoll=ragdoll_factory(ragdoll),
                selector=selector,
                max_evaluations=self.budget,
                **options,
            )
        return self._reconstructors[key]

    def run(
        self,
        method: Method | str,
        recording: RecordingLike,
        seed: int | np.random.Generator = 0,
        *,
        stop_on_interrupt: bool = False,
    ) -> MethodResult:
        """Run ``method`` on ``recording`` (``positions``, ``states``, ``timestamps``).

        ``seed`` drives the optimiser (reconstruction methods); filters are deterministic.
        """
        spec = parse_method(method) if isinstance(method, str) else method
        if spec.is_filter:
            return self._run_filter(spec, recording)
        return self._run_reconstruction(spec, recording, seed, stop_on_interrupt)

    def _run_filter(self, spec: Method, recording: RecordingLike) -> MethodResult:

        assert spec.filter_name is not None
        flt = make_filter(spec.filter_name)
        positions = np.asarray(recording.positions)
        if spec.mapped:
            mapping = sensor_to_output_map(self.options)
            if mapping is None:
                raise ValueError(
                    f"method {spec.name}: no definition map to apply; give a sensor map "
                    "(--sensor-map) or a calibration map (--calibration-map)"
                )
            positions = mapping.apply(positions).astype(np.float32)
        states = np.asarray(recording.states)
        stamps = getattr(recording, "timestamps", None)
        times = np.arange(len(positions)) / 30.0 if stamps is None else np.asarray(stamps)
        out = np.empty(positions.shape, dtype=np.float32)
        ms = np.empty(len(positions))
        flt.reset()
        for t in range(len(positions)):
            t0 = time.perf_counter()
            out[t] = flt.update(positions[t], states[t], float(times[t]))
            ms[t] = 1000.0 * (time.perf_counter() - t0)
        stage_ms = {"filter": ms.copy()}
        info: dict[str, Any] = {"filter_params": flt.params}
        if spec.ragdoll:
            if self._ragdoll_stage is None:
                self._ragdoll_stage = RagdollStage()
            lengths = reference_bone_lengths(positions, states)
            out, ragdoll_ms, ragdoll_info = self._ragdoll_stage.run(out, lengths)
            stage_ms["ragdoll"] = ragdoll_ms
            ms = ms + ragdoll_ms
            info.update(ragdoll_info)
        return MethodResult(poses=out, ms=ms, stage_ms=stage_ms, info=info)

    def _run_reconstruction(
        self,
        spec: Method,
        recording: RecordingLike,
        seed: int | np.random.Generator,
        stop_on_interrupt: bool,
    ) -> MethodResult:

        assert spec.selector is not None and spec.optimizer is not None
        reconstructor = self._reconstructor(spec.selector, spec.ragdoll, spec.prior)
        rng = as_generator(seed)
        result = reconstructor.reconstruct(
            recording, make(spec.optimizer), rng=rng, stop_on_interrupt=stop_on_interrupt
        )
        return _method_result(result)

    def run_many(
        self,
        method: Method | str,
        recordings: Sequence[RecordingLike],
        seeds: Sequence[int | np.random.Generator],
    ) -> list[MethodResult]:
        """Run ``method`` on many recordings; ``shum``/``fpg`` reconstruct them side by side
        with their searches batched (:func:`fpg_gym.reconstruct.streams.run_streams`).

        Each result equals ``run(method, recordings[i], seeds[i])`` (timings aside: a batched
        frame's search time is the batch's, see :mod:`fpg_gym.reconstruct.streams`).
        """
        spec = parse_method(method) if isinstance(method, str) else method
        if len(seeds) != len(recordings):
            raise ValueError(
                f"seeds: expected {len(recordings)} (one per recording), got {len(seeds)}"
            )
        if spec.is_filter or len(recordings) <= 1:
            return [self.run(spec, rec, seed) for rec, seed in zip(recordings, seeds, strict=True)]
        assert spec.selector is not None and spec.optimizer is not None
        first = self._reconstructor(spec.selector, spec.ragdoll, spec.prior)
        key = (spec.selector, spec.ragdoll, spec.prior)
        pool = self._pools.setdefault(key, [first])
        while len(pool) < len(recordings):
            pool.append(
                Reconstructor(self.graph, first.config, ragdoll=ragdoll_factory(spec.ragdoll))
            )
        results = run_streams(pool[: len(recordings)], recordings, spec.optimizer, list(seeds))
        return [_method_result(result) for result in results]

    def close(self) -> None:
        """Release every ragdoll."""
        for reconstructor in self._reconstructors.values():
            reconstructor.close()
        for pool in self._pools.values():
            for reconstructor in pool[1:]:  # pool[0] is one of self._reconstructors
                reconstructor.close()
        self._reconstructors.clear()
        self._pools.clear()
        if self._ragdoll_stage is not None:
            self._ragdoll_stage.close()
            self._ragdoll_stage = None

    def __enter__(self) -> MethodRunner:
        return self

    def __exit__(self, *exc: object) -> None:
        self.close()


#: The method every comparison is measured against (graph selection + local search).
BASELINE: Method = Method("fpg")

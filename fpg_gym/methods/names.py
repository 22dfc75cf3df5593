"""Reconstruction methods by name: the reference filters and the two reconstruction pipelines.

One name picks everything a run of a Kinect stream needs; ``fpg-gym compare --methods`` and
``fpg-gym demo`` take these names, and :class:`~fpg_gym.methods.runner.MethodRunner` runs one on
a recording.

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
(see :class:`~fpg_gym.methods.ragdoll.RagdollStage`).

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

from collections.abc import Iterable, Sequence
from dataclasses import dataclass, replace

from fpg_gym.filters import PRESETS

__all__ = [
    "BASELINE",
    "FILTER_BASES",
    "METHOD_BASES",
    "RECONSTRUCTION_BASES",
    "SELECTOR_OF_BASE",
    "Method",
    "expand_methods",
    "parse_method",
    "parse_methods",
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


#: The method every comparison is measured against (graph selection + local search).
BASELINE: Method = Method("fpg")

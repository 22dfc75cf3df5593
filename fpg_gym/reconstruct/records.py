"""What a reconstruction returns: one :class:`FrameOutput` (the pose and its
:class:`FrameRecord`) per frame and the stream's :class:`ReconstructionResult` (poses, records,
the bone lengths' report).
"""

from __future__ import annotations

from dataclasses import dataclass, field
from typing import Any, NamedTuple

import numpy as np

from fpg_gym.reconstruct.energy import TERM_NAMES
from fpg_gym.reconstruct.left_right import LABELLINGS

__all__ = ["STAGES", "FrameOutput", "FrameRecord", "ReconstructionResult"]

STAGES: tuple[str, ...] = (
    "normalise",
    "reliability",
    "selection",
    "latent",
    "search",
    "finish",
    "ragdoll",
)
"""Stages timed in :attr:`FrameRecord.ms` (milliseconds)."""


@dataclass
class FrameRecord:
    """What happened in one frame (not frozen: a frozen dataclass of this many fields costs a
    frame several microseconds to build).

    Attributes
    ----------
    index, timestamp : int, float
    reliability, behaviour, kinematic, tracking : ndarray, shape (20,)
    reference_source : str
        Where the bone lengths came from (see :mod:`fpg_gym.reconstruct.reliability`).
    nodes, node_scores : ndarray, shape (K,)
        Selected nodes (best first) and their selection scores.
    num_scored : int
        Nodes scored by the selector.
    full_search, recovered : bool
        Whether every node was scored; whether the recovery rule triggered it.
    first, no_body : bool
        Stream (re)start; no joint tracked or inferred.
    energy, energy_x0 : float
        ``E`` of the chosen point and of ``x0``.
    terms : dict of str to float
        ``Ec``, ``Es``, ``Ek``, ``Em`` of the chosen point (unweighted).
    evaluations : int
        Energy evaluations spent by the search.
    ms : dict of str to float
        Milliseconds per stage (:data:`STAGES`) and ``total``.
    ragdoll : dict or None
        The ragdoll's ``info`` after the frame (None without a ragdoll).
    labelling : str
        The left/right labelling used (:data:`LABELLINGS`; ``"as-reported"`` unless fixed).
    bone_lengths : ndarray, shape (19,) or None
        The user's bone lengths used in this frame (after the settling rule).
    """

    index: int
    timestamp: float
    reliability: np.ndarray
    behaviour: np.ndarray
    kinematic: np.ndarray
    tracking: np.ndarray
    reference_source: str
    nodes: np.ndarray
    node_scores: np.ndarray
    num_scored: int
    full_search: bool
    recovered: bool
    first: bool
    no_body: bool
    energy: float
    energy_x0: float
    terms: dict[str, float]
    evaluations: int
    ms: dict[str, float]
    ragdoll: dict[str, Any] | None = None
    labelling: str = "as-reported"
    bone_lengths: np.ndarray | None = None


class FrameOutput(NamedTuple):
    """One reconstructed frame: the pose and what happened (unpacks as ``pose, record``).

    Attributes
    ----------
    pose : ndarray, shape (20, 3), float32
        The reconstruction in the input's camera space.
    record : FrameRecord
    """

    pose: np.ndarray
    record: FrameRecord


@dataclass
class ReconstructionResult:
    """A stream's output, whatever made it: a reconstruction (poses and per-frame records) or a
    reference filter (poses and per-stage times, no records).

    Attributes
    ----------
    poses : ndarray, shape (T, 20, 3), float32
        Output poses in the input's camera space, frame for frame.
    records : list of FrameRecord
        One per frame of a reconstruction; empty for a filter.
    interrupted : bool
        True when the run stopped early (Ctrl-C); ``poses`` then holds the frames done.
    bones : dict
        When the bone lengths settled and how much they changed afterwards
        (:meth:`fpg_gym.reconstruct.bones.BoneSettler.report`; empty for a filter).
    info : dict
        Further facts of the run (recoveries, ragdoll divergences, a filter's parameters, ...).
    stage_times : dict of str to ndarray (T,), optional
        Milliseconds per stage of a stream without records (a filter: ``filter``, ``ragdoll``);
        None for a reconstruction (its records hold them).
    """

    poses: np.ndarray
    records: list[FrameRecord] = field(default_factory=list)
    interrupted: bool = False
    bones: dict[str, Any] = field(default_factory=dict)
    info: dict[str, Any] = field(default_factory=dict)
    stage_times: dict[str, np.ndarray] | None = None

    @property
    def num_frames(self) -> int:
        """Frames output."""
        return len(self.poses)

    @property
    def stage_ms(self) -> dict[str, np.ndarray]:
        """Milliseconds of each stage per frame, ``(T,)`` each: the reconstructor's
        :data:`STAGES` or a filter's stages."""
        if self.stage_times is not None:
            return dict(self.stage_times)
        return {s: np.array([r.ms[s] for r in self.records]) for s in STAGES}

    @property
    def ms(self) -> np.ndarray:
        """Milliseconds per frame ``(T,)``, every stage."""
        if self.stage_times is None:
            return np.array([r.ms["total"] for r in self.records])
        stages = list(self.stage_times.values())
        return np.sum(stages, axis=0) if stages else np.zeros(len(self.poses))

    @property
    def evaluations(self) -> np.ndarray | None:
        """Energy evaluations per frame ``(T,)`` (None for a filter)."""
        if self.stage_times is not None:
            return None
        return np.array([r.evaluations for r in self.records], dtype=np.float64)

    @property
    def energy(self) -> np.ndarray | None:
        """Energy of the chosen point per frame ``(T,)`` (None for a filter)."""
        if self.stage_times is not None:
            return None
        return np.array([r.energy for r in self.records], dtype=np.float64)

    def arrays(self) -> dict[str, np.ndarray]:
        """Everything as arrays (the ``reconstruct`` command's ``.npz`` keys).

        ``poses`` (T,20,3), ``timestamps`` (T,), ``reliability``/``behaviour``/``kinematic``/
        ``tracking`` (T,20), ``nodes``/``node_scores`` (T,K) (−1 / NaN padded), ``num_scored``,
        ``evaluations`` (T,), ``energy``, ``energy_x0`` (T,), ``energy_terms`` (T,5) in
        ``energy_term_names`` order, ``full_search``/``recovered``/``first``/``no_body`` (T,)
        bool, ``ms_per_frame`` (T,), ``ms_stages`` (T,S) in ``stage_names`` order. A filter's
        (``stage_times`` given): ``poses`` and ``ms_per_frame``.
        """
        records = self.records
        if self.stage_times is not None:
            return {"poses": np.asarray(self.poses, dtype=np.float32), "ms_per_frame": self.ms}
        t = len(records)
        k = max((len(r.nodes) for r in records), default=0)
        nodes = np.full((t, k), -1, dtype=np.int64)
        scores = np.full((t, k), np.nan)
        for i, r in enumerate(records):
            nodes[i, : len(r.nodes)] = r.nodes
            scores[i, : len(r.nodes)] = r.node_scores

        def stack(name: str, dtype: Any = np.float64) -> np.ndarray:
            return np.array([getattr(r, name) for r in records], dtype=dtype).reshape(t, -1)

        out: dict[str, np.ndarray] = {
            "poses": np.asarray(self.poses[:t], dtype=np.float32),
            "timestamps": np.array([r.timestamp for r in records], dtype=np.float64),
            "reliability": stack("reliability").astype(np.float32),
            "behaviour": stack("behaviour").astype(np.float32),
            "kinematic": stack("kinematic").astype(np.float32),
            "tracking": stack("tracking").astype(np.float32),
            "nodes": nodes,
            "node_scores": scores,
            "num_scored": np.array([r.num_scored for r in records], dtype=np.int64),
            "evaluations": np.array([r.evaluations for r in records], dtype=np.int64),
            "energy": np.array([r.energy for r in records]),
            "energy_x0": np.array([r.energy_x0 for r in records]),
            "energy_terms": np.array([[r.terms[n] for n in TERM_NAMES] for r in records]).reshape(
                t, len(TERM_NAMES)
            ),
            "energy_term_names": np.array(TERM_NAMES),
            "full_search": np.array([r.full_search for r in records], dtype=bool),
            "recovered": np.array([r.recovered for r in records], dtype=bool),
            "first": np.array([r.first for r in records], dtype=bool),
            "no_body": np.array([r.no_body for r in records], dtype=bool),
            "labelling": np.array([LABELLINGS.index(r.labelling) for r in records], dtype=np.int8),
            "labelling_names": np.array(LABELLINGS),
            "ms_per_frame": self.ms,
            "ms_stages": np.array([[r.ms[s] for s in STAGES] for r in records]).reshape(
                t, len(STAGES)
            ),
            "stage_names": np.array(STAGES),
        }
        if t and all(r.bone_lengths is not None for r in records):
            out["bone_lengths"] = np.stack([np.asarray(r.bone_lengths) for r in records])
        return out

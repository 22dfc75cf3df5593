"""Methods by name and the one runner of them: the reference filters and the two
reconstruction pipelines (:mod:`fpg_gym.methods.names`, the grammar), run on recordings by
:class:`MethodRunner` (:mod:`fpg_gym.methods.runner`) and on a live stream by
:mod:`fpg_gym.methods.live`; the ragdoll as a final filter (:mod:`fpg_gym.methods.ragdoll`).
Every stream of frames goes through :mod:`fpg_gym.reconstruct.streams`, and every run gives a
:class:`~fpg_gym.reconstruct.ReconstructionResult`.
"""

from __future__ import annotations

from fpg_gym.methods.names import (
    BASELINE,
    FILTER_BASES,
    METHOD_BASES,
    RECONSTRUCTION_BASES,
    SELECTOR_OF_BASE,
    Method,
    expand_methods,
    parse_method,
    parse_methods,
)
from fpg_gym.methods.ragdoll import RagdollStage, ragdoll_factory, reference_bone_lengths
from fpg_gym.methods.runner import MethodRunner, reconstruct_many

__all__ = [
    "BASELINE",
    "FILTER_BASES",
    "METHOD_BASES",
    "RECONSTRUCTION_BASES",
    "SELECTOR_OF_BASE",
    "Method",
    "MethodRunner",
    "RagdollStage",
    "expand_methods",
    "parse_method",
    "parse_methods",
    "ragdoll_factory",
    "reconstruct_many",
    "reference_bone_lengths",
]

"""The reconstruction energy (Shum 2013 Eq. 10-15), minimised over the natural posture space.

``E = w_c Ec + w_s Es + w_k Ek + w_m Em`` with weights 1.0, 0.5, 1.5, 0.25 where, for a candidate
pose ``p_x`` (normalised, in the current frame):

* ``Ec = sum_j R(j) ||p_x(j) - p_k(j)||^2`` — control: follow the reliable sensor joints
  (Eq. 11, the Eq. 9 form);
* ``Es = min_n mean_j ||p_x(j) - p_n(j)||^2`` over the K candidates ``p_n`` — style: stay near a
  real pose (Eq. 12);
* ``Ek = mean_b (l_x(b) - l_db(b))^2`` — kinematics: keep the bone lengths (Eq. 13);
* ``Em = mean_j ||p_x(j) - 2 p_{x-1}(j) + p_{x-2}(j)||^2`` — motion: small acceleration (Eq. 14).
  With irregular timestamps the constant-velocity target ``p_{x-1} + (p_{x-1} - p_{x-2}) dt /
  dt_prev`` replaces ``2 p_{x-1} - p_{x-2}`` (identical at a constant frame rate), so
  ``Em = mean_j ||p_x(j) - target(j)||^2``. Without a previous frame ``Em = 0``.

Beyond the papers, an optional fifth term (weight 0 by default, which is the papers' energy):

* ``Ep = mean_i z_i^2`` over the whitened latent coordinates — prior: a Gaussian prior on the
  natural posture space, centred on the mean of the K candidates with their spread (the PCA
  pose prior of e.g. Chai & Hodgins 2005). It pulls the search toward the candidates when the
  sensor term trusts joints that are wrong. ``EnergyWeights.with_prior()`` gives the weight
  chosen on a validation split (see the README).

The functions ``control_energy`` ... ``motion_energy`` compute each term directly from poses
(the reference implementation). :class:`EnergyModel` evaluates the same terms for a batch of
latent points without building the candidates' distance tensors: poses are decoded with one
matrix product and ``Es`` uses ``||x - n||^2 = ||std*z - y_n||^2 + ||r_n||^2`` (``y_n`` the
neighbour's unwhitened coordinates, ``r_n`` its residual outside the space), which is exact.
"""

from __future__ import annotations

import functools
from collections.abc import Callable, Sequence
from dataclasses import asdict, dataclass
from types import ModuleType
from typing import Any

import numpy as np
import numpy.typing as npt

from fpg_gym.core import skeleton
from fpg_gym.core.compiled import compiled_module
from fpg_gym.core.poses import bone_lengths
from fpg_gym.reconstruct.kernels import (
    KERNELS,
    EnergyTables,
    bind_energy,
    resolve_kernel,
    stack_tables,
)
from fpg_gym.reconstruct.latent import POSE_SIZE, LatentSpace

#: The papers' terms (computable from a pose alone) and all terms, in weight order.
POSE_TERM_NAMES: tuple[str, ...] = ("Ec", "Es", "Ek", "Em")
TERM_NAMES: tuple[str, ...] = (*POSE_TERM_NAMES, "Ep")
#: Kernels of :class:`EnergyModel`'s total: the fused ones of :mod:`fpg_gym.reconstruct.kernels`
#: and ``"direct"``, the terms' definitions on decoded poses (:func:`pose_energy_terms`, slow).
ENERGY_KERNELS: tuple[str, ...] = (*KERNELS, "direct")
#: Arithmetic precisions of :class:`EnergyModel`'s fused kernel
#: (``ReconstructorConfig.energy_dtype``).
ENERGY_DTYPES: tuple[str, ...] = ("float64", "float32")
#: Prior weight chosen on a validation split of Bandai Namco takes (README, "Beyond the papers").
TUNED_PRIOR_WEIGHT = 0.1


@dataclass(frozen=True)
class EnergyWeights:
    """Weights of the energy terms (Shum Eq. 10).

    Attributes
    ----------
    control, style, kinematic, motion : float
        Weights of ``Ec``, ``Es``, ``Ek`` and ``Em`` (1.0, 0.5, 1.5, 0.25).
    prior : float
        Weight of the latent prior ``Ep`` (beyond the papers; 0 = off, the papers' energy).
    """

    control: float = 1.0
    style: float = 0.5
    kinematic: float = 1.5
    motion: float = 0.25
    prior: float = 0.0

    @classmethod
    def with_prior(cls, prior: float = TUNED_PRIOR_WEIGHT) -> EnergyWeights:
        """The papers' weights plus the latent prior (weight chosen on a validation split)."""
        return cls(prior=prior)

    def __post_init__(self) -> None:
        for name, value in asdict(self).items():
            if not np.isfinite(value) or value < 0:
                raise ValueError(f"energy weight {name}: expected a finite value >= 0, got {value}")

    def as_array(self) -> np.ndarray:
        """The weights in :data:`TERM_NAMES` order, ``(5,)``."""
        return np.array([self.control, self.style, self.kinematic, self.motion, self.prior])

    def paper_terms(self) -> tuple[float, float, float, float]:
        """The weights of the papers' four terms (:data:`POSE_TERM_NAMES` order): ``w_c, w_s,
        w_k, w_m``."""
        return (self.control, self.style, self.kinematic, self.motion)


# --------------------------------------------------------------------------- direct terms


def control_energy(poses: np.ndarray, sensor: np.ndarray, reliability: np.ndarray) -> np.ndarray:
    """``Ec`` (Eq. 11): ``sum_j R(j) ||p_x(j) - p_k(j)||^2`` for poses ``(n, 20, 3) -> (n,)``."""
    diff = np.asarray(poses, dtype=np.float64) - np.asarray(sensor, dtype=np.float64)
    return np.einsum("njc,njc->nj", diff, diff) @ np.asarray(reliability, dtype=np.float64)


def style_energy(poses: np.ndarray, neighbours: np.ndarray) -> np.ndarray:
    """``Es`` (Eq. 12): ``min_n mean_j ||p_x(j) - p_n(j)||^2``, ``(n, 20, 3) -> (n,)``."""
    diff = np.asarray(poses, dtype=np.float64)[:, None] - np.asarray(neighbours, dtype=np.float64)
    return np.einsum("nkjc,nkjc->nk", diff, diff).min(axis=1) / skeleton.NUM_JOINTS


def kinematic_energy(poses: np.ndarray, lengths: np.ndarray) -> np.ndarray:
    """``Ek`` (Eq. 13): ``mean_b (l_x(b) - l_db(b))^2``, ``(n, 20, 3) -> (n,)``."""
    return ((bone_lengths(poses) - np.asarray(lengths)) ** 2).mean(axis=1)


def motion_energy(poses: np.ndarray, target: np.ndarray | None) -> np.ndarray:
    """``Em`` (Eq. 14): ``mean_j ||p_x(j) - target(j)||^2``, target ``= 2 p_{x-1} - p_{x-2}``.

    Returns zeros when ``target`` is None (first frame).
    """
    poses = np.asarray(poses, dtype=np.float64)
    if target is None:
        return np.zeros(len(poses))
    diff = poses - np.asarray(target, dtype=np.float64)
    return np.einsum("njc,njc->n", diff, diff) / skeleton.NUM_JOINTS


def motion_target(
    previous: np.ndarray, before: np.ndarray | None, dt: float, dt_previous: float | None = None
) -> np.ndarray:
    """Constant-velocity prediction ``p_{x-1} + (p_{x-1} - p_{x-2}) dt / dt_prev``.

    Equals ``2 p_{x-1} - p_{x-2}`` at a constant frame rate; ``p_{x-1}`` when ``before`` is None.
    """
    previous = np.asarray(previous, dtype=np.float64)
    if before is None:
        return previous.copy()
    ratio = 1.0 if not dt_previous or dt_previous <= 0 else dt / dt_previous
    return previous + (previous - np.asarray(before, dtype=np.float64)) * ratio


def pose_energy_terms(
    poses: np.ndarray,
    *,
    sensor: np.ndarray,
    reliability: np.ndarray,
    neighbours: np.ndarray,
    lengths: np.ndarray,
    target: np.ndarray | None,
) -> dict[str, np.ndarray]:
    """The papers' four terms (:data:`POSE_TERM_NAMES`) for poses ``(n, 20, 3)``, computed
    directly (the reference path)."""
    return {
        "Ec": control_energy(poses, sensor, reliability),
        "Es": style_energy(poses, neighbours),
        "Ek": kinematic_energy(poses, lengths),
        "Em": motion_energy(poses, target),
    }


# --------------------------------------------------------------------------- latent fast path

# Ek: bone vectors are linear in the flat pose x (60,): child minus parent coordinates.
_CHILD_COORDS = (3 * skeleton.BONES[:, 1][:, None] + np.arange(3)).reshape(-1)
_PARENT_COORDS = (3 * skeleton.BONES[:, 0][:, None] + np.arange(3)).reshape(-1)
#: The compiled kernels' "no motion target" (``Em = 0``).
_NO_TARGET = np.zeros(0)
_TERMS_AND_TOTAL = (*TERM_NAMES, "E")
_FLOAT64 = np.dtype(np.float64)
_DTYPES = tuple(np.dtype(name) for name in ENERGY_DTYPES)


@functools.cache
def _weights_array(weights: EnergyWeights) -> np.ndarray:
    """``weights.as_array()``, once per set of weights (shared: not to be written)."""
    return weights.as_array()


class EnergyModel:
    """The energy of one frame as a function of whitened latent points.

    Parameters
    ----------
    latent : LatentSpace
    sensor : ndarray, shape (20, 3)
        Normalised sensor pose ``p_k``.
    reliability : ndarray, shape (20,)
    neighbours : ndarray, shape (K, 20, 3)
        The selected candidates (what ``Es`` compares with).
    lengths : ndarray, shape (19,)
        Reference bone lengths ``l_db``.
    target : ndarray, shape (20, 3) or None
        Motion target for ``Em`` (see :func:`motion_target`); None gives ``Em = 0``.
    weights : EnergyWeights, optional
    dtype : numpy dtype
        Arithmetic precision of the fused kernel (float64 here; the reconstructor's default,
        ``ReconstructorConfig.energy_dtype``, is float32). ``float32`` is about 4x faster for
        batches of a few thousand points and ~20 % faster at 100; energies are returned as
        float64 either way.
    kernel : {"auto", "numba", "numpy", "direct"}
        The kernel of the total (calling the model; what the search runs): the frame's
        :class:`~fpg_gym.reconstruct.kernels.EnergyTables` (Eq. 10 as one matrix) evaluated by
        :func:`~fpg_gym.reconstruct.kernels.fused_energy`, compiled when ``fpg-gym[fast]``
        (numba) is installed with ``"auto"``; ``"direct"`` sums :func:`pose_energy_terms` of the
        decoded poses (the definition; slow, for benchmarks; not stacked by
        :class:`StackedEnergy`). :meth:`terms` gives each term: compiled
        (:func:`fpg_gym.reconstruct.compiled_frame.latent_terms`) with numba, else the
        definitions on the decoded poses.
    """

    def __init__(
        self,
        latent: LatentSpace,
        sensor: np.ndarray,
        reliability: np.ndarray,
        neighbours: np.ndarray,
        lengths: np.ndarray,
        target: np.ndarray | None,
        weights: EnergyWeights | None = None,
        dtype: npt.DTypeLike = np.float64,
        kernel: str = "auto",
    ) -> None:
        self.dtype = np.dtype(dtype)
        if self.dtype not in _DTYPES:
            raise ValueError(f"dtype: expected float32 or float64, got {self.dtype}")
        self.kernel = "direct" if kernel == "direct" else resolve_kernel(kernel)
        self.latent = latent
        self.weights = weights or EnergyWeights()
        self._w = _weights_array(self.weights)
        self.sensor = np.asarray(sensor, dtype=np.float64).reshape(POSE_SIZE)
        self.reliability = np.asarray(reliability, dtype=np.float64)
        self.lengths = np.asarray(lengths, dtype=np.float64)
        self.target = None if target is None else np.asarray(target, dtype=np.float64).reshape(-1)
        self._neighbours = np.asarray(neighbours, dtype=np.float64)
        flat = self._neighbours.reshape(len(neighbours), POSE_SIZE)
        compiled = (
            compiled_module("fpg_gym.reconstruct.compiled_frame")
            if self.kernel == "numba"
            else None
        )
        # With numba, the arguments of the compiled terms (latent_terms) after z; else None.
        self._terms_arguments: tuple[Any, ...] | None = None
        if compiled is None:
            self.tables = self._tables(latent, flat)
            if self.dtype != _FLOAT64:
                self.tables = self.tables.astype(self.dtype)
        else:
            self.tables = self._setup_compiled(compiled, latent, flat)
        # The fused kernel bound to the tables, on the first call (a compiled local search
        # takes the tables themselves).
        self._energy: Callable[[np.ndarray], np.ndarray] | None = None

    def _setup_compiled(
        self, compiled: ModuleType, latent: LatentSpace, flat: np.ndarray
    ) -> EnergyTables:
        """:meth:`_tables` and the compiled terms' arrays in one compiled call
        (:func:`fpg_gym.reconstruct.compiled_frame.energy_setup`)."""
        target = _NO_TARGET if self.target is None else self.target
        basis = latent.basis if latent.basis.flags.c_contiguous else latent.basis.copy()
        matrix, c0, ycst, b0, wk, components, joint_weights, y, y_sq, r_sq = compiled.energy_setup(
            latent.mean,
            basis,
            latent.std,
            self.sensor,
            self.reliability,
            flat if flat.flags.c_contiguous else flat.copy(),
            self.lengths,
            target,
            self._w,
            _CHILD_COORDS,
            _PARENT_COORDS,
        )
        lengths = self.lengths
        arrays = [latent.mean, components, self.sensor, joint_weights, y, y_sq, r_sq, latent.std]
        if self.dtype != _FLOAT64:  # the tables and the terms' arithmetic in the model's dtype
            dtype = self.dtype
            matrix, ycst, b0, lengths = (a.astype(dtype) for a in (matrix, ycst, b0, lengths))
            arrays = [a.astype(dtype) for a in arrays]
            target = target.astype(dtype)
        self._terms_arguments = (
            compiled.latent_terms,
            *arrays,
            lengths,
            target,
            _CHILD_COORDS,
            _PARENT_COORDS,
            self._w,
        )
        return EnergyTables(matrix, float(c0), ycst, b0, lengths, float(wk))

    def _tables(self, latent: LatentSpace, flat: np.ndarray) -> EnergyTables:
        """Eq. 10 as one matrix (:mod:`fpg_gym.reconstruct.kernels`): ``Ec`` (Eq. 11, ``W =
        diag(R)``) and ``Em`` (Eq. 14, ``W = I / 20``, where ``C C^T = diag(std^2)``) expanded
        as ``z^T A z + g.z + c``, the prior ``|z|^2 / d``, ``|u|^2`` and the ``K`` inner
        products of ``Es`` (Eq. 12; ``|y_n|^2 + |r_n|^2 = |x_n - mean|^2``, ``y_n`` the
        neighbours' unwhitened coordinates), the bone vectors of ``Ek`` (Eq. 13). The numpy
        twin of :func:`fpg_gym.reconstruct.compiled_frame.energy_setup`."""
        joints = skeleton.NUM_JOINTS
        joint_weights = np.repeat(self.reliability, 3)  # (60,) for Ec
        components = latent.components  # (d, 60)
        centred = flat - latent.mean
        y = centred @ latent.basis.T
        mean, std, d = latent.mean, latent.std, latent.dim
        wc, ws, wk, wm, wp = self._w
        delta = mean - self.sensor
        weighted = wc * joint_weights * delta
        const = float(weighted @ delta)
        diagonal = ws / joints * std * std + wp / max(d, 1)
        if self.target is not None:
            motion = mean - self.target
            weighted = weighted + (wm / joints) * motion
            const += wm / joints * float(motion @ motion)
            diagonal = diagonal + wm / joints * std * std
        k = len(y)
        matrix = np.empty((d, d + 1 + k + 3 * skeleton.NUM_BONES))
        np.matmul(components * (wc * joint_weights), components.T, out=matrix[:, :d])
        matrix[:, :d].flat[:: d + 1] += diagonal
        matrix[:, d] = 2.0 * (components @ weighted)
        matrix[:, d + 1 : d + 1 + k] = (-2.0 * ws / joints) * (std[:, None] * y.T)
        matrix[:, d + 1 + k :] = components[:, _CHILD_COORDS] - components[:, _PARENT_COORDS]
        return EnergyTables(
            matrix=matrix,
            c0=const,
            ycst=(ws / joints) * np.einsum("kd,kd->k", centred, centred),
            b0=mean[_CHILD_COORDS] - mean[_PARENT_COORDS],
            lengths=self.lengths,
            wk=wk / skeleton.NUM_BONES,
        )

    @property
    def dim(self) -> int:
        """Latent dimension ``d``."""
        return self.latent.dim

    @property
    def fused_kernel(self) -> str:
        """The kernel evaluating :attr:`tables` (``"numba"`` or ``"numpy"``; ``"numpy"`` for
        the ``"direct"`` model, whose tables are the same)."""
        return "numpy" if self.kernel == "direct" else self.kernel

    def stack_key(self) -> tuple[Any, ...]:
        """Models with equal keys can be stacked (:meth:`StackedEnergy.of`): same dtype,
        weights, latent dimension, number of candidates and kernel."""
        return (self.dtype.str, tuple(self._w), self.dim, self.tables.k, self.kernel)

    def terms(self, z: np.ndarray) -> dict[str, np.ndarray]:
        """``Ec``, ``Es``, ``Ek``, ``Em``, ``Ep`` for latent points ``(n, d)``, each ``(n,)``
        float64: compiled with numba (in the model's dtype), else :func:`pose_energy_terms` on
        the decoded poses."""
        terms = self.terms_and_total(z)
        del terms["E"]
        return terms

    def terms_and_total(self, z: np.ndarray) -> dict[str, np.ndarray]:
        """:meth:`terms` and ``E``, their :meth:`total` (one compiled call with numba)."""
        if self._terms_arguments is None:
            terms = self._definition_terms(z)
            terms["E"] = self.total(terms)
            return terms
        function, *arguments = self._terms_arguments
        rows = function(np.ascontiguousarray(z, dtype=self.dtype), *arguments)
        return dict(zip(_TERMS_AND_TOTAL, rows, strict=True))

    def total(self, terms: dict[str, np.ndarray]) -> np.ndarray:
        """Weighted sum of terms (Eq. 10, plus the prior when its weight is not 0)."""
        w = self._w
        total = w[0] * terms["Ec"] + w[1] * terms["Es"] + w[2] * terms["Ek"] + w[3] * terms["Em"]
        return total + w[4] * terms["Ep"] if w[4] else total

    def __call__(self, z: np.ndarray) -> np.ndarray:
        """``E`` for latent points ``(n, d) -> (n,)`` float64, by the fused kernel."""
        if self.kernel == "direct":
            return self.total(self._definition_terms(z))
        if self._energy is None:
            self._energy = bind_energy(self.tables, self.fused_kernel)
        energy = self._energy(np.asarray(z, dtype=self.dtype))
        return energy if energy.dtype == np.float64 else energy.astype(np.float64)

    def _definition_terms(self, z: np.ndarray) -> dict[str, np.ndarray]:
        """The terms by their definitions (:func:`pose_energy_terms`) on the decoded poses,
        and the latent prior ``Ep = |z|^2 / d``, float64."""
        z = np.asarray(z, dtype=np.float64)
        terms = pose_energy_terms(
            self.latent.decode(z),
            sensor=self.sensor.reshape(skeleton.NUM_JOINTS, 3),
            reliability=self.reliability,
            neighbours=self._neighbours,
            lengths=self.lengths,
            target=None if self.target is None else self.target.reshape(skeleton.NUM_JOINTS, 3),
        )
        terms["Ep"] = np.einsum("nd,nd->n", z, z) / max(z.shape[1], 1)
        return terms


class StackedEnergy:
    """The energies of S frames (S streams, one frame each) evaluated together.

    Built from S :class:`EnergyModel` with equal :meth:`EnergyModel.stack_key`: their
    :class:`~fpg_gym.reconstruct.kernels.EnergyTables` stacked
    (:func:`~fpg_gym.reconstruct.kernels.stack_tables`) and evaluated by the same fused kernel,
    so ``StackedEnergy.of(models).total(z)[s]`` equals ``models[s](z[s])`` (to the last bit with
    the compiled kernel, to floating-point rounding with numpy's). The many-stream search
    (:func:`fpg_gym.reconstruct.search.search_together`) evaluates one search iteration of
    every stream with one call.
    """

    def __init__(self, tables: EnergyTables, kernel: str) -> None:
        self.tables = tables
        self.kernel = kernel
        self._energy = bind_energy(tables, kernel)

    @classmethod
    def of(cls, models: Sequence[EnergyModel]) -> StackedEnergy:
        """Stack ``models`` (at least one, equal :meth:`EnergyModel.stack_key`).

        Raises
        ------
        ValueError
            On an empty list, a ``"direct"`` model or models that differ in their stack key.
        """
        if not models:
            raise ValueError("models: expected at least one EnergyModel, got none")
        if models[0].kernel == "direct":
            raise ValueError("models[0]: the 'direct' kernel is evaluated model by model")
        key = models[0].stack_key()
        for i, model in enumerate(models):
            if model.stack_key() != key:
                raise ValueError(
                    f"models[{i}]: expected the stack key {key} of models[0], got "
                    f"{model.stack_key()} (dtype, weights, d, K, kernel)"
                )
        return cls(stack_tables([m.tables for m in models]), models[0].fused_kernel)

    def __len__(self) -> int:
        return len(self.tables)

    def select(self, streams: np.ndarray) -> StackedEnergy:
        """The stack of the given streams (indices into this stack)."""
        return StackedEnergy(self.tables.select(streams), self.kernel)

    def total(self, z: np.ndarray) -> np.ndarray:
        """``E`` (Eq. 10) of points ``(S, n, d)`` -> ``(S, n)`` float64."""
        energy = self._energy(np.asarray(z, dtype=self.tables.matrix.dtype))
        return energy if energy.dtype == np.float64 else energy.astype(np.float64)

"""Learned candidate samplers as optimisers: ``learned:PATH`` and ``learned+search:PATH``.

A sampler trained by ``fpg-gym train-sampler`` (:mod:`policies`) maps a frame's observation to
a Gaussian over the whitened latent space. These optimisers build the observation of the
problem they are given (:meth:`policies.sampler.GaussianSampler.observe`, the env's own
builder), draw candidates from the Gaussian and let :func:`optimizers.run_optimizer` score them
with ``problem.evaluate``: the same budget accounting as every other optimiser.

``learned:PATH`` (:class:`LearnedSampler`)
    One batch of ``samples`` (200) points: the Gaussian's anchor (when the model has one, see
    :class:`policies.sampler.FeatureMap`) and mean first, then draws from the Gaussian; the
    lowest energy wins, or with a prior weight (a linear sampler's default) the highest
    posterior.
``learned+search:PATH`` (:class:`LearnedSearch`)
    ``samples`` (100) learned points, then local-search iterations (Shum §VI-E rule: move to the
    batch's best on improvement, else halve the step) seeded at the best one: ``iterations``
    (2) x ``search_samples`` (50). 200 evaluations in all by default.

``PATH`` is a model path as :func:`policies.loading.load_sampler` takes it (``MODEL``,
``MODEL.json`` or ``.pt``). A model is data: its weights are tensors read with
``weights_only=True`` and its network is rebuilt from the JSON, so loading one never runs code
from the files; anything else (stable-baselines3's pickling ``.zip`` included) is refused with a
:class:`~fpg_gym.core.errors.DataFormatError`. torch (and stable-baselines3 for RL samplers) must be
installed: ``pip install 'fpg-gym[learn]'``.

Examples
--------
>>> import optimizers                                                    # doctest: +SKIP
>>> opt = optimizers.make("learned+search:runs/sampler")                 # doctest: +SKIP
>>> z = optimizers.run_optimizer(problem, opt, rng=0).x                  # doctest: +SKIP
"""

from __future__ import annotations

import copy
import os
from typing import Any

import numpy as np

from optimizers import BaseOptimizer, register_prefix
from policies.loading import load_sampler

__all__ = ["LearnedSampler", "LearnedSearch"]


def _sampler(model: Any) -> Any:
    if isinstance(model, str | os.PathLike):
        return load_sampler(model)
    if not callable(getattr(model, "latent_gaussian", None)):
        raise ValueError(
            f"model: expected a sampler path or a policies.GaussianSampler, got {model!r}"
        )
    return model


#: Attributes a copy of a learned optimiser shares with the original (the model, the frame's
#: problem).
_SHARED = frozenset({"model", "sampler", "problem"})


class LearnedSampler(BaseOptimizer):
    """Candidates drawn from a learned Gaussian (``learned:PATH``).

    Parameters
    ----------
    model : str, path or GaussianSampler
        A saved sampler (loaded once, here) or a sampler object.
    samples : int
        Points (200): the anchor (if any) and the mean, then draws from the Gaussian.
    std_scale : float
        Multiplies the model's standard deviation (1).
    prior_weight : float, optional
        With a weight ``w``, the search returns the evaluated point of lowest
        ``E(z) + w |(z - mean) / std|^2 / 2``, the learned Gaussian as a prior (its
        :meth:`recommend`); None: the model's own choice (``hyperparameters["selection"]``,
        which a linear sampler sets, :data:`policies.pose_sampler.SELECTION`), else the
        lowest energy.
    anchor : bool, optional
        Whether the anchor is among the points (None: the model's choice, else yes).
    correct_output : bool
        Whether the reconstructor applies the model's learned output correction, when it has
        one (:attr:`output_correction`; True).
    """

    name = "learned"

    def __init__(
        self,
        model: Any,
        samples: int = 200,
        std_scale: float = 1.0,
        prior_weight: float | None = None,
        anchor: bool | None = None,
        correct_output: bool = True,
    ) -> None:
        super().__init__()
        if samples < 1:
            raise ValueError(f"samples: expected >= 1, got {samples}")
        if not std_scale >= 0:
            raise ValueError(f"std_scale: expected >= 0, got {std_scale}")
        self.model = model
        self.sampler = _sampler(model)
        self.samples = int(samples)
        self.std_scale = float(std_scale)
        # The model's own selection (a linear sampler sets one), unless given.
        chosen = dict(self.sampler.spec.hyperparameters.get("selection") or {})
        weight = chosen.get("prior_weight") if prior_weight is None else prior_weight
        if weight is not None and not float(weight) >= 0:
            raise ValueError(f"prior_weight: expected >= 0 or None, got {weight}")
        self.prior_weight = None if weight is None else float(weight)
        self.with_anchor = bool(chosen.get("anchor", True) if anchor is None else anchor)
        self.correct_output = bool(correct_output)

    @property
    def output_correction(self) -> Any:
        """The model's learned correction of the reconstructor's output
        (:mod:`fpg_gym.reconstruct.output_correction`), which the reconstructor applies after
        a frame this optimiser searched; None without one or with ``correct_output=False``."""
        if not self.correct_output:
            return None
        return getattr(self.sampler, "output_correction", None)

    def __deepcopy__(self, memo: dict[int, Any]) -> LearnedSampler:
        """A copy with its own search state that shares the model (read-only while searching):
        streams searched side by side (:func:`fpg_gym.reconstruct.search.make_optimizers`)
        need one optimiser each, not one network each, and a trained torch module holding
        tensors of its last backward pass cannot be deep-copied at all."""
        clone = copy.copy(self)
        memo[id(self)] = clone
        for name, value in self.__dict__.items():
            if name not in _SHARED:
                setattr(clone, name, copy.deepcopy(value, memo))
        return clone

    def params(self) -> dict[str, Any]:
        """Constructor parameters."""
        model = self.model if isinstance(self.model, str | os.PathLike) else "<sampler>"
        return {
            "model": str(model),
            "samples": self.samples,
            "std_scale": self.std_scale,
            "prior_weight": self.prior_weight,
            "anchor": self.with_anchor,
            "correct_output": self.correct_output,
        }

    def reset(self, problem: Any, rng: np.random.Generator) -> None:
        """Compute the frame's Gaussian (one forward pass)."""
        super().reset(problem, rng)
        self.mean, self.std, self.anchor = self.sampler.latent_gaussian(problem)
        self.best_z = self.mean.copy()
        self.best_energy = np.inf
        self.chosen: tuple[np.ndarray, float, float] | None = None  # (z, energy, score)
        self.drawn = False

    def _draws(self, count: int) -> np.ndarray:
        z = self.mean + self.std_scale * self.std * self.rng.standard_normal((count, self.dim))
        z[0] = self.mean
        if self.with_anchor and self.anchor is not None and count > 1:
            z[1] = self.anchor
        return z

    def ask(self) -> np.ndarray | None:
        """The mean, the anchor and draws (``samples`` in all), once; then None."""
        if self.drawn:
            return None
        self.drawn = True
        return self._draws(self.samples)

    def tell(self, z: np.ndarray, energies: np.ndarray) -> None:
        """Keep the lowest-energy point, and with a prior the point of highest posterior."""
        i = int(np.argmin(energies))
        if energies[i] < self.best_energy:
            self.best_energy = float(energies[i])
            self.best_z = np.array(z[i], dtype=np.float64)
        if self.prior_weight is not None:
            # -log posterior: E(z) + w |(z - mu) / sigma|^2 / 2 (the learned Gaussian as prior).
            spread = np.maximum(self.std_scale * self.std, 1e-12)
            scores = energies + 0.5 * self.prior_weight * (((z - self.mean) / spread) ** 2).sum(1)
            j = int(np.argmin(scores))
            if np.isfinite(scores[j]) and (self.chosen is None or scores[j] < self.chosen[2]):
                self.chosen = (np.array(z[j], dtype=np.float64), float(energies[j]), scores[j])

    def recommend(self) -> tuple[np.ndarray, float] | None:
        """With a prior weight, the evaluated point of highest posterior; else None (the
        lowest-energy point)."""
        return None if self.chosen is None else (self.chosen[0], self.chosen[1])


class LearnedSearch(LearnedSampler):
    """Learned candidates, then a short local search from the best (``learned+search:PATH``).

    Parameters
    ----------
    model : str, path or GaussianSampler
    samples : int
        Learned points (100).
    iterations : int
        Local-search batches after them (2).
    search_samples : int
        Points per local-search batch (50).
    step : float
        Initial local-search step (0.25 whitened units, as ``local-search``); halved after a
        batch without improvement.
    std_scale : float
        Multiplies the model's standard deviation (1).
    prior_weight, anchor, correct_output
        As :class:`LearnedSampler`; with a prior the search moves around the point of highest
        posterior, its steps in units of the learned spread.
    """

    name = "learned+search"

    def __init__(
        self,
        model: Any,
        samples: int = 100,
        iterations: int = 2,
        search_samples: int = 50,
        step: float = 0.25,
        std_scale: float = 1.0,
        prior_weight: float | None = None,
        anchor: bool | None = None,
        correct_output: bool = True,
    ) -> None:
        super().__init__(
            model,
            samples=samples,
            std_scale=std_scale,
            prior_weight=prior_weight,
            anchor=anchor,
            correct_output=correct_output,
        )
        if iterations < 0 or search_samples < 1:
            raise ValueError(
                f"iterations, search_samples: expected >= 0 and >= 1, got {iterations}, "
                f"{search_samples}"
            )
        if not step > 0:
            raise ValueError(f"step: expected > 0, got {step}")
        self.iterations = int(iterations)
        self.search_samples = int(search_samples)
        self.step = float(step)

    def params(self) -> dict[str, Any]:
        """Constructor parameters."""
        return {
            **super().params(),
            "iterations": self.iterations,
            "search_samples": self.search_samples,
            "step": self.step,
        }

    def reset(self, problem: Any, rng: np.random.Generator) -> None:
        """Compute the frame's Gaussian; the search starts after the learned batch."""
        super().reset(problem, rng)
        self.iteration = 0
        self.current_step = self.step

    def ask(self) -> np.ndarray | None:
        """The learned batch first, then ``search_samples`` points around the best."""
        if not self.drawn:
            return super().ask()
        if self.iteration >= self.iterations or not np.isfinite(self.best_energy):
            return None
        self.iteration += 1
        noise = self.rng.standard_normal((self.search_samples, self.dim))
        if self.chosen is None:
            return self.best_z + self.current_step * noise
        # With a prior: around the posterior's best, in units of the learned spread.
        spread = (self.current_step / self.step) * self.std_scale * self.std
        return self.chosen[0] + spread * noise

    def _progress(self) -> float:
        return self.best_energy if self.chosen is None else self.chosen[2]

    def tell(self, z: np.ndarray, energies: np.ndarray) -> None:
        """Move to the best point (of the posterior, with a prior); halve the step after a
        search batch without improvement."""
        before = self._progress()
        super().tell(z, energies)
        if self.iteration > 0 and not self._progress() < before:
            self.current_step *= 0.5


# The learned samplers register themselves as the parametrised optimisers learned:PATH and
# learned+search:PATH (pyproject's optimizers.plugins entry point imports this module on demand).
register_prefix("learned", LearnedSampler)
register_prefix("learned+search", LearnedSearch)

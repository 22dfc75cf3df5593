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

from policies.sampler.base import AnchorSampler, GaussianSampler
from policies.sampler.extra import INSTALL_HINT, import_learn
from policies.sampler.features import (
    ANCHORS,
    DEFAULT_FEATURES,
    FEATURE_SETS,
    LATENT_FEATURES,
    MASKED_CONTEXT,
    PAPER_WEIGHTS,
    FeatureMap,
    SamplerFeatures,
    problem_observation,
    quadratic_anchor,
)
from policies.sampler.spec import FORMAT, FORMAT_VERSION, KINDS, MAX_MODEL_VALUE, SamplerSpec
from policies.sampler.weights import (
    WEIGHTS_SUFFIX,
    check_layer_widths,
    check_model_values,
    load_weights_file,
    load_weights_into,
    model_paths,
)

__all__ = [
    "ANCHORS",
    "DEFAULT_FEATURES",
    "FEATURE_SETS",
    "FORMAT",
    "FORMAT_VERSION",
    "INSTALL_HINT",
    "KINDS",
    "LATENT_FEATURES",
    "MASKED_CONTEXT",
    "MAX_MODEL_VALUE",
    "PAPER_WEIGHTS",
    "WEIGHTS_SUFFIX",
    "AnchorSampler",
    "FeatureMap",
    "GaussianSampler",
    "SamplerFeatures",
    "SamplerSpec",
    "check_layer_widths",
    "check_model_values",
    "import_learn",
    "load_weights_file",
    "load_weights_into",
    "model_paths",
    "problem_observation",
    "quadratic_anchor",
]

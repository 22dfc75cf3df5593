"""``KinectPoseEnv``: Kinect pose reconstruction as a Gymnasium env (``fpg_gym/KinectPose-v0``).

See :mod:`fpg_gym.env` and :class:`KinectPoseEnv`.
"""

from __future__ import annotations

import math
import os
import time
from collections.abc import Mapping, Sequence
from typing import Any, SupportsFloat

import gymnasium as gym
import numpy as np
from gymnasium import spaces
from gymnasium.utils import EzPickle

from fpg_gym.core import skeleton
from fpg_gym.core.defaults import DEFAULT_HOLDOUT_CLIPS
from fpg_gym.env.ragdoll import CountingRagdollFactory, ragdoll_keywords
from fpg_gym.env.settings import RENDER_MODES, EnvSettings, energy_weights_of
from fpg_gym.env.step_errors import StepErrors
from fpg_gym.env.step_types import ExactAction, StageTimes
from fpg_gym.env_episodes import EpisodeSource
from fpg_gym.env_observation import ObservationLayout
from fpg_gym.graph import load_graph
from fpg_gym.io.clip import Clip
from fpg_gym.io.recording import Recording
from fpg_gym.reconstruct import (
    EnergyWeights,
    FrameRecord,
    Reconstructor,
    SearchProblem,
    TemporalConfig,
)
from fpg_gym.reconstruct.streams import Stream
from fpg_gym.rendering import HumanWindow, render_panels

__all__ = ["ENV_ID", "KinectPoseEnv"]

#: The registered id.
ENV_ID = "fpg_gym/KinectPose-v0"


class KinectPoseEnv(gym.Env[Any, np.ndarray], EzPickle):
    """Kinect pose reconstruction, one frame per step, over the graph-selected latent space.

    ## Description

    A Kinect skeleton stream is noisy, and occluded joints are guessed or lost. Shum et al.
    (2013) and the Filtered Pose Graph of Plantard, Shum & Multon (2016) reconstruct each frame
    from a database of clean poses: they rate each joint's reliability, select K = 30 database
    poses near the reliable joints (FPG: by walking a graph from the previous frame's poses),
    build a local PCA "natural posture space" of them, search that space for the pose with the
    lowest energy ``E = 1.0 Ec + 0.5 Es + 1.5 Ek + 0.25 Em`` (follow the reliable joints, stay
    near real poses, keep the bone lengths, move smoothly) and pass the result through a PD
    ragdoll. This environment exposes the search: one episode is one recording, one step is one
    frame, and the agent picks the frame's point in the natural posture space. An optimiser can
    be the agent too: the frame's search problem is ``env.unwrapped.problem``
    (:class:`~fpg_gym.reconstruct.SearchProblem`, with the energy as a vectorised function of
    latent points and an evaluation budget); :func:`fpg_gym.episodes.run_episode` runs an
    optimiser from the registry or a trained policy over a whole episode.

    ## Action Space

    ``Box(-1, 1, (latent_dim,), float32)``: a point of the frame's whitened latent space, in units
    of ``action_scale`` whitened standard deviations (3 by default). With ``action_mode="delta"``
    (default) the point is ``z = x0 + action_scale * action``, relative to ``x0``, the previous
    reconstruction projected into the new space (the best candidate on a stream's first frame),
    so the zero action is the no-search baseline; with ``"absolute"`` it is
    ``z = action_scale * action`` (the zero action is the candidates' mean). Delta is the default
    because ``x0`` usually lies far out in whitened units (median largest coordinate ~10, up to
    ~150 on the embedded episodes: the previous pose is rarely inside the new space) while the
    best point found by the paper's search is within ±4 of ``x0`` on 90 % of frames.
    A frame's space has ``d = min(latent_dim, K - 1)`` axes (fewer when fewer than K candidates
    are found); the action's entries beyond ``d`` are ignored. Out-of-bound entries are clipped
    to [-1, 1] (``info["action_clipped"]`` says so); ``clip_actions=False`` uses them as given,
    and so does an :class:`ExactAction` (``action_for(z, exact=True)``: the optimiser driver steps
    one, to reconstruct exactly from the point it found). Non-finite
    actions raise ``ValueError``.

    ## Observation Space

    ``Box(low, high, (N,), float32)`` with ``N = 344 + 65 L + K L + 2 K``: 2,304 values at the
    defaults (L = ``latent_dim`` = 20, K = ``k`` = 30); ``observation_mode="dict"`` gives
    the same parts as a ``Dict`` of flat Boxes. ``env.unwrapped.observation_layout`` maps each
    part's name to its slice and ``env.unwrapped.split_observation(obs)`` cuts a vector (or a
    batch) into named, reshaped parts. The parts (see :mod:`fpg_gym.env_observation` for the
    table with bounds): ``kinect`` (20, 3) the normalised sensor pose (m, root at the origin,
    facing +Z); ``reliability`` (20,) and ``reliability_terms`` (3, 20) (behaviour, kinematic,
    tracking); ``prediction`` (20, 3) the continuity prediction; ``previous`` (20, 3) the previous
    reconstruction; ``bone_lengths`` (19,); the latent space: ``latent_mean`` (20, 3),
    ``latent_basis`` (L, 60), ``latent_std`` (L,) in metres, ``latent_mask`` (L,); ``x0`` (L,) as
    ``x0 / action_scale``; ``z_kinect``, ``z_prediction`` (L,) and ``z_candidates`` (K, L): the
    actions that select the projections of the sensor pose, the prediction and each candidate;
    ``candidate_scores``, ``candidate_mask`` (K,); ``context`` (5,): first frame, no body, has
    prediction, dt in frames, episode progress. Values are finite and clipped to the bounds
    (poses ±4 m, latent coordinates ±10 action units); missing parts are zeros.

    ## Rewards

    ``reward_mode="energy"`` (default): ``-E``, the paper's energy of the chosen point (Shum
    Eq. 10; needs no ground truth). ``"error"``: ``-e``, the FPG Eq. 13 frame error (mean over the
    19 bones of the bone-vector distance, metres) of the output (after the ragdoll) against the
    ground truth. ``"combined"``: ``-(E + error_weight * e)`` (``error_weight`` 1.0: on the
    embedded episodes E is about 0.03 after the paper's search and 0.3 without, e about
    0.1-0.15 m). ``"smooth"``: ``-(e + smooth_weight * a)``, the error and the output's jitter:
    ``a`` is the mean over the joints of the output's acceleration (m/s²,
    :func:`fpg_gym.core.metrics.acceleration` of this output and the two before it; 0 on an
    episode's first two frames). ``smooth_weight`` 0.002 by default: a jitter of 10 m/s² (the
    papers' reconstruction of UI-PRMD's real streams shakes at 7-8 m/s²) then weighs as 2 cm of
    error. ``info`` holds the four negated
    weighted terms ``reward_control`` (``-w_c Ec``), ``reward_style`` (``-w_s Es``),
    ``reward_bone`` (``-w_k Ek``), ``reward_temporal`` (``-w_m Em``) and ``reward_prior``
    (``-w_p Ep``, 0 unless the latent prior is switched on), which sum to ``-E``; and
    ``energy``, and ``frame_error`` / ``raw_frame_error`` (of the sensor stream) when the episode
    has ground truth; and ``acceleration`` (``a`` above) in every mode. The error modes
    (``"error"``, ``"combined"``, ``"smooth"``) raise ``ValueError`` at construction
    (recordings) or reset (a recording given in ``options``) when an episode has no ground
    truth.

    ## Starting State

    ``reset`` picks an episode with ``np_random``: one of ``recordings`` uniformly, or a clip and
    a scenario uniformly and a seed, and simulates the Kinect stream of the clip through the
    episode planner (:mod:`fpg_gym.simulate.episodes`, whose one seeding rule turns the seed into
    the simulator's: ``walk/front-many/3`` is the stream ``fpg-gym compare`` simulates for that
    clip, scenario and seed). It starts a new stream (reliability, bone lengths and the
    graph walk start over, a fresh ragdoll), prepares frame 0 (full candidate search) and
    returns its observation. ``options`` may fix the episode: ``{"recording": index or name}``,
    or ``{"clip": name or index, "scenario": name, "seed": int}``, or (in any env)
    ``{"recording": Recording}`` to play that stream; the choices are drawn all the same, so the
    random stream does not depend on the options. Simulating costs about
    0.4 ms per frame the first time a clip is simulated in a scenario and 0.1 ms after (its ray
    casts are kept); with ``simulator_seeds=n`` the seed is drawn from ``range(n)`` and the
    simulated recordings are kept (at most clips x scenarios x n), so later resets are free.

    ## Episode End

    ``terminated`` once the last frame of the recording is reconstructed (the final observation
    repeats the last frame's: there is no next frame, and ``env.unwrapped.problem`` is None).
    ``truncated`` after ``max_episode_steps`` steps when set (the same rule as Gymnasium's
    ``TimeLimit``, which ``gym.make(..., max_episode_steps=n)`` adds instead).

    ## Arguments

    ``graph``: a pose graph file (``.npz`` from ``fpg-gym build-graph``), a
    :class:`~fpg_gym.graph.FilteredPoseGraph`, or None (or ``"default"``) for the embedded
    default (the DeepMimic clips less :data:`~fpg_gym.core.defaults.DEFAULT_HOLDOUT_CLIPS`, built
    once and cached, see ``cache_dir``; :func:`fpg_gym.graph.load_graph`). Episodes:
    ``recordings`` (paths in any Kinect format or :class:`~fpg_gym.io.Recording` objects) or
    ``clips`` (embedded clip names or :class:`~fpg_gym.io.Clip` objects; default the held-out
    clips walk, punch, kick, dance_b) and ``scenarios`` (simulator scenarios; default
    front-many, left45-many, right45-many).
    ``selector`` ``"graph"`` (FPG) or ``"brute-force"`` (Shum); ``k`` = 30 candidates;
    ``latent_dim`` = 20; ``energy_weights`` (an ``EnergyWeights``, a mapping or 4 numbers; 1.0,
    0.5, 1.5, 0.25); ``reward_mode``, ``error_weight``, ``smooth_weight``; ``action_mode``,
    ``action_scale``, ``clip_actions``; ``observation_mode`` ``"vector"`` or ``"dict"``;
    ``ragdoll`` (True, False, or a mapping of :class:`~fpg_gym.physics.ragdoll.Ragdoll`
    keyword arguments); ``max_episode_steps``;
    ``simulator_seeds`` (None: any episode seed; n: seeds 0..n-1, simulated streams cached);
    ``max_evaluations`` (energy evaluations an optimiser may spend per frame, 2,000);
    ``render_mode`` ``"rgb_array"`` or ``"human"``; ``cache_dir`` for the default graph;
    ``reconstructor_options`` (other :class:`~fpg_gym.reconstruct.ReconstructorConfig` fields).
    The scalar settings, checked, are ``env.settings`` (:class:`~fpg_gym.env.settings.EnvSettings`)
    and attributes of the same names (``env.reward_mode``, ``env.action_scale``, ...).

    ## Version History

    * v0: initial version.

    Notes
    -----
    Pickling (and ``copy.deepcopy``) re-creates the env from its constructor arguments
    (:class:`gymnasium.utils.EzPickle`): a pybullet client cannot be pickled, so the episode
    state is not carried over and the copy must be reset. Same seed, same actions: same
    observations, rewards and infos (``info["timings"]`` aside).
    """

    metadata = {"render_modes": list(RENDER_MODES), "render_fps": 30}  # noqa: RUF012
    _stream: Stream | None = None  # the episode's frames through the reconstructor (reset)

    def __init__(
        self,
        graph: str | os.PathLike[str] | Any | None = None,
        *,
        recordings: Sequence[str | os.PathLike[str] | Recording] | None = None,
        clips: Sequence[str | Clip] | None = None,
        scenarios: Sequence[Any] | None = None,
        selector: str = "graph",
        k: int = 30,
        latent_dim: int = 20,
        energy_weights: EnergyWeights | Mapping[str, float] | Sequence[float] | None = None,
        reward_mode: str = "energy",
        error_weight: float = 1.0,
        smooth_weight: float = 0.002,
        action_mode: str = "delta",
        action_scale: float = 3.0,
        clip_actions: bool = True,
        observation_mode: str = "vector",
        ragdoll: bool | Mapping[str, Any] = True,
        max_episode_steps: int | None = None,
        simulator_seeds: int | None = None,
        max_evaluations: int | None = 2000,
        render_mode: str | None = None,
        cache_dir: str | os.PathLike[str] | None = None,
        reconstructor_options: Mapping[str, Any] | None = None,
    ) -> None:
        # Pickling re-creates the env from its arguments as given (EzPickle): __init__'s locals.
        EzPickle.__init__(
            self, graph, **{k: v for k, v in locals().items() if k not in ("self", "graph")}
        )
        settings = EnvSettings(
            reward_mode=reward_mode,
            error_weight=error_weight,
            smooth_weight=smooth_weight,
            action_mode=action_mode,
            action_scale=action_scale,
            clip_actions=clip_actions,
            observation_mode=observation_mode,
            latent_dim=latent_dim,
            max_episode_steps=max_episode_steps,
            simulator_seeds=simulator_seeds,
            render_mode=render_mode,
        )
        if recordings is not None and clips is not None:
            raise ValueError("give either recordings= or clips= (with scenarios=), not both")
        if recordings is not None and scenarios is not None:
            raise ValueError("scenarios= applies to clips=, not to recordings=")
        self.settings = settings
        self.render_mode = settings.render_mode
        self.reward_mode = settings.reward_mode
        self.error_weight = settings.error_weight
        self.smooth_weight = settings.smooth_weight
        self.action_mode = settings.action_mode
        self.action_scale = settings.action_scale
        self.clip_actions = settings.clip_actions
        self.observation_mode = settings.observation_mode
        self.max_episode_steps = settings.max_episode_steps
        self.simulator_seeds = settings.simulator_seeds
        self.latent_dim = settings.latent_dim
        self.weights = energy_weights_of(energy_weights)
        self._needs_truth = reward_mode != "energy"

        # Episode source.
        self.episodes = EpisodeSource(
            recordings=recordings,
            clips=clips,
            scenarios=scenarios,
            simulator_seeds=self.simulator_seeds,
            needs_truth=self._needs_truth,
            reward_mode=reward_mode,
        )

        # Reconstruction core.
        self.graph = load_graph(graph, exclude=DEFAULT_HOLDOUT_CLIPS, cache_dir=cache_dir)
        self._counts = {"ragdoll_resets": 0, "ragdoll_divergences": 0, "ragdoll_builds": 0}
        self._ragdoll_kwargs = ragdoll_keywords(ragdoll)
        self.reconstructor = self._make_reconstructor(
            selector, int(k), max_evaluations, reconstructor_options
        )
        self.candidates = self.reconstructor.k
        self.layout = ObservationLayout(self.latent_dim, self.candidates)

        # Spaces.
        self.action_space = spaces.Box(-1.0, 1.0, (self.latent_dim,), dtype=np.float32)
        self.observation_space = self._observation_space(observation_mode)

        # Episode state.
        self._recording: Recording | None = None
        self._episode: dict[str, Any] = {}
        self._problem: SearchProblem | None = None
        self._elapsed = 0
        self._last_obs: np.ndarray | None = None
        # The step's errors against the episode's truth (the outputs are the stream's).
        self._errors = StepErrors()
        self._render_centre: np.ndarray | None = None
        self._window: HumanWindow | None = None
        self._prepare_ms = self._observation_ms = 0.0

    # ------------------------------------------------------------------ construction helpers

    def _make_reconstructor(
        self,
        selector: str,
        k: int,
        max_evaluations: int | None,
        reconstructor_options: Mapping[str, Any] | None,
    ) -> Reconstructor:
        """The env's reconstructor: its own arguments, then ``reconstructor_options``."""
        overrides: dict[str, Any] = dict(reconstructor_options or {})
        explicit: dict[str, Any] = {
            "selector": selector,
            "k": k,
            "latent_dim": self.latent_dim,
            "weights": self.weights,
            "max_evaluations": max_evaluations,
        }
        clash = sorted(set(overrides) & set(explicit))
        if clash:
            raise ValueError(
                f"reconstructor_options: {clash} are arguments of the env itself; pass them "
                "as keyword arguments"
            )
        # The per-frame problem keeps the papers' energy and frame (the reward's meaning; see
        # fpg_gym.reconstruct.temporal); reconstructor_options={"temporal": ...} overrides it.
        overrides.setdefault("temporal", TemporalConfig.off())
        return Reconstructor(
            self.graph,
            ragdoll=(
                None
                if self._ragdoll_kwargs is None
                else CountingRagdollFactory(self._ragdoll_kwargs, self._counts)
            ),
            **explicit,
            **overrides,
        )

    def _observation_space(self, observation_mode: str) -> spaces.Space[Any]:
        """A ``Box`` of :attr:`layout` (``"vector"``) or a ``Dict`` of its parts."""
        if observation_mode == "vector":
            return spaces.Box(self.layout.low, self.layout.high, dtype=np.float32)
        return spaces.Dict(
            {
                name: spaces.Box(self.layout.low[sl], self.layout.high[sl], dtype=np.float32)
                for name, sl in self.layout.slices.items()
            }
        )

    # ------------------------------------------------------------------ public state

    @property
    def problem(self) -> SearchProblem | None:
        """The current frame's :class:`~fpg_gym.reconstruct.SearchProblem` (None after the
        episode's last step or before ``reset``).

        An optimiser may search it (``env.unwrapped.reconstructor.search(optimizer, rng)``, within
        the env's ``max_evaluations``) and step with the action of the point it found
        (:meth:`action_for`).
        """
        return self._problem

    @property
    def ragdoll_enabled(self) -> bool:
        """Whether reconstructions go through the PD ragdoll (the ``ragdoll`` argument)."""
        return self._ragdoll_kwargs is not None

    @property
    def recording(self) -> Recording | None:
        """The current episode's recording (None before ``reset``)."""
        return self._recording

    @property
    def stream(self) -> Stream | None:
        """The current episode's frames through the reconstructor
        (:class:`~fpg_gym.reconstruct.streams.Stream`: ``result()`` gives the poses and records
        of the steps so far; None before ``reset``)."""
        return self._stream

    @property
    def episode(self) -> dict[str, Any]:
        """The current episode: ``recording`` (name), ``clip``, ``scenario``, ``seed``,
        ``num_frames``, ``has_ground_truth`` (a copy)."""
        return dict(self._episode)

    @property
    def episode_names(self) -> list[str]:
        """Names of the recordings (or clips) episodes are drawn from."""
        return self.episodes.names

    @property
    def scenario_names(self) -> list[str]:
        """Names of the scenarios episodes are simulated in (empty with ``recordings``)."""
        return self.episodes.scenario_names

    @property
    def frame(self) -> int:
        """Index of the frame the next step reconstructs."""
        return 0 if self._stream is None else self._stream.next

    @property
    def observation_layout(self) -> dict[str, slice]:
        """Part name -> its slice of the observation vector (see :mod:`fpg_gym.env_observation`)."""
        return dict(self.layout.slices)

    def split_observation(self, observation: Any) -> dict[str, np.ndarray]:
        """Named, reshaped parts of an observation vector or a batch ``(..., N)`` (or of a
        ``"dict"`` observation)."""
        if isinstance(observation, Mapping):
            return {
                name: np.asarray(observation[name]).reshape(
                    *np.shape(observation[name])[:-1], *self.layout.shapes[name]
                )
                for name in self.layout.slices
            }
        return self.layout.split(observation)

    def action_for(
        self, z: np.ndarray, problem: SearchProblem | None = None, *, exact: bool = False
    ) -> np.ndarray:
        """The action that selects latent point ``z`` ``(d,)`` of ``problem`` (the current one).

        Returns a float64 ``(latent_dim,)`` array, zero-padded, *not* clipped: entries beyond
        ±1 are clipped by :meth:`step` unless ``clip_actions`` is False. With ``exact=True`` it
        is an :class:`ExactAction`, which :meth:`step` never clips, so that it reconstructs from
        exactly ``z`` (the optimiser driver :func:`fpg_gym.episodes.run_episode` does this).
        """
        problem = problem or self._require_problem("action_for")
        z = np.asarray(z, dtype=np.float64).reshape(-1)
        if z.shape != (problem.dim,):
            raise ValueError(f"z: expected shape ({problem.dim},), got {z.shape}")
        action = np.zeros(self.latent_dim)
        d = min(problem.dim, self.latent_dim)
        origin = problem.x0[:d] if self.action_mode == "delta" else 0.0
        action[:d] = (z[:d] - origin) / self.action_scale
        return ExactAction(action) if exact else action

    def latent_point(self, action: np.ndarray, problem: SearchProblem | None = None) -> np.ndarray:
        """The latent point ``(d,)`` that ``action`` selects in ``problem`` (the current one),
        after clipping when ``clip_actions`` is set."""
        problem = problem or self._require_problem("latent_point")
        return self._latent_point(action, problem)[0]

    def _require_problem(self, what: str) -> SearchProblem:
        if self._problem is None:
            raise RuntimeError(f"{what}: no frame is waiting (call reset, or the episode is over)")
        return self._problem

    def _latent_point(self, action: Any, problem: SearchProblem) -> tuple[np.ndarray, bool]:
        exact = isinstance(action, ExactAction)
        a = np.asarray(action, dtype=np.float64)
        if a.size != self.latent_dim:
            raise ValueError(f"action: expected shape ({self.latent_dim},), got {np.shape(action)}")
        a = a.reshape(self.latent_dim)
        peak = float(np.abs(a).max())  # NaN when an entry is NaN, inf when one is inf
        if not math.isfinite(peak):
            raise ValueError("action: NaN or inf value")
        clipped = peak > 1.0
        if clipped and self.clip_actions and not exact:
            a = np.clip(a, -1.0, 1.0)
        d = min(problem.dim, self.latent_dim)
        z = problem.x0.copy() if self.action_mode == "delta" else np.zeros(problem.dim)
        z[:d] += self.action_scale * a[:d]
        return z, clipped

    # ------------------------------------------------------------------ gymnasium API

    def reset(
        self, *, seed: int | None = None, options: dict[str, Any] | None = None
    ) -> tuple[Any, dict[str, Any]]:
        """Start an episode (see *Starting State*); returns ``(observation, info)``.

        ``info``: the episode (``recording``, ``clip``, ``scenario``, ``seed``, ``num_frames``,
        ``has_ground_truth``) and frame 0's ``frame``, ``reliability``, ``nodes``,
        ``full_search``, ``recovered``.
        """
        super().reset(seed=seed)
        recording, episode = self.episodes.draw(self.np_random, dict(options or {}))
        self._recording = recording
        self._episode = episode
        for key in self._counts:
            self._counts[key] = 0
        self._elapsed = 0
        self._errors.reset(recording)
        root = recording.positions[:, skeleton.ROOT]
        self._render_centre = np.array([np.median(root[:, 0]), np.median(root[:, 1])])
        # Reconstructor.reset() starts a stream that does not depend on earlier episodes (same
        # seed, same episode): fresh ragdoll physics and no cached retargeted database.
        self.reconstructor.reset()
        self._stream = Stream(self.reconstructor, recording)
        obs_vector = self._prepare()
        info: dict[str, Any] = dict(episode)
        info.update(self._frame_info())
        if self.render_mode == "human":
            self.render()
        return self._observation(obs_vector), info

    def step(self, action: Any) -> tuple[Any, SupportsFloat, bool, bool, dict[str, Any]]:
        """Reconstruct the waiting frame from ``action`` and prepare the next one.

        Returns ``(observation, reward, terminated, truncated, info)``; see *Rewards* for
        ``info``'s energy terms and errors. ``info`` also holds ``pose`` (20, 3) the
        reconstruction in the recording's camera space, ``frame``, ``timestamp``,
        ``energy_x0``, ``reliability`` (20,), ``nodes`` (K,) (-1 padded), ``recovered``,
        ``full_search``, ``first``, ``no_body``, ``labelling``, ``evaluations`` (energy
        evaluations the agent spent on ``problem``), ``action_clipped``, ``ragdoll_resets``,
        ``ragdoll_divergences``, ``ragdoll_builds`` (counts in this step), ``acceleration`` (the
        output's mean joint acceleration over this and the two previous outputs, m/s²; 0 before)
        and ``timings``
        (:class:`StageTimes`, ms: the frame's ``normalise`` ... ``ragdoll`` stages and ``total``,
        whose ``search`` is the agent's time between the observation and this call; then this
        step's ``prepare_next`` (the next frame's normalise ... latent), ``observation`` and
        ``env_step``, the whole call).

        Raises
        ------
        RuntimeError
            If no frame is waiting (before ``reset`` or after the episode's last step).
        ValueError
            On an action of the wrong size or with NaN/inf.
        """
        start = time.perf_counter()
        problem = self._require_problem("step")
        recording = self._recording
        assert recording is not None
        z, clipped = self._latent_point(action, problem)
        stream = self._stream
        assert stream is not None
        t = stream.next
        pose, record = stream.finish(z)
        if record.ragdoll:
            self._counts["ragdoll_divergences"] += int(record.ragdoll.get("new_divergences", 0))

        w = problem.weights
        terms = record.terms
        info: dict[str, Any] = {
            "frame": t,
            "timestamp": float(record.timestamp),
            "pose": pose.copy(),
            "energy": float(record.energy),
            "energy_x0": float(record.energy_x0),
            "reward_control": -w.control * terms["Ec"],
            "reward_style": -w.style * terms["Es"],
            "reward_bone": -w.kinematic * terms["Ek"],
            "reward_temporal": -w.motion * terms["Em"],
            "reward_prior": -w.prior * terms["Ep"],
        }
        reward = self._reward(record, info)
        info.update(
            {
                **self._candidate_info(record.reliability, record.nodes),
                "recovered": bool(record.recovered),
                "full_search": bool(record.full_search),
                "first": bool(record.first),
                "no_body": bool(record.no_body),
                "labelling": str(record.labelling),
                "evaluations": int(record.evaluations),
                "action_clipped": clipped,
            }
        )
        info.update(self._counts)
        for key in self._counts:
            self._counts[key] = 0

        self._elapsed += 1
        terminated = stream.done
        self._prepare_ms = self._observation_ms = 0.0
        if terminated:
            self._problem = None
            assert self._last_obs is not None
            obs_vector = self._last_obs.copy()
        else:
            obs_vector = self._prepare()
        timings = dict(record.ms)
        timings["prepare_next"] = self._prepare_ms
        timings["observation"] = self._observation_ms
        timings["env_step"] = 1e3 * (time.perf_counter() - start)
        info["timings"] = StageTimes(timings)
        truncated = self.max_episode_steps is not None and self._elapsed >= self.max_episode_steps
        if self.render_mode == "human":
            self.render()
        return self._observation(obs_vector), reward, terminated, bool(truncated), info

    def _reward(self, record: FrameRecord, info: dict[str, Any]) -> float:
        """The step's reward (*Rewards*); puts ``frame_error`` and ``raw_frame_error`` (with
        ground truth) and ``acceleration`` of the frame just finished into ``info``."""
        assert self._stream is not None
        info.update(self._errors.output(self._stream))
        if self.reward_mode == "energy":
            reward = -float(record.energy)
        elif self.reward_mode == "error":
            reward = -info["frame_error"]
        elif self.reward_mode == "smooth":
            reward = -(info["frame_error"] + self.smooth_weight * info["acceleration"])
        else:
            reward = -(float(record.energy) + self.error_weight * info["frame_error"])
        return reward

    def render(self) -> np.ndarray | None:
        """``rgb_array``: a ``(320, 640, 3)`` uint8 image, the Kinect input (joints coloured by
        tracking state: green tracked, orange inferred, red not tracked) and the reconstruction
        side by side, as the sensor sees them, with the ground truth in light grey when known.
        ``human``: the same image in a matplotlib window (a warning and nothing shown when there
        is no display)."""
        if self.render_mode is None:
            gym.logger.warn(
                "You are calling render method without specifying any render mode. "
                "You can specify the render_mode at initialization, "
                f'e.g. gym.make("{ENV_ID}", render_mode="rgb_array")'
            )
            return None
        frame = self._render_frame()
        if self.render_mode == "rgb_array":
            return frame
        if self._window is None:
            self._window = HumanWindow(self.metadata["render_fps"])
        self._window.show(frame)
        return None

    def close(self) -> None:
        """Release the ragdoll's pybullet client and the render window (idempotent)."""
        reconstructor = getattr(self, "reconstructor", None)
        if reconstructor is not None:
            reconstructor.close()
        episodes = getattr(self, "episodes", None)
        if episodes is not None:
            episodes.close()
        if self._window is not None:
            self._window.close()

    # ------------------------------------------------------------------ frames

    def _prepare(self) -> np.ndarray:
        """Prepare the stream's next frame; returns (and keeps) its observation vector."""
        recording, stream = self._recording, self._stream
        assert recording is not None and stream is not None
        t = stream.next
        t0 = time.perf_counter()
        problem = stream.prepare()
        self._problem = problem
        t1 = time.perf_counter()
        obs = self.layout.build(
            problem,
            action_scale=self.action_scale,
            delta=self.action_mode == "delta",
            no_body=stream.no_body[t],
            progress=t / recording.num_frames,
            frame_dt=self.reconstructor.config.frame_dt,
        )
        self._last_obs = obs
        self._prepare_ms = 1e3 * (t1 - t0)
        self._observation_ms = 1e3 * (time.perf_counter() - t1)
        return obs

    def _candidate_info(self, reliability: np.ndarray, nodes: np.ndarray) -> dict[str, Any]:
        """``info``'s ``reliability`` (20,) float32 and ``nodes`` (K,) (-1 padded)."""
        padded = np.full(self.candidates, -1, dtype=np.int64)
        padded[: len(nodes)] = nodes[: self.candidates]
        return {"reliability": np.asarray(reliability, dtype=np.float32), "nodes": padded}

    def _frame_info(self) -> dict[str, Any]:
        problem = self._require_problem("info")
        return {
            "frame": self.frame,
            **self._candidate_info(problem.reliability, problem.nodes),
            "full_search": bool(problem.selection.full_search),
            "recovered": bool(problem.selection.recovered),
        }

    def _observation(self, vector: np.ndarray) -> Any:
        if self.observation_mode == "dict":
            return self.layout.to_dict(vector)
        return vector.copy()

    # ------------------------------------------------------------------ rendering

    def _render_frame(self) -> np.ndarray:
        recording = self._recording
        if recording is None:
            return render_panels(None, None, None, None)
        stream = self._stream
        done = 0 if stream is None else stream.next
        last = stream.poses[done - 1] if stream is not None and done > 0 else None
        shown = done - 1 if last is not None else done
        shown = min(max(shown, 0), recording.num_frames - 1)
        name = self._episode.get("recording", "")
        return render_panels(
            recording.positions[shown],
            recording.states[shown],
            last,
            None if recording.ground_truth is None else recording.ground_truth[shown],
            centre=self._render_centre,
            caption=f"{name}  frame {shown + 1}/{recording.num_frames}",
        )

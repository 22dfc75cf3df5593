"""Run whole episodes of :class:`~fpg_gym.env.KinectPoseEnv` with an optimiser or a policy.

:func:`run_episode` drives one episode with any of three kinds of agent:

* an **optimiser** — a registered name (``optimizers.available()``: ``"local-search"``,
  ``"random-search"``, ``"cma-es"``, ``"none"``, ...) or an object with ``reset/ask/tell``: on
  every frame it searches ``env.unwrapped.problem`` within the problem's evaluation budget
  (:func:`optimizers.run_optimizer`) and the env steps with the action of the best point found
  (exactly that point: an :class:`~fpg_gym.env.ExactAction`, which the env does not clip; the
  env's ``clip_actions`` is left as it is);
* a **policy** — anything with ``predict(obs, deterministic=True) -> (action, state)``, as
  stable-baselines3 models have;
* a **callable** ``obs -> action`` (e.g. ``lambda obs: env.action_space.sample()``);
* a **method name** (:mod:`fpg_gym.methods`): ``fpg:OPTIMIZER`` / ``shum:OPTIMIZER`` run that
  optimiser (the env's selector and ragdoll setting must match the name), and the reference
  filters ``raw``, ``holt[:PRESET]``, ``kalman[:PRESET]``, ``one-euro[:PRESET]`` (optionally
  ``+map``, through the env reconstructor's definition maps, and ``+ragdoll``) run on the
  episode's recording after the reset, without stepping the env (their rewards and energies are
  NaN; frame errors are measured when the recording has ground truth).

:func:`measure_env_throughput` times the env itself (random actions, no search), for
``fpg-gym bench``.

Examples
--------
>>> import gymnasium as gym, fpg_gym                                           # doctest: +SKIP
>>> from fpg_gym.episodes import run_episode
>>> env = gym.make("fpg_gym/KinectPose-v0", reward_mode="error")               # doctest: +SKIP
>>> result = run_episode(env, "local-search", seed=0)                          # doctest: +SKIP
>>> result.summary()["mean_error"]                                             # doctest: +SKIP
0.09...
"""

from __future__ import annotations

import time
from collections.abc import Callable, Mapping
from dataclasses import dataclass, field
from typing import Any

import numpy as np
from tqdm import tqdm

import optimizers
from fpg_gym.core import metrics
from fpg_gym.core.seeding import as_generator
from fpg_gym.env import KinectPoseEnv
from fpg_gym.methods import METHOD_BASES, MethodRunner, parse_method
from fpg_gym.reconstruct import ReconstructionResult

__all__ = ["EpisodeResult", "measure_env_throughput", "run_episode"]


@dataclass
class EpisodeResult:
    """One episode, frame by frame: the reconstructed stream and how it scored.

    Attributes
    ----------
    name : str
        The episode (``info["recording"]`` at reset: a recording name, or clip/scenario/seed).
    agent : str
        What acted (the optimiser's name, or the policy's class name).
    reconstruction : ReconstructionResult
        The episode's stream: poses (in the recording's camera space) and per-frame records
        (none for a filter).
    rewards : ndarray, shape (T,)
    frame_errors, raw_frame_errors : ndarray, shape (T,), or None
        FPG Eq. 13 per frame of the reconstruction and of the sensor stream (ground truth only).
    agent_ms, step_ms : ndarray, shape (T,)
        Milliseconds the agent took to choose the action, and ``env.step`` took.
    terminated, truncated : bool
        How the episode ended (both False if ``max_steps`` stopped it).
    reset_info : dict
    infos : list of dict
        Every step's ``info`` (only with ``keep_infos=True``).
    """

    name: str
    agent: str
    reconstruction: ReconstructionResult
    rewards: np.ndarray
    frame_errors: np.ndarray | None
    raw_frame_errors: np.ndarray | None
    agent_ms: np.ndarray
    step_ms: np.ndarray
    terminated: bool
    truncated: bool
    reset_info: dict[str, Any] = field(default_factory=dict)
    infos: list[dict[str, Any]] = field(default_factory=list)

    @property
    def poses(self) -> np.ndarray:
        """The reconstructions ``(T, 20, 3)`` float32, in the recording's camera space."""
        return self.reconstruction.poses

    @property
    def energies(self) -> np.ndarray:
        """Energy of each frame's output ``(T,)`` (NaN for a filter)."""
        energy = self.reconstruction.energy
        return np.full(self.steps, np.nan) if energy is None else energy

    @property
    def evaluations(self) -> np.ndarray:
        """Energy evaluations spent per frame ``(T,)`` int (0 for a filter)."""
        evaluations = self.reconstruction.evaluations
        if evaluations is None:
            return np.zeros(self.steps, dtype=np.int64)
        return evaluations.astype(np.int64)

    @property
    def steps(self) -> int:
        """Frames reconstructed."""
        return len(self.rewards)

    @property
    def total_reward(self) -> float:
        """Sum of the rewards."""
        return float(np.sum(self.rewards))

    def summary(self) -> dict[str, Any]:
        """Scalars for reports: steps, total reward, mean energy, mean error and Err0.2 (of the
        reconstruction and of the raw stream, None without ground truth), evaluations per frame,
        milliseconds per frame (agent + step) and frames per second."""
        frame_ms = self.agent_ms + self.step_ms
        out: dict[str, Any] = {
            "name": self.name,
            "agent": self.agent,
            "steps": self.steps,
            "total_reward": self.total_reward,
            "mean_energy": float(np.mean(self.energies)) if self.steps else None,
            "mean_error": None,
            "err02": None,
            "raw_mean_error": None,
            "raw_err02": None,
            "evaluations_per_frame": float(np.mean(self.evaluations)) if self.steps else 0.0,
            "ms_per_frame": float(np.mean(frame_ms)) if self.steps else None,
            "frames_per_second": (
                float(1e3 * self.steps / np.sum(frame_ms))
                if self.steps and np.sum(frame_ms) > 0
                else None
            ),
            "terminated": self.terminated,
            "truncated": self.truncated,
        }
        for prefix, errors in (("", self.frame_errors), ("raw_", self.raw_frame_errors)):
            if errors is not None and len(errors):
                out[f"{prefix}mean_error"] = float(np.mean(errors))
                out[f"{prefix}err02"] = metrics.err_ratio(errors)
        return out


def _method_agent(name: str, base: Any) -> tuple[str, Any, str] | None:
    """``("filter", Method, label)`` or ``("optimizer", optimiser, label)`` for a method name
    (None when ``name`` is not one)."""

    head = name.partition("+")[0].partition(":")[0].strip().lower()
    if head not in METHOD_BASES:
        return None
    method = parse_method(name)
    if method.is_filter:
        return "filter", method, method.name
    selector = getattr(getattr(base, "reconstructor", None), "config", None)
    selector = getattr(selector, "selector", method.selector)
    if selector != method.selector:
        raise ValueError(
            f"agent {name!r} needs selector {method.selector!r} but the env uses {selector!r}; "
            f"create the env with selector={method.selector!r}"
        )
    if bool(getattr(base, "ragdoll_enabled", method.ragdoll)) != method.ragdoll:
        raise ValueError(
            f"agent {name!r}: the env's ragdoll setting differs; create the env with "
            f"ragdoll={method.ragdoll}"
        )
    assert method.optimizer is not None
    return "optimizer", optimizers.make(method.optimizer), method.name


def _agent_kind(agent: Any, base: Any = None) -> tuple[str, Any, str]:
    """``("optimizer" | "filter" | "policy" | "callable", object, label)``."""

    if isinstance(agent, str):
        as_method = _method_agent(agent, base)
        if as_method is not None:
            return as_method
        return "optimizer", optimizers.make(agent), agent
    if hasattr(agent, "predict"):
        return "policy", agent, type(agent).__name__
    if all(callable(getattr(agent, m, None)) for m in ("reset", "ask", "tell")):
        return "optimizer", agent, str(getattr(agent, "name", type(agent).__name__))
    if callable(agent):
        return "callable", agent, str(getattr(agent, "__name__", type(agent).__name__))
    raise TypeError(
        "agent: expected an optimiser name or object (reset/ask/tell), a policy with "
        f"predict(obs, deterministic=...), or a callable obs -> action; got {type(agent).__name__}"
    )


def run_episode(
    env: Any,
    agent: Any,
    *,
    seed: int | None = None,
    options: Mapping[str, Any] | None = None,
    rng: np.random.Generator | int | None = None,
    deterministic: bool = True,
    max_steps: int | None = None,
    keep_infos: bool = False,
    progress: bool = False,
) -> EpisodeResult:
    """Reset ``env`` and run one episode with ``agent`` (see the module docstring).

    Parameters
    ----------
    env : gymnasium.Env
        A :class:`~fpg_gym.env.KinectPoseEnv`, possibly wrapped (``gym.make``); wrappers see
        every step.
    agent : str, optimiser, policy or callable
    seed : int, optional
        Passed to ``env.reset``; also seeds the optimiser when ``rng`` is None.
    options : mapping, optional
        Passed to ``env.reset`` (e.g. ``{"clip": "walk", "scenario": "front-many"}``).
    rng : numpy.random.Generator or int, optional
        The optimiser's randomness (default: a generator seeded with ``seed``).
    deterministic : bool
        Passed to a policy's ``predict``.
    max_steps : int, optional
        Stop after this many steps.
    keep_infos : bool
        Keep every step's ``info`` in :attr:`EpisodeResult.infos`.
    progress : bool
        Show a tqdm progress bar.

    Returns
    -------
    EpisodeResult

    Raises
    ------
    TypeError
        If ``agent`` is none of the accepted kinds.
    optimizers.OptimizerNotFound
        If ``agent`` names no registered optimiser.
    """

    base: Any = env.unwrapped
    kind, actor, label = _agent_kind(agent, base)
    generator = as_generator(seed if rng is None else rng)
    obs, reset_info = env.reset(seed=seed, options=dict(options) if options else None)
    total = int(reset_info.get("num_frames", 0)) or None
    if max_steps is not None:
        total = max_steps if total is None else min(total, max_steps)
    if kind == "filter":
        config = getattr(getattr(base, "reconstructor", None), "config", None)
        return _run_filter_episode(base.recording, actor, label, total, reset_info, config)
    bar = None
    if progress:
        bar = tqdm(total=total, unit="frame", desc=f"episode ({label})", leave=False)
    steps = _Steps()
    terminated = truncated = False
    try:
        while max_steps is None or len(steps.rewards) < max_steps:
            t0 = time.perf_counter()
            action = _action(kind, actor, base, obs, generator, deterministic)
            t1 = time.perf_counter()
            obs, reward, terminated, truncated, info = env.step(action)
            t2 = time.perf_counter()
            steps.add(info, float(reward), 1e3 * (t1 - t0), 1e3 * (t2 - t1), keep_infos)
            if bar is not None:
                bar.update(1)
            if terminated or truncated:
                break
    finally:
        if bar is not None:
            bar.close()
    stream = base.stream  # the episode's frames through the reconstructor
    return steps.result(
        str(reset_info.get("recording", "")),
        label,
        stream.result(),
        terminated,
        truncated,
        reset_info,
    )


@dataclass
class _Steps:
    """What :func:`run_episode` keeps of each step."""

    rewards: list[float] = field(default_factory=list)
    errors: list[float] = field(default_factory=list)
    raw_errors: list[float] = field(default_factory=list)
    agent_ms: list[float] = field(default_factory=list)
    step_ms: list[float] = field(default_factory=list)
    infos: list[dict[str, Any]] = field(default_factory=list)

    def add(
        self, info: dict[str, Any], reward: float, agent_ms: float, step_ms: float, keep: bool
    ) -> None:
        """One step's ``info`` and reward, the agent's and the step's milliseconds."""
        self.rewards.append(reward)
        if "frame_error" in info:
            self.errors.append(info["frame_error"])
            self.raw_errors.append(info["raw_frame_error"])
        self.agent_ms.append(agent_ms)
        self.step_ms.append(step_ms)
        if keep:
            self.infos.append(info)

    def result(
        self,
        name: str,
        agent: str,
        reconstruction: ReconstructionResult,
        terminated: bool,
        truncated: bool,
        reset_info: dict[str, Any],
    ) -> EpisodeResult:
        """The episode's :class:`EpisodeResult` (``reconstruction``: its stream's)."""
        count = len(self.rewards)
        errors, raw_errors = self.errors, self.raw_errors
        return EpisodeResult(
            name=name,
            agent=agent,
            reconstruction=reconstruction,
            rewards=np.asarray(self.rewards, dtype=np.float64),
            frame_errors=np.asarray(errors) if len(errors) == count and count else None,
            raw_frame_errors=(
                np.asarray(raw_errors) if len(raw_errors) == count and count else None
            ),
            agent_ms=np.asarray(self.agent_ms),
            step_ms=np.asarray(self.step_ms),
            terminated=bool(terminated),
            truncated=bool(truncated),
            reset_info=reset_info,
            infos=self.infos,
        )


def _action(
    kind: str,
    actor: Any,
    base: Any,
    obs: Any,
    generator: np.random.Generator,
    deterministic: bool,
) -> Any:
    """The agent's action on the waiting frame: an optimiser's search result as an
    :class:`~fpg_gym.env.ExactAction` (the env steps exactly that point, even outside the
    action box), a policy's prediction, or a callable's answer."""
    if kind == "optimizer":
        problem = base.problem
        z = base.reconstructor.search(actor, generator).x
        return base.action_for(z, problem, exact=True)
    if kind == "policy":
        action, _ = actor.predict(obs, deterministic=deterministic)
        return action
    return actor(obs)


def _run_filter_episode(
    recording: Any,
    method: Any,
    label: str,
    frames: int | None,
    reset_info: dict[str, Any],
    config: Any = None,
) -> EpisodeResult:
    """A reference filter over the episode's recording (the env is not stepped); ``+map``
    uses the maps of the env's reconstructor ``config``."""

    part = recording.head(frames)
    count = part.num_frames
    maps = ("sensor_map", "output_map", "calibrate_output", "calibration_map")
    options = {name: getattr(config, name, None) for name in maps} if config else {}
    with MethodRunner(reconstructor_options=options) as runner:
        result = runner.run(method, part)
    truth = part.ground_truth
    return EpisodeResult(
        name=str(reset_info.get("recording", "")),
        agent=label,
        reconstruction=result,
        rewards=np.full(count, np.nan),
        frame_errors=None if truth is None else metrics.frame_error(truth, result.poses),
        raw_frame_errors=None if truth is None else metrics.frame_error(truth, part.positions),
        agent_ms=result.ms,
        step_ms=np.zeros(count),
        terminated=count == recording.num_frames,
        truncated=count < recording.num_frames,
        reset_info=reset_info,
    )


def measure_env_throughput(
    steps: int = 300,
    ragdoll: bool = True,
    *,
    seed: int = 0,
    env_kwargs: Mapping[str, Any] | None = None,
    make_env: Callable[..., Any] | None = None,
) -> dict[str, Any]:
    """Steps per second of one env with random actions and no search (for ``fpg-gym bench``).

    The env is built and reset once before the clock starts (graph loading, first imports).
    Then ``steps`` random actions (``action_space`` seeded with ``seed``) are taken, resetting
    when an episode ends: ``steps_per_second`` counts everything (the resets simulate the next
    episode and build a fresh ragdoll), ``step_only_per_second`` only the ``step`` calls.

    Parameters
    ----------
    steps : int
        Steps to time.
    ragdoll : bool
        With the PD ragdoll (True) or without.
    seed : int
    env_kwargs : mapping, optional
        More :class:`~fpg_gym.env.KinectPoseEnv` arguments.
    make_env : callable, optional
        ``make_env(**kwargs)`` builds the env (default: :class:`~fpg_gym.env.KinectPoseEnv`).

    Returns
    -------
    dict
        ``steps``, ``resets``, ``seconds``, ``steps_per_second``, ``cpu_seconds`` and
        ``steps_per_cpu_second`` (process CPU time: steadier than wall time on a busy machine,
        but it counts every thread), ``step_only_per_second``,
        ``reset_ms`` (mean), ``step_ms`` (mean, p50, p95), ``stage_ms`` (mean per stage of
        ``info["timings"]``), ``ragdoll``, ``ragdoll_builds``, ``ragdoll_divergences``,
        ``observation_size``.
    """
    if steps < 1:
        raise ValueError(f"steps: expected >= 1, got {steps}")
    kwargs = dict(env_kwargs or {})
    kwargs["ragdoll"] = ragdoll
    if make_env is None:
        make_env = KinectPoseEnv
    env: Any = make_env(**kwargs)
    try:
        env.reset(seed=seed)
        env.action_space.seed(seed)
        step_times: list[float] = []
        reset_times: list[float] = []
        stages: dict[str, float] = {}
        builds = divergences = 0
        start = time.perf_counter()
        cpu_start = time.process_time()
        for _ in range(steps):
            action = env.action_space.sample()
            t0 = time.perf_counter()
            _, _, terminated, truncated, info = env.step(action)
            t1 = time.perf_counter()
            step_times.append(t1 - t0)
            for name, value in info["timings"].items():
                stages[name] = stages.get(name, 0.0) + value
            builds += info["ragdoll_builds"]
            divergences += info["ragdoll_divergences"]
            if terminated or truncated:
                env.reset()
                reset_times.append(time.perf_counter() - t1)
        seconds = time.perf_counter() - start
        cpu_seconds = time.process_time() - cpu_start
        step_ms = 1e3 * np.asarray(step_times)
        return {
            "steps": steps,
            "resets": len(reset_times),
            "seconds": seconds,
            "steps_per_second": steps / seconds,
            "cpu_seconds": cpu_seconds,
            "steps_per_cpu_second": steps / cpu_seconds if cpu_seconds > 0 else None,
            "step_only_per_second": steps / float(np.sum(step_times)),
            "reset_ms": float(1e3 * np.mean(reset_times)) if reset_times else None,
            "step_ms": {
                "mean": float(np.mean(step_ms)),
                "p50": float(np.percentile(step_ms, 50)),
                "p95": float(np.percentile(step_ms, 95)),
            },
            "stage_ms": {name: value / steps for name, value in stages.items()},
            "ragdoll": ragdoll,
            "ragdoll_builds": builds,
            "ragdoll_divergences": divergences,
            "observation_size": int(env.unwrapped.layout.size),
        }
    finally:
        env.close()

"""The supervised sampler's training pairs: (observation, target action) per frame.

:func:`collect_imitation_data` rolls recordings through the
:class:`~fpg_gym.reconstruct.Reconstructor` and records, on every frame, the sampler's
observation and the latent point it should propose. The recordings are reconstructed side by
side, ``batch`` at a time, with their searches' energies evaluated together
(:func:`fpg_gym.reconstruct.search.search_together`), and split between ``workers`` local
processes or, with ``backend="ray"``, Ray tasks (``fpg-gym[distributed]``: the graph put once in
the object store, each task carrying its recordings). Each episode draws from its own generator
(``SeedSequence(seed).spawn``), so the pairs do not depend on ``batch``, ``workers`` or the
backend.
"""

from __future__ import annotations

import copy
import multiprocessing
from collections.abc import Callable, Collection, Sequence
from concurrent.futures import FIRST_COMPLETED, ProcessPoolExecutor, wait
from dataclasses import dataclass
from typing import Any

import numpy as np
from tqdm.auto import tqdm

from fpg_gym.core import poses as pose_utils
from fpg_gym.core.skeleton import ROOT
from fpg_gym.reconstruct import Reconstructor, TemporalConfig
from fpg_gym.reconstruct.energy import EnergyWeights
from fpg_gym.reconstruct.search import search_together
from fpg_gym.reconstruct.streams import Choice, Stream, reconstruct_streams
from fpg_gym.runtime.ray_session import ray_session, require_ray, task_result
from optimizers import OptimizerRun, make, run_optimizer
from policies.learned_optimizers import LearnedSampler, LearnedSearch
from policies.sampler import AnchorSampler, SamplerSpec, problem_observation

__all__ = [
    "FOLLOW",
    "TARGETS",
    "TRUTH_TARGETS",
    "ImitationData",
    "collect_imitation_data",
    "frame_caps",
    "truth_latent",
]

#: Targets of the supervised sampler (:func:`collect_imitation_data`).
TARGETS: tuple[str, ...] = ("best", "search", "truth", "bones")
#: The targets taken from the ground truth (:func:`truth_latent`'s two metrics).
TRUTH_TARGETS: tuple[str, ...] = ("truth", "bones")
#: What the imitation stream continues from (:func:`collect_imitation_data`).
FOLLOW: tuple[str, ...] = ("search", "anchor", "truth")
#: Recordings reconstructed side by side by default.
DEFAULT_BATCH = 8
#: Where the episodes run: here or in local worker processes, or on a Ray cluster.
BACKENDS: tuple[str, ...] = ("local", "ray")


def truth_latent(
    problem: Any, placement: Any, truth: np.ndarray, metric: str = "joints"
) -> np.ndarray:
    """Whitened coordinates ``(d,)`` of a ground-truth pose in ``problem``'s latent space.

    The truth is seen in the problem's frame: its own root at the origin (Eq. 13 scores bone
    vectors, so the root's offset carries no error, and the database poses are root-centred)
    and turned by ``placement.yaw``, the heading the reconstructor normalised the frame with
    (:attr:`fpg_gym.reconstruct.Reconstructor.placement`). That heading is not always the raw
    sensor pose's: after a left/right relabelling it differs by about 180 degrees, a frame
    without a body keeps the last one, and a sensor map or the temporal stage move it;
    recomputing it from the raw sensor frame (what collect_imitation_data did before) put the
    target in a wrong heading on exactly those frames.

    Parameters
    ----------
    problem : SearchProblem
    placement : Placement
        The prepared frame's placement.
    truth : ndarray, shape (20, 3)
        Ground truth, camera space.
    metric : {"joints", "bones"}
        ``"joints"``: the orthogonal projection of the truth's joints (``problem.encode``).
        ``"bones"``: the point whose bone vectors are closest (least squares) to the truth's
        bone directions at the frame's bone lengths (``problem.lengths``). The reconstructor
        gives its output those lengths and FPG Eq. 13 scores bone vectors, so this is the
        point of the latent space that Eq. 13 scores best (a lower error than ``"joints"``
        on UI-PRMD, where the sensor's bone lengths are not Vicon's).
    """
    pose = np.asarray(truth, dtype=np.float64)
    frame = pose_utils.Placement(root=pose[ROOT], yaw=np.asarray(placement.yaw))
    local = pose_utils.into_placement(pose, frame)
    if metric == "joints":
        return np.asarray(problem.encode(local), dtype=np.float64)
    if metric != "bones":
        raise ValueError(f"metric: expected 'joints' or 'bones', got {metric!r}")
    target = pose_utils.bone_directions(local) * np.asarray(problem.lengths, np.float64)[:, None]
    latent = problem.latent
    # Bone vectors are linear in z: decode(z) = m + (z s) B (Shum Eq. 9).
    design = pose_utils.latent_bone_design(latent.std[:, None] * latent.basis)
    offset = pose_utils.flat_bone_vectors(latent.mean)
    return pose_utils.fit_bone_vectors(design, target.reshape(-1) - offset)


@dataclass
class ImitationData:
    """(observation, target action) pairs of the supervised sampler.

    Attributes
    ----------
    observations : ndarray, shape (n, N), float32
        Env observations (:func:`policies.sampler.problem_observation`).
    actions : ndarray, shape (n, L), float32
        Target actions (zero beyond each frame's ``d`` axes).
    masks : ndarray, shape (n, L), float32
        1 on each frame's valid axes.
    episodes : ndarray, shape (n,), int
        Episode index of each frame.
    search_energies : ndarray, shape (n,)
        Energy of the local-search optimum on each frame.
    """

    observations: np.ndarray
    actions: np.ndarray
    masks: np.ndarray
    episodes: np.ndarray
    search_energies: np.ndarray

    def __len__(self) -> int:
        return len(self.actions)

    @classmethod
    def empty(cls, observation_size: int, latent_dim: int) -> ImitationData:
        """No pairs (the arrays' widths set)."""
        return cls(
            np.zeros((0, observation_size), np.float32),
            np.zeros((0, latent_dim), np.float32),
            np.zeros((0, latent_dim), np.float32),
            np.zeros(0, np.int64),
            np.zeros(0),
        )

    @classmethod
    def concatenate(cls, parts: Sequence[ImitationData]) -> ImitationData:
        """The pairs of ``parts`` one after the other (at least one part)."""
        return cls(
            np.concatenate([p.observations for p in parts]),
            np.concatenate([p.actions for p in parts]),
            np.concatenate([p.masks for p in parts]),
            np.concatenate([p.episodes for p in parts]),
            np.concatenate([p.search_energies for p in parts]),
        )


@dataclass(frozen=True)
class _Collection:
    """What every episode's collection shares (sent once to each worker process)."""

    spec: SamplerSpec
    target: str
    follow: str
    options: dict[str, Any]


@dataclass(frozen=True)
class _Chunk:
    """Episodes collected together: their recordings, episode numbers, frame caps and
    generators (one each)."""

    recordings: list[Any]
    episodes: list[int]
    caps: list[int]
    rngs: list[np.random.Generator]


def _chunks(
    recordings: Sequence[Any],
    caps: Sequence[int],
    rngs: Sequence[np.random.Generator],
    size: int,
) -> list[_Chunk]:
    """The episodes with frames to collect, in order, in chunks of at most ``size``."""
    kept = [i for i, n in enumerate(caps) if n > 0]
    return [
        _Chunk(
            [recordings[i] for i in part],
            part,
            [caps[i] for i in part],
            [rngs[i] for i in part],
        )
        for part in (kept[j : j + size] for j in range(0, len(kept), size))
    ]


def frame_caps(recordings: Sequence[Any], frames: int | None) -> list[int]:
    """Frames collected per recording: all of them, in order, until ``frames`` in total."""
    caps, left = [], None if frames is None else max(int(frames), 0)
    for recording in recordings:
        n = recording.num_frames if left is None else min(recording.num_frames, left)
        caps.append(n)
        if left is not None:
            left -= n
    return caps


def _best_of(
    problems: Sequence[Any],
    optimizers: Sequence[Any],
    rngs: Sequence[np.random.Generator | None],
) -> list[Any]:
    """One search per problem, run side by side; their results."""
    runs = [OptimizerRun(p, o, r) for p, o, r in zip(problems, optimizers, rngs, strict=True)]
    search_together(problems, runs)
    return [run.result() for run in runs]


class _Pairs:
    """The chooser of the imitation streams (:data:`~fpg_gym.reconstruct.streams.Chooser`): on
    every frame the searches (or the anchor) run on the streams' problems side by side, each
    frame's pair is recorded and the stream continues from the point ``follow`` names."""

    def __init__(self, chunk: _Chunk, job: _Collection) -> None:
        spec = job.spec
        self.job, self.recordings = job, chunk.recordings
        self.delta = spec.action_mode == "delta"
        self.anchor_only = LearnedSampler(AnchorSampler(spec), samples=1)
        anchored = None
        if job.target == "best" and spec.anchor != "none":
            anchored = LearnedSearch(
                AnchorSampler(spec), samples=1, iterations=20, search_samples=100
            )
        streams = range(len(chunk.recordings))
        # One optimiser object per stream, reset on every frame.
        self.searches = [make("local-search") for _ in streams]
        self.anchored = [copy.deepcopy(anchored) for _ in streams] if anchored else []
        rows = sum(chunk.caps)
        self.observations = np.zeros((rows, spec.layout.size), np.float32)
        self.actions = np.zeros((rows, spec.latent_dim), np.float32)
        self.masks = np.zeros((rows, spec.latent_dim), np.float32)
        self.energies = np.zeros(rows)
        # Each episode's rows are contiguous: stream i's frame t goes to row start[i] + t.
        self.start = np.cumsum([0, *chunk.caps])[:-1]
        self.labels = np.repeat(np.asarray(chunk.episodes, np.int64), chunk.caps)

    def _found(self, problems: Sequence[Any], streams: Sequence[Stream]) -> list[Any]:
        """The search results the frames' pairs and points come from."""
        generators = [s.rng for s in streams]
        if self.job.follow != "search":
            return [
                run_optimizer(p, self.anchor_only, r)
                for p, r in zip(problems, generators, strict=True)
            ]
        found = _best_of(problems, [self.searches[s.index] for s in streams], generators)
        if self.anchored:
            others = _best_of(problems, [self.anchored[s.index] for s in streams], generators)
            # The best of both searches (the lowest energy found).
            found = [o if o.energy < f.energy else f for f, o in zip(found, others, strict=True)]
        return found

    def __call__(self, problems: Sequence[Any], streams: Sequence[Stream]) -> list[Choice]:
        spec, target = self.job.spec, self.job.target
        latent_dim, scale = spec.latent_dim, spec.action_scale
        choices = []
        for stream, problem, result in zip(
            streams, problems, self._found(problems, streams), strict=True
        ):
            i, t = stream.index, stream.next
            z = result.x
            d = min(problem.dim, latent_dim)
            if target in TRUTH_TARGETS:
                truth = self.recordings[i].ground_truth
                placement = stream.reconstructor.placement
                assert truth is not None and placement is not None
                metric = "bones" if target == "bones" else "joints"
                z_target = truth_latent(problem, placement, truth[t], metric)
                if self.job.follow == "truth":
                    z = z_target
            else:
                z_target = z
            row = self.start[i] + t
            origin = problem.x0 if self.delta else 0.0
            self.actions[row, :d] = ((z_target - origin) / scale)[:d]
            self.masks[row, :d] = 1.0
            self.observations[row] = problem_observation(
                problem, spec.layout, action_scale=scale, delta=self.delta, frame_dt=spec.frame_dt
            )
            self.energies[row] = result.energy
            choices.append(Choice(z))
        return choices

    def data(self) -> ImitationData:
        """The pairs recorded."""
        return ImitationData(
            self.observations, self.actions, self.masks, self.labels, self.energies
        )


def _collect_episodes(
    graph: Any, chunk: _Chunk, job: _Collection, progress: Any = None
) -> ImitationData:
    """The pairs of the chunk's episodes (at least one, at most ``batch``), side by side
    (:func:`~fpg_gym.reconstruct.streams.reconstruct_streams` with :class:`_Pairs`)."""
    streams = [
        Stream(Reconstructor(graph, **job.options), recording, rng=rng, frames=cap, index=i)
        for i, (recording, cap, rng) in enumerate(
            zip(chunk.recordings, chunk.caps, chunk.rngs, strict=True)
        )
    ]
    pairs = _Pairs(chunk, job)
    try:
        reconstruct_streams(streams, pairs, on_step=None if progress is None else progress.update)
    finally:
        for stream in streams:
            stream.reconstructor.close()
    return pairs.data()


#: The graph of this worker process (set once by the pool's initializer).
_WORKER_GRAPH: list[Any] = []


def _init_worker(graph: Any) -> None:
    """Pool initializer: keep the graph (sent once per process) and BLAS on one thread."""
    from threadpoolctl import threadpool_limits

    threadpool_limits(1)
    _WORKER_GRAPH[:] = [graph]


def _collect_in_worker(chunk: _Chunk, job: _Collection) -> ImitationData:
    """:func:`_collect_episodes` in a worker process, on the process's graph."""
    return _collect_episodes(_WORKER_GRAPH[0], chunk, job)


def collect_imitation_data(
    graph: Any,
    recordings: Sequence[Any],
    spec: SamplerSpec,
    *,
    target: str = "best",
    frames: int | None = None,
    seed: int = 0,
    progress: bool = False,
    follow: str = "search",
    reconstructor_options: dict[str, Any] | None = None,
    batch: int = DEFAULT_BATCH,
    workers: int = 1,
    backend: str = "local",
    address: str | None = None,
    skip: Collection[int] = (),
    on_chunk: Callable[[list[int], ImitationData], object] | None = None,
) -> ImitationData:
    """Roll ``recordings`` through the reconstructor and record (observation, target) pairs.

    Every frame is searched with the papers' local search (``local-search``, 2,000
    evaluations, from ``x0``); with ``target="best"`` a second local search starts from the
    spec's anchor (:class:`~policies.sampler.FeatureMap`) on the same problem. The stream
    continues from the best point found, as a search-driven
    reconstruction would. The target action selects:

    * ``"search"``: the best point of the papers' local search alone;
    * ``"best"``: the best point of both searches (the lowest energy found; the same as
      ``"search"`` without an anchor);
    * ``"truth"``: the ground-truth pose seen in the problem's frame (:func:`truth_latent`:
      root-relative, turned by the heading the reconstructor normalised the frame with) and
      projected (needs recordings with ground truth);
    * ``"bones"``: the same truth, the latent point closest to its bone directions at the
      frame's bone lengths (:func:`truth_latent` with ``metric="bones"``).

    With ``follow="anchor"`` or ``"truth"`` (targets ``"truth"`` and ``"bones"`` only) no
    search runs: the stream continues from the spec's anchor (the closed-form point: previous
    frames of the quality a sampler will give) or from the projected truth (teacher forcing),
    one evaluation per frame; data collection is then a small fraction of the search's cost.

    Parameters
    ----------
    graph : FilteredPoseGraph
    recordings : sequence of Recording
    spec : SamplerSpec
        The sampler the data is for (observation layout, action mode and scale, anchor).
    target : {"best", "search", "truth", "bones"}
    frames : int, optional
        Stop after this many frames, taken in recording order (all recordings otherwise).
    seed : int
        Root of the episodes' generators (episode ``e`` draws from the ``e``-th child of
        ``SeedSequence(seed)``).
    progress : bool
        A tqdm bar over the frames.
    follow : {"search", "anchor", "truth"}
        The point each frame is finished with (the next frames' history).
    reconstructor_options : dict, optional
        Overrides of the :class:`~fpg_gym.reconstruct.Reconstructor` settings (default: the
        env's per-frame problem: temporal stage off, no ragdoll). Pass the settings the
        sampler will be used with (``sensor_map``, ``temporal``, ``sensor_blend``...).
    batch : int
        Recordings reconstructed side by side (8); the pairs are the same for any value.
    workers : int
        Local processes the recordings are split between (1: this process), or with
        ``backend="ray"`` the CPUs of a local Ray instance started for the call; the pairs are
        the same for any value.
    backend : {"local", "ray"}
        ``"ray"`` runs chunks of at most ``batch`` episodes as Ray tasks.
    address : str, optional
        Ray cluster (``backend="ray"``); None: ``RAY_ADDRESS``, an instance already started
        in this process, or a local one.
    skip : collection of int
        Episodes (recording indices) not to collect, e.g. those a stopped run saved already;
        the others' pairs are the same as when nothing is skipped (each episode has its own
        generator, and the frame cap counts the skipped episodes' frames).
    on_chunk : callable, optional
        Receives each finished chunk of at most ``batch`` episodes, ``(episodes, pairs)``, as
        soon as it is done (:class:`policies.checkpoints.RunCheckpoints` saves them).

    Returns
    -------
    ImitationData
        The pairs of the episodes not skipped, in episode order.

    Raises
    ------
    ValueError
        On an unknown ``target``, ``follow`` or ``backend``, ``follow`` other than
        ``"search"`` without ``target="truth"``, ``"truth"`` without ground truth,
        ``batch``/``workers`` < 1, or an episode of ``skip`` out of range.
    RayUnavailable
        ``backend="ray"`` without Ray installed.
    """
    _check_collection(recordings, target, follow, batch, workers, backend)
    job = _Collection(spec, target, follow, _collection_options(spec, reconstructor_options))
    caps = _episode_caps(recordings, frames, skip)
    children = np.random.SeedSequence(seed).spawn(len(recordings))
    rngs = [np.random.default_rng(child) for child in children]
    episodes = sum(n > 0 for n in caps)
    if episodes == 0:  # no frame to collect, whatever the backend
        return ImitationData.empty(spec.layout.size, spec.latent_dim)
    bar = tqdm(
        total=sum(caps), desc="imitation data", unit="frame", leave=False, disable=not progress
    )
    try:
        return _collect_chunks(
            graph, recordings, caps, rngs, job, bar, batch, workers, backend, address, on_chunk
        )
    finally:
        bar.close()


def _check_collection(
    recordings: Sequence[Any], target: str, follow: str, batch: int, workers: int, backend: str
) -> None:
    """:func:`collect_imitation_data`'s argument checks, before any work."""
    if target not in TARGETS:
        raise ValueError(f"target: expected one of {TARGETS}, got {target!r}")
    if follow not in FOLLOW:
        raise ValueError(f"follow: expected one of {FOLLOW}, got {follow!r}")
    if follow != "search" and target not in TRUTH_TARGETS:
        raise ValueError(
            f"follow={follow!r} needs target 'truth' or 'bones' (got target={target!r})"
        )
    if batch < 1:
        raise ValueError(f"batch: expected >= 1, got {batch}")
    if workers < 1:
        raise ValueError(f"workers: expected >= 1, got {workers}")
    if backend not in BACKENDS:
        raise ValueError(f"backend: expected one of {BACKENDS}, got {backend!r}")
    if backend == "ray":
        require_ray()  # before any work
    if target in TRUTH_TARGETS:
        missing = [i for i, r in enumerate(recordings) if r.ground_truth is None]
        if missing:
            raise ValueError(
                f"target {target!r} needs ground truth; recordings {missing} have none"
            )


def _collection_options(
    spec: SamplerSpec, reconstructor_options: dict[str, Any] | None
) -> dict[str, Any]:
    """The reconstructor's settings for the data of ``spec``: the env's per-frame problem
    (its candidates, latent dimension and weights; no temporal stage, no ragdoll) unless
    overridden, and no evaluation cap."""
    weights = dict(
        zip(("control", "style", "kinematic", "motion"), spec.energy_weights, strict=True)
    )
    return {
        "k": spec.candidates,
        "latent_dim": spec.latent_dim,
        "ragdoll": False,
        "weights": EnergyWeights(**weights),
        "temporal": TemporalConfig.off(),  # the env's per-frame problem
        **(reconstructor_options or {}),
        "max_evaluations": None,
    }


def _episode_caps(
    recordings: Sequence[Any], frames: int | None, skip: Collection[int]
) -> list[int]:
    """Frames to collect per episode (:func:`frame_caps`), none for those of ``skip``."""
    caps = frame_caps(recordings, frames)
    for episode in skip:
        if not 0 <= episode < len(recordings):
            raise ValueError(f"skip: episode {episode} is not in 0..{len(recordings) - 1}")
        caps[episode] = 0
    return caps


def _collect_chunks(
    graph: Any,
    recordings: Sequence[Any],
    caps: list[int],
    rngs: list[np.random.Generator],
    job: _Collection,
    bar: Any,
    batch: int,
    workers: int,
    backend: str,
    address: str | None,
    on_chunk: Callable[[list[int], ImitationData], object] | None,
) -> ImitationData:
    """The episodes' pairs, collected in chunks here, in local processes or on Ray."""
    episodes = sum(n > 0 for n in caps)
    # Chunks of at most ``batch`` episodes, fewer when that keeps every worker busy.
    size = max(1, min(batch, -(-episodes // workers)))
    report = on_chunk or (lambda _episodes, _pairs: None)
    if backend == "ray":
        return _collect_on_ray(
            graph, _chunks(recordings, caps, rngs, size), job, workers, bar, address, report
        )
    if workers == 1 or episodes == 1:  # here, chunk after chunk
        parts = []
        for chunk in _chunks(recordings, caps, rngs, batch):
            parts.append(_collect_episodes(graph, chunk, job, bar))
            report(chunk.episodes, parts[-1])
        return ImitationData.concatenate(parts)
    chunks = _chunks(recordings, caps, rngs, size)
    return _collect_in_pool(graph, chunks, job, workers, bar, report)


def _collect_in_pool(
    graph: Any,
    chunks: Sequence[_Chunk],
    job: _Collection,
    workers: int,
    bar: Any,
    report: Callable[[list[int], ImitationData], object],
) -> ImitationData:
    """The chunks in ``workers`` spawned processes; the pairs put back in episode order."""
    context = multiprocessing.get_context("spawn")
    results: dict[int, ImitationData] = {}
    pool = ProcessPoolExecutor(
        min(workers, len(chunks)), mp_context=context, initializer=_init_worker, initargs=(graph,)
    )
    try:
        pending = {pool.submit(_collect_in_worker, c, job): n for n, c in enumerate(chunks)}
        while pending:
            done, _ = wait(pending, return_when=FIRST_COMPLETED)
            for future in done:
                n = pending.pop(future)
                results[n] = future.result()
                bar.update(len(results[n]))
                report(chunks[n].episodes, results[n])
    except BaseException:
        pool.shutdown(wait=False, cancel_futures=True)  # Ctrl-C or a failing chunk: stop now
        raise
    pool.shutdown()
    return ImitationData.concatenate([results[n] for n in range(len(chunks))])


def _collect_ray_task(graph: Any, chunk: _Chunk, job: _Collection) -> ImitationData:
    """One Ray task: :func:`_collect_episodes` with BLAS on one thread (the graph comes from
    the object store)."""
    from threadpoolctl import threadpool_limits

    with threadpool_limits(1):
        return _collect_episodes(graph, chunk, job)


def _collect_on_ray(
    graph: Any,
    chunks: Sequence[_Chunk],
    job: _Collection,
    workers: int,
    bar: Any,
    address: str | None,
    report: Callable[[list[int], ImitationData], object],
) -> ImitationData:
    """The chunks as Ray tasks (``workers``: the CPUs of a local instance started here), the
    graph in the object store once; the pairs put back in episode order."""
    with ray_session(address, num_cpus=workers) as ray:
        graph_ref = ray.put(graph)
        remote = ray.remote(num_cpus=1, max_retries=0)(_collect_ray_task)
        pending = {remote.remote(graph_ref, c, job): n for n, c in enumerate(chunks)}
        results: dict[int, ImitationData] = {}
        try:
            while pending:
                done, _ = ray.wait(list(pending), num_returns=1)
                for ref in done:
                    n = pending.pop(ref)
                    results[n] = task_result(ray, ref)
                    bar.update(len(results[n]))
                    report(chunks[n].episodes, results[n])
        except BaseException:
            for ref in pending:
                ray.cancel(ref, force=True)
            raise
    return ImitationData.concatenate([results[n] for n in range(len(chunks))])

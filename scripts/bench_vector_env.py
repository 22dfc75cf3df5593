"""The env's vector mode: N episodes driven one by one vs. through ``KinectPoseVectorEnv.search``.

Both drive the same N episodes of ``fpg_gym/KinectPose-v0`` (seeds 0..N-1, the first ``--frames``
frames of each, the paper's local search):

1. one by one: :func:`fpg_gym.episodes.run_episode` on one env, episode after episode;
2. together: :class:`fpg_gym.vector_env.KinectPoseVectorEnv` with N sub-envs,
   ``venv.step(venv.search("local-search"))`` frame after frame (the N searches' energies
   evaluated with one stacked kernel call per iteration).

Resets (which simulate the episode's stream) and steps are inside the clock; building the envs
(graph loading) and compiling the kernels are not. CPU time is ``time.process_time``; runs are
interleaved ``--repeat`` times (median). Also checks that each episode's poses are equal both
ways. BLAS threads are limited to one (``OPENBLAS_NUM_THREADS=1`` unless set).

Usage::

    python scripts/bench_vector_env.py --envs 8 --frames 15 --no-ragdoll
"""

from __future__ import annotations

import os

os.environ.setdefault("OPENBLAS_NUM_THREADS", "1")
os.environ.setdefault("OMP_NUM_THREADS", "1")

import argparse
import statistics
import time

import numpy as np

from fpg_gym.env import KinectPoseEnv
from fpg_gym.episodes import run_episode
from fpg_gym.reconstruct.kernels import compile_kernels
from fpg_gym.vector_env import KinectPoseVectorEnv


def one_by_one(
    env: KinectPoseEnv, count: int, frames: int
) -> tuple[float, float, list[np.ndarray]]:
    """CPU seconds, wall seconds in the searches, and poses of ``count`` episodes run one after
    the other."""
    cpu = time.process_time()
    results = [run_episode(env, "local-search", seed=i, max_steps=frames) for i in range(count)]
    search = 1e-3 * sum(float(r.agent_ms.sum()) for r in results)
    return time.process_time() - cpu, search, [r.poses for r in results]


def together(venv: KinectPoseVectorEnv, frames: int) -> tuple[float, float, list[np.ndarray]]:
    """CPU seconds, wall seconds in the searches, and poses of the vector env's episodes."""
    cpu = time.process_time()
    search = 0.0
    venv.reset(seed=0)
    poses: list[list[np.ndarray]] = [[] for _ in range(venv.num_envs)]
    ended = np.zeros(venv.num_envs, dtype=bool)
    for _ in range(frames):
        start = time.perf_counter()
        actions = venv.search("local-search")
        search += time.perf_counter() - start
        _, _, terminated, truncated, infos = venv.step(actions)
        for i in np.flatnonzero(~ended & infos["_pose"]):
            poses[i].append(infos["pose"][i])
        ended |= terminated | truncated
    return time.process_time() - cpu, search, [np.asarray(p) for p in poses]


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    parser.add_argument("--envs", type=int, default=8)
    parser.add_argument("--frames", type=int, default=15)
    parser.add_argument("--no-ragdoll", action="store_true", help="without the PD ragdoll")
    parser.add_argument("--repeat", type=int, default=3, help="interleaved repeats (median)")
    args = parser.parse_args()

    kwargs = {"ragdoll": not args.no_ragdoll}
    env = KinectPoseEnv(**kwargs)
    venv = KinectPoseVectorEnv(args.envs, **kwargs)
    compile_kernels()
    alone: list[tuple[float, float]] = []
    batched: list[tuple[float, float]] = []
    worst = 0.0
    for _ in range(args.repeat):
        cpu, search, poses_alone = one_by_one(env, args.envs, args.frames)
        alone.append((cpu, search))
        cpu, search, poses = together(venv, args.frames)
        batched.append((cpu, search))
        worst = max(
            [worst, *(float(np.abs(a - b).max()) for a, b in zip(poses_alone, poses, strict=True))]
        )
    frames = sum(len(p) for p in poses)
    a, b = (statistics.median(c for c, _ in runs) for runs in (alone, batched))
    sa, sb = (statistics.median(s for _, s in runs) for runs in (alone, batched))
    print(
        f"{args.envs} episodes, {frames} frames, ragdoll {not args.no_ragdoll}, "
        f"{args.repeat} repeats (medians)"
    )
    print(f"{'':27s} {'CPU s':>7s} {'frames/CPU-s':>13s} {'search wall s':>14s}")
    print(f"{'one by one (run_episode)':27s} {a:7.2f} {frames / a:13.1f} {sa:14.2f}")
    print(f"{'together (venv.search)':27s} {b:7.2f} {frames / b:13.1f} {sb:14.2f}")
    print(f"ratio {a / b:.2f}x (searches {sa / sb:.2f}x); largest pose difference {worst:.3g} m")
    env.close()
    venv.close()


if __name__ == "__main__":
    main()

"""Evaluation of optimisers on held-out episodes, and a trained sampler's final table.

* :func:`evaluate_agents`: mean energy, mean error, Err0.2, evaluations and ms per frame of
  optimisers (a learned sampler through :mod:`policies.learned_optimizers`) on episodes.
* :func:`final_agents`: what a trained sampler is compared with at the end of its run.
"""

from __future__ import annotations

from collections.abc import Sequence
from pathlib import Path
from typing import Any

import numpy as np

from fpg_gym.core import metrics
from fpg_gym.reconstruct import Reconstructor, TemporalConfig
from fpg_gym.reconstruct.streams import run_streams
from optimizers.local_search import LocalSearch
from optimizers.random_search import RandomSearch
from policies.learned_optimizers import LearnedSampler, LearnedSearch
from policies.loading import load_sampler
from policies.rl import UNTRAINED_CHECKPOINT, zero_action
from policies.sampler import AnchorSampler, GaussianSampler

__all__ = ["evaluate_agents", "final_agents", "format_evaluation"]


def evaluate_agents(
    graph: Any,
    recordings: Sequence[Any],
    agents: dict[str, Any],
    *,
    k: int = 30,
    latent_dim: int = 20,
    seed: int = 0,
    progress: bool = False,
    reconstructor_options: dict[str, Any] | None = None,
) -> dict[str, dict[str, float]]:
    """Reconstruct ``recordings`` with each agent (an optimiser name or object) and summarise.

    The reconstructors run the env's per-frame problem (temporal stage off, no ragdoll) with
    ``reconstructor_options`` on top (a sensor map, a sensor blend...).

    Returns, per agent: ``mean_energy``, ``mean_error`` (FPG Eq. 13, m) with
    ``error_ci_low``/``error_ci_high`` (its 95 % bootstrap interval over the recordings,
    :func:`fpg_gym.core.metrics.bootstrap_mean_ci`: a few episodes give a wide one), ``err02``
    (share of frames with error >= 0.2 m), ``jitter`` (the output's mean joint acceleration, m/s²,
    :func:`fpg_gym.core.metrics.jitter`, averaged over the recordings), ``evaluations`` and ``ms``
    per frame, ``frames``. Errors need ground truth (NaN otherwise).
    """

    # One reconstructor per recording: the recordings run side by side, their searches batched
    # (fpg_gym.reconstruct.streams; each stream as alone with seed + i).
    reconstructors = [
        Reconstructor(
            graph,
            **{
                "k": k,
                "latent_dim": latent_dim,
                "ragdoll": False,
                "temporal": TemporalConfig.off(),
                **(reconstructor_options or {}),
            },
        )
        for _ in recordings
    ]
    out: dict[str, dict[str, float]] = {}
    try:
        for name, agent in agents.items():
            energies: list[np.ndarray] = []
            errors: list[np.ndarray] = []
            jitters: list[float] = []
            evaluations: list[np.ndarray] = []
            ms: list[np.ndarray] = []
            seeds = [seed + i for i in range(len(recordings))]
            results = run_streams(reconstructors, recordings, agent, seeds)
            for recording, result in zip(recordings, results, strict=True):
                arrays = result.arrays()
                energies.append(arrays["energy"])
                evaluations.append(arrays["evaluations"])
                ms.append(arrays["ms_per_frame"])
                if len(result.poses) >= 3:
                    jitters.append(
                        float(np.nanmean(metrics.jitter(result.poses, fps=recording.fps)))
                    )
                truth = recording.head(len(result.poses)).ground_truth
                if truth is not None:
                    errors.append(metrics.frame_error(truth, result.poses))
            err = np.concatenate(errors) if errors else np.array([np.nan])
            low, high = (
                metrics.bootstrap_mean_ci(
                    [np.mean(e) for e in errors], weights=[len(e) for e in errors], rng=seed
                )
                if errors
                else (np.nan, np.nan)
            )
            out[name] = {
                "mean_energy": float(np.mean(np.concatenate(energies))),
                "mean_error": float(np.mean(err)),
                "error_ci_low": low,
                "error_ci_high": high,
                "err02": metrics.err_ratio(err) if errors else np.nan,
                "jitter": float(np.mean(jitters)) if jitters else np.nan,
                "evaluations": float(np.mean(np.concatenate(evaluations))),
                "ms": float(np.mean(np.concatenate(ms))),
                "frames": int(sum(len(e) for e in energies)),
            }
            if progress:
                print(_format_row(name, out[name]), flush=True)
    finally:
        for reconstructor in reconstructors:
            reconstructor.close()
    return out


def _format_row(name: str, row: dict[str, float]) -> str:
    return (
        f"  {name:<22} energy {row['mean_energy']:.4f}  error {row['mean_error']:.4f} m  "
        f"Err0.2 {100 * row['err02']:.1f} %  jitter {row['jitter']:.2f} m/s²  "
        f"evals {row['evaluations']:.0f}  "
        f"{row['ms']:.2f} ms/frame"
    )


def format_evaluation(table: dict[str, dict[str, float]]) -> str:
    """A markdown table of :func:`evaluate_agents`' output."""
    lines = [
        "| agent | mean energy | mean error (m) [95 % CI over episodes] | Err0.2 (%) "
        "| jitter (m/s²) | evaluations/frame | ms/frame |",
        "| --- | --- | --- | --- | --- | --- | --- |",
    ]
    for name, row in table.items():
        lines.append(
            f"| {name} | {row['mean_energy']:.4f} | {row['mean_error']:.4f} "
            f"[{row.get('error_ci_low', np.nan):.4f}, {row.get('error_ci_high', np.nan):.4f}] | "
            f"{100 * row['err02']:.1f} | {row['jitter']:.2f} | {row['evaluations']:.0f} | "
            f"{row['ms']:.2f} |"
        )
    return "\n".join(lines)


def _policy_references(sampler: Any, checkpoints: Path) -> dict[str, Any]:
    """What an RL sampler's proposals must beat, at the same 200 evaluations: the local
    search alone, and ``learned+search`` with the untrained policy (its step-0 checkpoint) and
    with the zero action (:func:`policies.rl.zero_action`)."""
    rows: dict[str, Any] = {
        "local-search (200)": LocalSearch(iterations=2),
        "zero action, learned+search (200)": LearnedSearch(zero_action(sampler)),
    }
    untrained = checkpoints / f"{UNTRAINED_CHECKPOINT}.json"
    if untrained.is_file():
        rows["untrained, learned+search (200)"] = LearnedSearch(load_sampler(untrained))
    return rows


def final_agents(sampler: GaussianSampler, kind: str, checkpoints: Path) -> dict[str, Any]:
    """The optimisers of a trained sampler's final evaluation: the baselines none /
    random-search(200) / local-search, its anchor alone, its mean action, ``learned`` and
    ``learned+search`` (and ``learned`` without its output correction when it has one; with an
    RL sampler, :func:`_policy_references`)."""
    return {
        "none (x0)": "none",
        "random-search (200)": RandomSearch(samples=100, iterations=2),
        "local-search (2000)": "local-search",
        "anchor only (1)": LearnedSampler(AnchorSampler(sampler.spec), samples=1),
        "mean action (1)": LearnedSampler(sampler, samples=1),
        "learned (200)": LearnedSampler(sampler),
        "learned+search (200)": LearnedSearch(sampler),
        **(
            {"learned, uncorrected (200)": LearnedSampler(sampler, correct_output=False)}
            if getattr(sampler, "output_correction", None) is not None
            else {}
        ),
        **(_policy_references(sampler, checkpoints) if kind == "rl" else {}),
    }

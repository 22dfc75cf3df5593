"""The study's tables of scored rows (:func:`sampler_study.scoring.score`): seeds pooled and per
seed, paired changes against closed-form with bootstrap intervals, per held-out subject and per
set of repetitions, and the per-subject plot."""

from __future__ import annotations

from pathlib import Path
from typing import Any

import numpy as np

from fpg_gym.core import metrics


def _method_kind(method: str, models: dict[str, dict[str, str]]) -> tuple[str, str | None]:
    """``(row name, seed)`` of a method of the UI-PRMD protocol."""
    for fold in models.values():
        for seed, path in fold.items():
            if method.endswith(path):
                return method[: -len(path)].removeprefix("fpg:").rstrip(":"), seed
    return method.removeprefix("fpg:"), None


#: Figures of a row (:func:`sampler_study.scoring._row`) the tables pool per episode.
FIGURES = ("error", "mpjpe", "mpjpe_root", "mpjpe_pa", "jitter", "spread_mm", "bone_error_mm")
#: Evaluations per frame of each row's method (200 for the learned ones).
EVALUATIONS = {
    "raw": "–",
    "holt": "–",
    "mapped": "–",
    "mapped+holt": "–",
    "closed-form": "1",
    "local-search": "2,000",
    "mean-only": "1",
    "oracle-bones": "– (sees the truth)",
}


def _by_method(results: list[dict[str, Any]]) -> dict[str, dict[str, dict[str, float]]]:
    """``{row name: {episode: {figure: value}}}``: each figure of :data:`FIGURES` (NaN where a
    fold file lacks it) and ``cpu_ms``, averaged over the seeds of one method; a row per seed
    too (``"NAME (seed S)"``) when there are several."""
    models = {res["subject"]: res["models"] for res in results}
    several = len({seed for fold in models.values() for seed in fold}) > 1
    by: dict[str, dict[str, dict[str, list[float]]]] = {}
    for result in results:
        for row in result["rows"]:
            name, seed = _method_kind(row["method"], models)
            keys = [name] + ([f"{name} (seed {seed})"] if seed is not None and several else [])
            for key in keys:
                slot = by.setdefault(key, {}).setdefault(row["episode"], {})
                for figure in (*FIGURES, "cpu_ms"):
                    slot.setdefault(figure, []).append(float(row.get(figure, np.nan)))
    return {
        name: {
            episode: {figure: float(np.mean(values)) for figure, values in slot.items()}
            for episode, slot in episodes.items()
        }
        for name, episodes in by.items()
    }


def change(values: np.ndarray, base: np.ndarray, rng: np.random.Generator) -> str:
    """The change of the mean of ``values`` against ``base`` (paired episodes) with its 95 %
    bootstrap interval."""
    low, high = metrics.bootstrap_mean_ci(values, base=base, rng=rng)
    return f"{100 * (values.mean() / base.mean() - 1):+.1f} % [{100 * low:+.1f}, {100 * high:+.1f}]"


def uiprmd_table(results: list[dict[str, Any]], episodes: list[str] | None = None) -> str:
    """The table of every method over the episodes (``episodes``: a subset of them): FPG
    Eq. 13 and MPJPE with their 95 % CIs and their changes against closed-form (paired CIs),
    root-relative and Procrustes-aligned MPJPE, jitter, the largest settled bone range over
    the episodes, the bone-length error against the truth, CPU ms per frame; learned rows pool
    the seeds (one row per seed below, when there are several)."""
    by = _by_method(results)
    order = sorted(by["closed-form"]) if episodes is None else sorted(episodes)
    rng = np.random.default_rng(2016)

    def figure(name: str, key: str) -> np.ndarray:
        return np.array([by[name][e][key] for e in order])

    lines = [
        "| method | evaluations/frame | Eq. 13 (m) [95 % CI] | vs closed-form [95 % CI] | "
        "MPJPE (m) [95 % CI] | vs closed-form [95 % CI] | root-relative MPJPE (m) | PA-MPJPE "
        "(m) | jitter (m/s²) | settled bone range, max (mm) | bone length error (mm) | CPU "
        "ms/frame |",
        "| --- | --- | --- | --- | --- | --- | --- | --- | --- | --- | --- | --- |",
    ]
    for name in by:
        cells = []
        for key in ("error", "mpjpe"):
            values, base = figure(name, key), figure("closed-form", key)
            lo, hi = metrics.bootstrap_mean_ci(values, rng=rng)
            cells += [f"{values.mean():.4f} [{lo:.4f}, {hi:.4f}]", change(values, base, rng)]
        cells += [
            f"{figure(name, 'mpjpe_root').mean():.4f}",
            f"{figure(name, 'mpjpe_pa').mean():.4f}",
            f"{figure(name, 'jitter').mean():.2f}",
            f"{np.nanmax(figure(name, 'spread_mm')):.1f}",
            f"{figure(name, 'bone_error_mm').mean():.1f}",
            f"{np.median(figure(name, 'cpu_ms')):.2f}",
        ]
        kind = name.split(" ")[0]
        lines.append(f"| {name} | {EVALUATIONS.get(kind, '200')} | " + " | ".join(cells) + " |")
    return "\n".join(lines)


def _subject_errors(result: dict[str, Any]) -> dict[str, dict[str, np.ndarray]]:
    """One fold's episode figures by method (seeds pooled): ``{method: {figure: (episodes,)}}``,
    episodes in the same (sorted) order for every method."""
    by = _by_method([result])
    return {
        name: {key: np.array([episodes[e][key] for e in sorted(episodes)]) for key in FIGURES}
        for name, episodes in by.items()
    }


SUBJECT_METHODS = ("closed-form", "local-search", "learned", "learned+search", "oracle-bones")


def uiprmd_subject_table(results: list[dict[str, Any]]) -> str:
    """Per held-out subject: closed-form's and ``learned:``'s Eq. 13 and MPJPE, ``learned:``'s
    changes against closed-form with their paired 95 % CIs over the subject's episodes, the
    jitter of both and ``learned:``'s largest settled bone range."""
    rng = np.random.default_rng(2016)
    lines = [
        "| held out | episodes | closed-form Eq. 13 (m) | learned Eq. 13 (m) | change [95 % CI] "
        "| closed-form MPJPE (m) | learned MPJPE (m) | change [95 % CI] | jitter closed-form "
        "→ learned (m/s²) | learned settled bone range, max (mm) |",
        "| --- | --- | --- | --- | --- | --- | --- | --- | --- | --- |",
    ]
    for result in sorted(results, key=lambda r: r["subject"]):
        errors = _subject_errors(result)
        base, learned = errors["closed-form"], errors.get("learned")
        if learned is None:
            continue
        cells = []
        for key in ("error", "mpjpe"):
            cells += [
                f"{base[key].mean():.4f}",
                f"{learned[key].mean():.4f}",
                change(learned[key], base[key], rng),
            ]
        lines.append(
            f"| {result['subject']} | {len(base['error'])} | {' | '.join(cells)} | "
            f"{base['jitter'].mean():.2f} → {learned['jitter'].mean():.2f} | "
            f"{np.nanmax(learned['spread_mm']):.1f} |"
        )
    return "\n".join(lines)


#: Disjoint sets of UI-PRMD repetitions (``eNN`` of a recording's name): the repetitions
#: scored stand in for seeds where training is deterministic.
REPETITION_SETS = (("e01", "e04", "e07", "e10"), ("e02", "e05", "e08"), ("e03", "e06", "e09"))


def repetition_table(results: list[dict[str, Any]]) -> str:
    """``learned:`` against closed-form (Eq. 13 and MPJPE, paired 95 % CIs) on each set of
    :data:`REPETITION_SETS` that has two episodes or more (empty when none has)."""
    by = _by_method(results)
    if "learned" not in by:
        return ""
    rng = np.random.default_rng(2016)
    lines = [
        "| repetitions | episodes | learned vs closed-form, Eq. 13 [95 % CI] | MPJPE [95 % CI] |",
        "| --- | --- | --- | --- |",
    ]
    for chosen in REPETITION_SETS:
        order = sorted(e for e in by["closed-form"] if e.rsplit("_", 1)[-1] in chosen)
        if len(order) < 2:
            continue
        cells = [
            change(
                np.array([by["learned"][e][key] for e in order]),
                np.array([by["closed-form"][e][key] for e in order]),
                rng,
            )
            for key in ("error", "mpjpe")
        ]
        lines.append(f"| {', '.join(chosen)} | {len(order)} | {' | '.join(cells)} |")
    return "\n".join(lines) if len(lines) > 2 else ""


def plot_subjects(results: list[dict[str, Any]], path: Path) -> Path:
    """A PNG of each held-out subject's mean error by method (:data:`SUBJECT_METHODS`), with
    95 % bootstrap intervals over the subject's episodes."""
    from matplotlib.backends.backend_agg import FigureCanvasAgg
    from matplotlib.figure import Figure

    rng = np.random.default_rng(2016)
    ordered = sorted(results, key=lambda r: r["subject"])
    folds = [_subject_errors(result) for result in ordered]
    figure = Figure(figsize=(max(6.0, 1.1 * len(ordered) + 2), 4.0))
    axes = figure.add_subplot()
    width = 0.8 / len(SUBJECT_METHODS)
    for k, method in enumerate(SUBJECT_METHODS):
        # Per subject: the mean and its interval's lower and upper reach (cm); NaN: no row.
        bars = np.full((len(folds), 3), np.nan)
        for i, errors in enumerate(folds):
            if method in errors:
                values = errors[method]["error"]
                low, high = metrics.bootstrap_mean_ci(values, rng=rng)
                bars[i] = 100 * np.array([values.mean(), values.mean() - low, high - values.mean()])
        x = np.arange(len(folds)) + (k - (len(SUBJECT_METHODS) - 1) / 2) * width
        axes.bar(x, bars[:, 0], width, label=method)
        axes.errorbar(x, bars[:, 0], yerr=np.nan_to_num(bars[:, 1:].T), fmt="none", ecolor="k",
                      elinewidth=0.8, capsize=2)  # fmt: skip
    axes.set_xticks(np.arange(len(ordered)), [r["subject"] for r in ordered])
    axes.set_xlabel("held-out subject")
    axes.set_ylabel("mean error, FPG Eq. 13 (cm)")
    axes.set_title("UI-PRMD, leave subjects out (95 % CI over episodes)")
    axes.legend(fontsize=8, ncols=len(SUBJECT_METHODS), loc="upper center",
                bbox_to_anchor=(0.5, -0.14))  # fmt: skip
    figure.tight_layout()
    FigureCanvasAgg(figure)
    figure.savefig(path, dpi=110)
    return path

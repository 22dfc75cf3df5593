"""Aggregates of a comparison: per-method means, per-scenario and per-joint tables, and the
paired Wilcoxon tests against the baseline (``summary.json``)."""

from __future__ import annotations

import math
import warnings
from collections.abc import Sequence
from datetime import datetime, timezone
from pathlib import Path
from typing import Any

import numpy as np

from fpg_gym.core import metrics, skeleton
from fpg_gym.experiments.store import FrameFiles, read_config, read_rows
from fpg_gym.methods import BASELINE


def _num(value: Any) -> float:
    try:
        return float(value)
    except (TypeError, ValueError):
        return float("nan")


def _max_column(rows: Sequence[dict[str, str]], column: str) -> float | None:
    """Largest finite value of a CSV column (None without one; older files lack the column)."""
    values = np.array([_num(r.get(column)) for r in rows])
    values = values[np.isfinite(values)]
    return float(values.max()) if values.size else None


def _paired_test(rows: dict[str, dict[str, float]], method: str, baseline: str) -> dict[str, Any]:
    """Wilcoxon signed-rank test of per-episode mean errors, ``method`` vs ``baseline``."""
    from scipy.stats import wilcoxon

    mine, base = rows.get(method, {}), rows.get(baseline, {})
    common = sorted(
        e for e in set(mine) & set(base) if math.isfinite(mine[e]) and math.isfinite(base[e])
    )
    result: dict[str, Any] = {
        "paired_episodes": len(common),
        "mean_difference_m": None,
        "lower_error_episodes": None,
        "wilcoxon_p": None,
        "note": "",
    }
    if not common:
        result["note"] = "no paired episodes"
        return result
    x = np.array([mine[e] for e in common])
    y = np.array([base[e] for e in common])
    diff = x - y
    result["mean_difference_m"] = float(diff.mean())
    result["lower_error_episodes"] = int(np.sum(diff < 0))
    if method == baseline:
        result["note"] = "baseline"
        return result
    nonzero = diff[diff != 0]
    if len(nonzero) < 2:
        result["note"] = "too few episodes that differ"
        return result
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        try:
            test = wilcoxon(x, y, zero_method="wilcox", alternative="two-sided")
        except ValueError as error:  # e.g. every difference zero
            result["note"] = str(error)
            return result
    result["wilcoxon_p"] = float(test.pvalue)
    if len(nonzero) < 6:
        result["note"] = f"only {len(nonzero)} differing episodes: p cannot fall below 0.05"
    return result


def summarise(out: str | Path, baseline: str = BASELINE.name) -> dict[str, Any]:
    """Aggregate ``results.csv`` and the per-frame files of a compare folder.

    Rows of interrupted tasks are left out. Returns the structure written to ``summary.json``.
    """
    out = Path(out)
    return summarise_frames(out, baseline, FrameFiles(out))


def _mapping(value: Any) -> dict[str, Any]:
    """``value`` if it is a dict, else an empty one (a damaged config.json)."""
    return value if isinstance(value, dict) else {}


def _sequence(value: Any) -> list[Any]:
    """``value`` if it is a list, else an empty one (a damaged config.json)."""
    return value if isinstance(value, list) else []


def _per_joint(parts: list[tuple[np.ndarray, int]]) -> dict[str, float] | None:
    """A per-joint mean over episodes, weighted by their frames, by joint name."""
    if not parts:
        return None
    mean = np.sum([j * n for j, n in parts], axis=0) / sum(n for _, n in parts)
    return dict(zip(skeleton.JOINT_NAMES, mean.tolist(), strict=True))


def _method_summary(method: str, mine: list[dict[str, str]], files: FrameFiles) -> dict[str, Any]:
    """One method's entry of the summary from its rows (``mine``) and their per-frame files."""
    errors, ms, joints, root_joints, mpjpe_joints = [], [], [], [], []
    stage_sums: dict[str, list[np.ndarray]] = {}
    for r in mine:
        frames = files.get(r["episode"], method)
        if frames is None:
            continue
        if "errors" in frames:
            errors.append(frames["errors"])
            joints.append((frames["per_joint_error"], len(frames["errors"])))
            if "per_joint_root_error" in frames:
                root_joints.append((frames["per_joint_root_error"], len(frames["errors"])))
            if "per_joint_mpjpe" in frames:
                mpjpe_joints.append((frames["per_joint_mpjpe"], len(frames["errors"])))
        ms.append(frames["ms"])
        for i, stage in enumerate(frames["stage_names"]):
            stage_sums.setdefault(str(stage), []).append(frames["stage_ms"][:, i])
    episode_err02 = np.array([_num(r["err02_pct"]) for r in mine])
    episode_err02 = episode_err02[np.isfinite(episode_err02)]
    all_errors = np.concatenate(errors) if errors else np.zeros(0)
    all_ms = np.concatenate(ms) if ms else np.zeros(0)
    weights = np.array([_num(r["frames"]) for r in mine])

    def weighted(column: str, rows_: list[dict[str, str]] = mine, w: np.ndarray = weights) -> Any:
        values = np.array([_num(r.get(column, "")) for r in rows_])
        use = np.isfinite(values) & (w > 0)
        return float(np.average(values[use], weights=w[use])) if use.any() else None

    entry: dict[str, Any] = {
        "episodes": len(mine),
        "frames": int(np.nansum(weights)),
        "mean_error_m": float(all_errors.mean()) if all_errors.size else None,
        "std_error_m": float(all_errors.std()) if all_errors.size else None,
        "median_error_m": float(np.median(all_errors)) if all_errors.size else None,
        "err02_pct": (
            {
                "min": float(episode_err02.min()),
                "mean": float(episode_err02.mean()),
                "max": float(episode_err02.max()),
                "pooled": 100.0 * metrics.err_ratio(all_errors),
            }
            if episode_err02.size and all_errors.size
            else None
        ),
        "band_shares": (metrics.band_shares(all_errors).tolist() if all_errors.size else None),
        "bone_length_spread_mm": weighted("bone_length_spread_mm"),
        "jitter_ms2": weighted("jitter_ms2"),
        "lag_frames": weighted("lag_frames"),
        "lag_ms": weighted("lag_ms"),
        "settled_bone_spread_mm": _max_column(mine, "settled_bone_spread_mm"),
        "ms_per_frame": metrics.time_summary(all_ms) if all_ms.size else None,
        "stage_ms_median": {s: float(np.median(np.concatenate(v))) for s, v in stage_sums.items()},
        "evaluations_per_frame": weighted("evaluations_mean"),
        "mean_energy": weighted("energy_mean"),
        "per_joint_error_m": (
            dict(
                zip(
                    skeleton.JOINT_NAMES,
                    (
                        np.sum([j * n for j, n in joints], axis=0) / sum(n for _, n in joints)
                    ).tolist(),
                    strict=True,
                )
            )
            if joints
            else None
        ),
        "per_joint_root_error_m": _per_joint(root_joints),
        "per_joint_mpjpe_m": _per_joint(mpjpe_joints),
        "mpjpe_m": weighted("mpjpe_m"),
        "root_mpjpe_m": weighted("root_mpjpe_m"),
        "pa_mpjpe_m": weighted("pa_mpjpe_m"),
        "visible_mpjpe_m": weighted("visible_mpjpe_m"),
        "occluded_mpjpe_m": weighted(
            "occluded_mpjpe_m",
            mine,
            np.array([_num(r.get("occluded_joint_frames", "")) for r in mine]),
        ),
        "input_mpjpe_m": weighted("input_mpjpe_m"),
        "bone_length_error_mm": weighted("bone_length_error_mm"),
        "per_scenario_mean_error_m": {},
    }
    for scenario in sorted({r["scenario"] for r in mine}):
        subset = [r for r in mine if r["scenario"] == scenario]
        entry["per_scenario_mean_error_m"][scenario or "(recording)"] = weighted(
            "mean_error_m", subset, np.array([_num(r["frames"]) for r in subset])
        )
    return entry


def summarise_frames(out: Path, baseline: str, files: FrameFiles) -> dict[str, Any]:
    rows = [r for r in read_rows(out / "results.csv") if r.get("interrupted") in ("0", "")]
    latest: dict[tuple[str, str], dict[str, str]] = {}
    for row in rows:  # a task rerun after an interruption: the last row counts
        latest[(row["episode"], row["method"])] = row
    rows = list(latest.values())
    config = read_config(out / "config.json") or {}
    settings = _mapping(config.get("config"))
    order = [str(m) for m in _sequence(settings.get("methods"))]
    # The report covers this run's methods and episodes: rows that an earlier run into the same
    # folder left (other --methods, other inputs) stay in results.csv, counted apart.
    episode_ids = {str(_mapping(e).get("id")) for e in _sequence(config.get("episodes"))}
    every = len(rows)
    if order and episode_ids:
        rows = [r for r in rows if r["method"] in order and r["episode"] in episode_ids]
    for row in rows:
        if row["method"] not in order:
            order.append(row["method"])
    methods = [m for m in order if any(r["method"] == m for r in rows)]
    episodes = sorted({r["episode"] for r in rows})
    if baseline not in methods and methods:
        fallback = next((m for m in methods if m.startswith("fpg:local-search")), methods[0])
        baseline = fallback
    per_episode_error: dict[str, dict[str, float]] = {}
    result: dict[str, Any] = {}
    for method in methods:
        mine = [r for r in rows if r["method"] == method]
        per_episode_error[method] = {r["episode"]: _num(r["mean_error_m"]) for r in mine}
        result[method] = _method_summary(method, mine, files)
    for method in methods:
        result[method]["vs_baseline"] = _paired_test(per_episode_error, method, baseline)
    truth_rows = [r for r in rows if r["method"] == (methods[0] if methods else "")]
    truth_jitter = np.array([_num(r["truth_jitter_ms2"]) for r in truth_rows])
    truth_jitter = truth_jitter[np.isfinite(truth_jitter)]
    input_error = np.array([_num(r["input_mean_error_m"]) for r in truth_rows])
    input_error = input_error[np.isfinite(input_error)]
    return {
        "generated": datetime.now(timezone.utc).isoformat(timespec="seconds"),
        "baseline": baseline,
        "methods": result,
        "method_order": methods,
        "episodes": episodes,
        "scenarios": sorted({r["scenario"] for r in rows}),
        "clips": sorted({r["clip"] for r in rows}),
        "ground_truth_jitter_ms2": float(truth_jitter.mean()) if truth_jitter.size else None,
        "input_mean_error_m": float(input_error.mean()) if input_error.size else None,
        "config": settings,
        "rows_not_reported": every - len(rows),
        "graph": config.get("graph_summary", ""),
        "graph_exclude": config.get("graph_exclude", []),
        "held_out_warning": config.get("held_out_warning", ""),
    }

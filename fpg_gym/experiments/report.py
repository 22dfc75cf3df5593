"""A comparison's report: the tables (FPG §8 style), ``report.md`` and the plots."""

from __future__ import annotations

import json
import math
from collections.abc import Callable, Sequence
from pathlib import Path
from typing import Any

import numpy as np

from fpg_gym.core import skeleton
from fpg_gym.core.jsonable import jsonable
from fpg_gym.core.outputs import write_text
from fpg_gym.experiments import plots
from fpg_gym.experiments.stats import summarise_frames
from fpg_gym.experiments.store import FrameFiles
from fpg_gym.methods import BASELINE

#: Columns of the main table of ``report.md`` (and of what ``compare``/``demo`` print).
TABLE_COLUMNS: tuple[str, ...] = (
    "method",
    "episodes",
    "mean error (m) ± std",
    "MPJPE (m)",
    "root-rel. / PA-MPJPE (m)",
    "occluded / visible MPJPE (m)",
    "bone-length error (mm)",
    "Err0.2 (%) min / mean / max",
    "bone-length spread (mm)",
    "jitter (m/s²)",
    "lag (frames)",
    "bone spread after 1 s, max (mm)",
    "ms/frame median / p95",
    "evaluations/frame",
    "mean energy",
)


#: Columns of the paired-test table.
TEST_COLUMNS: tuple[str, ...] = (
    "method",
    "paired episodes",
    "mean error − baseline (m)",
    "lower error in",
    "Wilcoxon p",
)


def _fmt(value: Any, digits: int = 3) -> str:
    if value is None or (isinstance(value, float) and not math.isfinite(value)):
        return "–"
    return f"{value:.{digits}f}"


def table_rows(summary: dict[str, Any]) -> list[list[str]]:
    """The main table's cells, one list per method (columns of :data:`TABLE_COLUMNS`)."""
    rows = []
    for name in summary["method_order"]:
        m = summary["methods"][name]
        error = (
            f"{m['mean_error_m']:.3f} ± {m['std_error_m']:.3f}"
            if m["mean_error_m"] is not None
            else "–"
        )
        err = m["err02_pct"]
        err_text = f"{err['min']:.1f} / {err['mean']:.1f} / {err['max']:.1f}" if err else "–"
        ms = m["ms_per_frame"]
        ms_text = f"{ms['median']:.2f} / {ms['p95']:.2f}" if ms else "–"
        label = f"**{name}**" if name == summary["baseline"] else name
        rows.append(
            [
                label,
                str(m["episodes"]),
                error,
                _fmt(m.get("mpjpe_m")),
                f"{_fmt(m.get('root_mpjpe_m'))} / {_fmt(m.get('pa_mpjpe_m'))}",
                f"{_fmt(m.get('occluded_mpjpe_m'))} / {_fmt(m.get('visible_mpjpe_m'))}",
                _fmt(m.get("bone_length_error_mm"), 1),
                err_text,
                _fmt(m["bone_length_spread_mm"], 1),
                _fmt(m["jitter_ms2"], 1),
                _fmt(m.get("lag_frames"), 2),
                _fmt(m.get("settled_bone_spread_mm"), 1),
                ms_text,
                _fmt(m["evaluations_per_frame"], 0),
                _fmt(m["mean_energy"], 4),
            ]
        )
    return rows


def markdown_table(columns: Sequence[str], rows: Sequence[Sequence[str]]) -> str:
    """A markdown table: a header row of ``columns``, a ``---`` row, then ``rows`` (cells as
    given)."""
    lines = ["| " + " | ".join(columns) + " |", "|" + "|".join(" --- " for _ in columns) + "|"]
    lines += ["| " + " | ".join(row) + " |" for row in rows]
    return "\n".join(lines)


def format_table(summary: dict[str, Any]) -> str:
    """The main table (markdown) of a summary (:func:`summarise`)."""
    return markdown_table(TABLE_COLUMNS, table_rows(summary))


def format_tests(summary: dict[str, Any]) -> str:
    """The paired-test table (markdown): each method against the baseline."""
    rows = []
    for name in summary["method_order"]:
        test = summary["methods"][name]["vs_baseline"]
        if name == summary["baseline"]:
            continue
        n = test["paired_episodes"]
        p = test["wilcoxon_p"]
        p_text = f"{p:.3g}" if p is not None else "–"
        if test["note"]:
            p_text += f" ({test['note']})"
        rows.append(
            [
                name,
                str(n),
                (
                    f"{test['mean_difference_m']:+.4f}"
                    if test["mean_difference_m"] is not None
                    else "–"
                ),
                f"{test['lower_error_episodes']} of {n}" if n else "–",
                p_text,
            ]
        )
    return markdown_table(TEST_COLUMNS, rows)


def format_scenarios(summary: dict[str, Any]) -> str:
    """Mean error per scenario (rows) and method (columns), markdown."""
    methods = summary["method_order"]
    scenarios = sorted(
        {s for m in methods for s in summary["methods"][m]["per_scenario_mean_error_m"]}
    )
    rows = [
        [s] + [_fmt(summary["methods"][m]["per_scenario_mean_error_m"].get(s)) for m in methods]
        for s in scenarios
    ]
    return markdown_table(["scenario", *methods], rows)


def format_joints(summary: dict[str, Any], limit: int = 8) -> str:
    """Markdown table of each joint's error (cm), one column per method (the first ``limit``
    methods): absolute (MPJPE's), root-relative, and the Eq. 13 term of the bone ending at it
    in parentheses; empty when no method has ground truth."""
    methods = [
        m for m in summary["method_order"] if summary["methods"][m].get("per_joint_root_error_m")
    ][:limit]
    if not methods:
        return ""
    rows = []
    for joint in skeleton.JOINT_NAMES:
        cells = []
        for m in methods:
            entry = summary["methods"][m]
            root = entry["per_joint_root_error_m"][joint]
            absolute = (entry.get("per_joint_mpjpe_m") or {}).get(joint)
            bone = (entry.get("per_joint_error_m") or {}).get(joint)
            text = f"{100 * absolute:.1f} / " if absolute is not None else ""
            text += f"{100 * root:.1f}"
            if bone is not None and math.isfinite(bone):
                text += f" ({100 * bone:.1f})"
            cells.append(text)
        rows.append([joint, *cells])
    return markdown_table(["joint", *methods], rows)


def _plot_methods(summary: dict[str, Any], limit: int = 6) -> list[str]:
    """Methods for the per-episode time plot: raw, the baseline, then the most accurate."""
    methods = summary["method_order"]
    if len(methods) <= limit:
        return list(methods)
    chosen = [m for m in ("raw", summary["baseline"]) if m in methods]
    ranked = sorted(
        (
            m
            for m in methods
            if m not in chosen and summary["methods"][m]["mean_error_m"] is not None
        ),
        key=lambda m: summary["methods"][m]["mean_error_m"],
    )
    chosen += ranked[: limit - len(chosen)]
    return [m for m in methods if m in chosen]


def _write_plots(
    out: Path, summary: dict[str, Any], files: FrameFiles, claim: Callable[[Path], None]
) -> dict[str, str]:
    """Write the plots the summary has data for (``claim`` each file first); their names."""

    methods = summary["method_order"]
    errors: dict[str, np.ndarray] = {}
    ms: dict[str, np.ndarray] = {}
    for method in methods:
        e, t = [], []
        for episode in summary["episodes"]:
            frames = files.get(episode, method)
            if frames is not None:
                if "errors" in frames:
                    e.append(frames["errors"])
                t.append(frames["ms"])
        if e:
            errors[method] = np.concatenate(e)
        if t:
            ms[method] = np.concatenate(t)
    written: dict[str, str] = {}
    colours = plots.method_colours(methods)
    if errors:
        written["error_histogram"] = plots.plot_error_histogram(
            errors, _claimed(out / "error_histogram.png", claim), colours=colours
        ).name
        written["cumulative"] = plots.plot_cumulative(
            errors, _claimed(out / "cumulative.png", claim), colours=colours
        ).name
        chosen = _plot_methods(summary)
        episode, series = _time_plot_series(summary, chosen, files)
        if episode:
            written["error_over_time"] = plots.plot_error_over_time(
                series,
                _claimed(out / "error_over_time.png", claim),
                title=f"Per-frame error, episode {episode}",
                colours=colours,
            ).name
            summary["time_plot_episode"] = episode
    if ms:
        written["frame_times"] = plots.plot_frame_times(
            ms, _claimed(out / "frame_times.png", claim), colours=colours
        ).name
    return written


def _time_plot_series(
    summary: dict[str, Any], methods: Sequence[str], files: FrameFiles
) -> tuple[str, dict[str, np.ndarray]]:
    """The first episode that every plotted method finished with ground truth, and the methods'
    per-frame errors on it (``""`` and nothing when there is none)."""
    for episode in summary["episodes"]:
        series: dict[str, np.ndarray] = {}
        for method in methods:
            frames = files.get(episode, method)
            if frames is None or "errors" not in frames:
                break
            series[method] = frames["errors"]
        else:
            return str(episode), series
    return "", {}


def _claimed(path: Path, claim: Callable[[Path], None]) -> Path:
    """``path``, after ``claim(path)`` (compare lists it in its manifest before writing it)."""
    claim(path)
    return path


def write_report(
    out: str | Path,
    *,
    plots: bool = True,
    baseline: str = BASELINE.name,
    interrupted: bool = False,
    claim: Callable[[Path], None] | None = None,
) -> dict[str, Any]:
    """Write ``summary.json``, ``report.md`` and the plots of a compare folder from its files.

    Works on a partial run (only finished rows count; ``interrupted`` says so in the report).
    ``claim`` is called with each file before it is written (compare's manifest). Returns the
    summary; ``summary["plots"]`` names the plots written (none with ``plots=False``).
    """
    out = Path(out)
    claim = claim or (lambda _path: None)
    files = FrameFiles(out)
    summary = summarise_frames(out, baseline, files)
    summary["interrupted"] = bool(interrupted)
    summary["plots"] = (
        _write_plots(out, summary, files, claim) if plots and summary["method_order"] else {}
    )
    write_text(_claimed(out / "summary.json", claim), json.dumps(jsonable(summary), indent=2))
    write_text(_claimed(out / "report.md", claim), report_markdown(summary))
    return summary


def _report_header(summary: dict[str, Any]) -> list[str]:
    """The report's first lines: the version, the graph, the episodes and the run's settings."""
    config = summary.get("config", {})
    return [
        "# fpg-gym compare",
        "",
        f"Generated {summary['generated']} (fpg-gym "
        f"{__import__('fpg_gym').__version__}). Graph: `{config.get('graph', '?')}` "
        f"{summary.get('graph', '')}"
        + (
            f", built without the evaluated embedded clips {', '.join(summary['graph_exclude'])}"
            if summary.get("graph_exclude")
            else ""
        )
        + ".",
        "",
        f"{len(summary['episodes'])} episodes: clips {', '.join(summary['clips'])}; scenarios "
        f"{', '.join(s or '(recording)' for s in summary['scenarios'])}; seeds "
        f"{', '.join(str(s) for s in config.get('seeds', []))}"
        + (f"; at most {config['max_frames']} frames each" if config.get("max_frames") else "")
        + f". Budget {config.get('budget', '?')} evaluations per frame, K = "
        f"{config.get('k', '?')}; {config.get('workers', 1)} worker process(es)"
        + (
            f", up to {config['batch']} episodes side by side"
            if int(config.get("batch", 1)) > 1
            else ""
        )
        + (" on Ray" if config.get("backend") == "ray" else "")
        + ".",
        "",
    ]


def report_markdown(summary: dict[str, Any]) -> str:
    """The text of ``report.md``."""
    lines = _report_header(summary)
    if summary.get("held_out_warning"):
        lines += [f"**Warning:** {summary['held_out_warning']}.", ""]
    if summary.get("interrupted"):
        lines += ["**Interrupted:** the tables cover the finished runs only.", ""]
    if summary.get("rows_not_reported"):
        lines += [
            f"`results.csv` also holds {summary['rows_not_reported']} row(s) of earlier runs "
            "into this folder with other methods or episodes; they are not in this report.",
            "",
        ]
    if not summary["method_order"]:
        lines += ["No finished runs.", ""]
        return "\n".join(lines)
    truth_jitter = summary.get("ground_truth_jitter_ms2")
    lines += [
        "## Results",
        "",
        format_table(summary),
        "",
        "Mean error: FPG Eq. 13 (mean over the 19 bones of the bone-vector error) over all "
        "frames, ± its standard deviation over frames. MPJPE: mean distance of each joint to "
        "the ground truth in the space both share (absolute); root-relative: once both have "
        "their HipCenter at the origin; PA: after the best similarity transform of each frame "
        "(Procrustes); occluded / visible: the joints the recording marks as hidden (or "
        "mislabelled) and the others. Bone-length error: mean absolute difference of each "
        "bone's length from the truth's, over bones, frames and episodes. Err0.2: share of "
        "frames with error ≥ 0.2 m, min / mean / max over episodes. Bone-length spread: "
        "standard deviation of each bone's length over an episode, mean over bones and "
        "episodes. Jitter: mean acceleration magnitude over joints and frames"
        + (f" (ground truth: {truth_jitter:.1f} m/s²)" if truth_jitter is not None else "")
        + ". Lag: the shift (frames) that best aligns the output with the ground truth "
        "(`fpg_gym.core.metrics.lag`), mean over episodes; positive is late. Bone spread after "
        "1 s: the largest range (max − min) of a bone's length after the first second of an "
        "episode "
        "(`fpg_gym.core.metrics.settled_bone_spread`), max over bones and episodes. ms/frame: "
        "computation time of one frame on this machine, ragdoll included, "
        "median / 95th percentile (noisy when workers share cores; with episodes side by "
        "side, a frame's search counts its share of the batched energy evaluations). "
        "Evaluations and energy "
        f"(Shum Eq. 10, lower is better): reconstruction methods only. Bold: the baseline "
        f"`{summary['baseline']}`.",
        "",
        f"## Paired test against `{summary['baseline']}`",
        "",
        format_tests(summary),
        "",
        "Per-episode mean errors, paired by episode; two-sided Wilcoxon signed-rank test "
        "(`scipy.stats.wilcoxon`, zero differences dropped). A negative difference means "
        "lower error than the baseline.",
        "",
        "## Mean error (m) per scenario",
        "",
        format_scenarios(summary),
        "",
    ]
    joints = format_joints(summary)
    if joints:
        lines += [
            "## Error per joint (cm)",
            "",
            joints,
            "",
            "Absolute error (MPJPE's term) / root-relative error (distance of each joint to the "
            "ground truth once both have their HipCenter at the origin), mean over frames; in "
            "brackets the FPG Eq. 13 summand (the error of the bone that ends at the joint).",
            "",
        ]
    plots = summary.get("plots", {})
    if plots:
        lines += ["## Plots", ""]
        captions = {
            "error_histogram": "Share of frames per error band (FPG §8)",
            "cumulative": "Frames with error above a threshold (FPG Fig. 7)",
            "error_over_time": f"Per-frame error over episode {summary.get('time_plot_episode')}",
            "frame_times": "Computation time per frame",
        }
        for key, name in plots.items():
            lines += [f"![{captions.get(key, key)}]({name})", ""]
    lines += ["## Episodes", "", ", ".join(f"`{e}`" for e in summary["episodes"]), ""]
    return "\n".join(lines)

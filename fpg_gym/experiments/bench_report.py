"""``fpg-gym bench``'s report as markdown tables (:func:`format_bench`), one function per
section of :func:`fpg_gym.experiments.bench.run_bench`'s report.
"""

from __future__ import annotations

from collections.abc import Callable
from typing import Any

from fpg_gym.experiments import markdown_table

__all__ = ["format_bench"]


def format_bench(report: dict[str, Any]) -> str:
    """The bench report as markdown tables (what ``fpg-gym bench`` prints)."""
    out = [
        f"fpg-gym bench, {report['date']}, {report['machine']}; data: {report.get('data', '?')}; "
        f"BLAS threads: {report.get('blas_threads', '?')}; energy kernels: "
        f"{', '.join(report.get('energy_kernels', []))}",
        "",
    ]
    for section in _SECTIONS:
        out += section(report)
    state = " (interrupted)" if report.get("interrupted") else ""
    out.append(f"bench time {report['seconds']:.1f} s{state}")
    return "\n".join(out)


def _stages_section(report: dict[str, Any]) -> list[str]:
    """Frame time per stage and CPU time per frame."""
    if "stages" not in report:
        return []
    out: list[str] = []
    stage_rows = [r for r in report["stages"] if "graph_median_ms" in r]
    cpu_rows = [r for r in report["stages"] if "graph_median_ms" not in r]
    out += [
        f"Frame time per stage (ms; local search, ragdoll; {report['settings']['episodes']} "
        f"episode(s) of <= {report['settings']['max_frames']} frames; "
        f"{report['stages_graph']})",
        "",
        markdown_table(
            ["stage", "graph median", "graph p95", "brute-force median", "brute-force p95"],
            [
                [
                    r["stage"],
                    f"{r['graph_median_ms']:.3f}",
                    f"{r['graph_p95_ms']:.3f}",
                    f"{r['brute-force_median_ms']:.3f}",
                    f"{r['brute-force_p95_ms']:.3f}",
                ]
                for r in stage_rows
            ],
        ),
        "",
    ]
    if cpu_rows:
        cpu = cpu_rows[0]
        out += [
            "CPU time per frame (mean, time.process_time): "
            f"graph {cpu.get('graph_cpu_ms', float('nan')):.3f} ms, "
            f"brute-force {cpu.get('brute-force_cpu_ms', float('nan')):.3f} ms; "
            f"graph without the ragdoll {cpu.get('graph-no-ragdoll_cpu_ms', float('nan')):.3f}"
            " ms",
            "",
        ]
    return out


def _stages_quality_section(report: dict[str, Any]) -> list[str]:
    """The output of the stage runs (error, jitter, lag, bone spread)."""
    if not report.get("stages_quality"):
        return []
    return [
        "Output of the same runs (FPG Eq. 13 error, jitter = mean acceleration, lag against "
        "the ground truth, largest bone-length range after the first second)",
        "",
        markdown_table(
            [
                "selector",
                "mean error (m)",
                "Err0.2 (%)",
                "jitter (m/s²)",
                "lag (frames)",
                "bone spread after 1 s (mm)",
            ],
            [
                [
                    selector,
                    _cell(q["mean_error_m"], 3),
                    _cell(q["err02_pct"], 1),
                    _cell(q["jitter_ms2"], 1),
                    _cell(q["lag_frames"], 2),
                    _cell(q["settled_bone_spread_mm"], 1),
                ]
                for selector, q in report["stages_quality"].items()
            ],
        ),
        "",
    ]


def _cell(value: float | None, digits: int) -> str:
    """A table cell: the value with ``digits`` decimals, a dash for None."""
    return "–" if value is None else f"{value:.{digits}f}"


def _kernels_section(report: dict[str, Any]) -> list[str]:
    """The energy kernels, the frame without ragdoll, the search alone, the floor."""
    if "kernels" not in report:
        return []
    out: list[str] = []
    kernels = report["kernels"]
    floor = kernels["floor"]
    out += [
        "Energy of 100 latent points of a real frame (CPU µs, median; interleaved)",
        "",
        markdown_table(
            ["kernel", "µs / 100 points", "speed-up vs direct"],
            [
                [r["kernel"], f"{r['us_per_100_points']:.1f}", f"{r['speedup_vs_direct']:.1f}x"]
                for r in kernels["energy"]
            ],
        ),
        "",
        "Frame without ragdoll: graph selection + local search, 2,000 evaluations (CPU ms "
        "per frame, mean; search stage wall median)",
        "",
        markdown_table(
            ["configuration", "CPU ms / frame", "search wall median ms", "speed-up vs direct"],
            [
                [
                    r["configuration"],
                    f"{r['cpu_ms_per_frame']:.3f}",
                    f"{r['search_wall_median_ms']:.3f}",
                    f"{r['speedup_vs_direct']:.2f}x",
                ]
                for r in kernels["frame"]
            ],
        ),
        "",
        "Local search alone, 2,000 evaluations (CPU ms per search, mean over recorded "
        "frame problems; results compared)",
        "",
        markdown_table(
            ["proposals", "problems", "ask/tell loop ms", "compiled ms", "speed-up", "differ"],
            [
                [
                    r["proposals"],
                    str(r["problems"]),
                    f"{r['loop_ms']:.3f}",
                    f"{r['compiled_ms']:.3f}",
                    f"{r['loop_ms'] / r['compiled_ms']:.2f}x",
                    str(r["differ"]),
                ]
                for r in kernels.get("search", [])
            ],
        ),
        "",
        f"Arithmetic floor of a frame's search: {floor['mflop']:.2f} MFLOP for "
        f"{floor['evaluations']} evaluations at {floor['gemm_gflops']:.1f} GFLOP/s (this "
        f"machine's (100 x d) x (d x cols) product) = {floor['floor_ms']:.3f} ms",
        "",
    ]
    return out


def _selection_section(report: dict[str, Any]) -> list[str]:
    """Selection per frame against graph size."""
    if "selection" not in report:
        return []
    return [
        "Selection per frame against graph size (CPU ms, median; p95 of the walk; nodes "
        "scored by the walk; auto: frames it searched all nodes)",
        "",
        markdown_table(
            [
                "thres1 (m)",
                "nodes",
                "mean degree",
                "graph walk",
                "walk p95",
                "walk scored",
                "auto",
                "auto full",
                "brute force (exact)",
                "brute force (direct)",
                "exact speed-up",
            ],
            [
                [
                    f"{r['thres1']:g}",
                    str(r["nodes"]),
                    f"{r['mean_degree']:.1f}",
                    f"{r['graph_ms']:.3f}",
                    f"{r['graph_p95_ms']:.3f}",
                    f"{r['graph_scored']:.0f}",
                    f"{r['auto_ms']:.3f}",
                    f"{r['auto_full_searches']}/{r['queries']}",
                    f"{r['brute_gemv_ms']:.3f}",
                    f"{r['brute_direct_ms']:.3f}",
                    f"{r['gemv_speedup']:.1f}x",
                ]
                for r in report["selection"]
            ],
        ),
        "",
    ]


def _streams_section(report: dict[str, Any]) -> list[str]:
    """Many streams side by side against one by one."""
    if "streams" not in report:
        return []
    out: list[str] = []
    rows = report["streams"]
    out += [
        f"Many streams: {rows[0]['streams']} recordings, {rows[0]['frames']} frames, local "
        "search, no ragdoll (CPU time, median of interleaved rounds; largest output "
        f"difference side by side vs alone: {rows[0]['max_difference_m']:.3g} m)",
        "",
        markdown_table(
            ["run", "CPU s", "frames / CPU-s", "vs one by one"],
            [
                [
                    r["run"],
                    f"{r['cpu_s']:.2f}",
                    f"{r['frames_per_cpu_s']:.0f}",
                    f"{r['ratio']:.2f}x",
                ]
                for r in rows
            ],
        ),
        "",
    ]
    return out


def _build_section(report: dict[str, Any]) -> list[str]:
    """Graph build time against input size."""
    if "build" not in report:
        return []
    return [
        "Graph build time (FPG Alg. 1-4) against input size",
        "",
        markdown_table(
            ["clips", "mirror", "poses", "nodes", "edges", "seconds", "poses/s"],
            [
                [
                    str(r["clips"]),
                    "yes" if r["mirror"] else "no",
                    str(r["poses"]),
                    str(r["nodes"]),
                    str(r["edges"]),
                    f"{r['seconds']:.3f}",
                    f"{r['poses_per_second']:.0f}",
                ]
                for r in report["build"]
            ],
        ),
        "",
    ]


def _env_section(report: dict[str, Any]) -> list[str]:
    """Environment throughput."""
    if "env" not in report:
        return []
    out: list[str] = []
    rows = []
    for r in report["env"]:
        sps, only = r.get("steps_per_second"), r.get("step_only_per_second")
        per_cpu = r.get("steps_per_cpu_second")
        rows.append(
            [
                str(r["source"]),
                "–" if sps is None else f"{sps:.1f}",
                "–" if per_cpu is None else f"{per_cpu:.1f}",
                "–" if only is None else f"{only:.1f}",
            ]
        )
    out += [
        "Environment throughput (resets included; step calls only)",
        "",
        markdown_table(["measured by", "steps/s", "steps / CPU s", "step-only steps/s"], rows),
        "",
    ]
    return out


def _read_section(report: dict[str, Any]) -> list[str]:
    """Mocap read speed."""
    if "read" not in report:
        return []
    return [
        "Mocap read speed",
        "",
        markdown_table(
            ["source", "frames", "seconds", "frames/s"],
            [
                [
                    r["source"],
                    str(r["frames"]),
                    f"{r['seconds']:.3f}",
                    f"{r['frames_per_second']:.0f}",
                ]
                for r in report["read"]
            ],
        ),
        "",
    ]


#: The report's sections, in order (each empty when its part was not measured).
_SECTIONS: tuple[Callable[[dict[str, Any]], list[str]], ...] = (
    _stages_section,
    _stages_quality_section,
    _kernels_section,
    _selection_section,
    _streams_section,
    _build_section,
    _env_section,
    _read_section,
)

"""``fpg-gym reconstruct``: reconstruct a Kinect recording against a pose graph."""

from __future__ import annotations

import argparse
import itertools
import json
import time
from pathlib import Path
from typing import Any

from fpg_gym.commands import types
from fpg_gym.io.kinect import KINECT_FORMATS  # loaded with the CLI (fpg_gym.io.plausibility)

NAME = "reconstruct"
HELP = (
    "reconstruct a Kinect recording (graph or brute-force selection, an optimiser, ragdoll), "
    "or run a reference filter on it (--method raw|holt|kalman)"
)

#: Bin edges (metres) of the printed error histogram.
HISTOGRAM_EDGES: tuple[float, ...] = (0.0, 0.05, 0.1, 0.15, 0.2, 0.3, 0.5)


def add_arguments(parser: argparse.ArgumentParser) -> None:
    """Register the command's arguments."""
    parser.add_argument(
        "--graph",
        metavar="FILE",
        help="pose graph .npz, or a name: 'default' (the input sensor's default database: "
        "'uiprmd' for a Kinect v2, else 'embedded'), 'embedded' (DeepMimic clips), 'uiprmd' "
        "(packaged UI-PRMD joint centres); needed by every method but the filters",
    )
    parser.add_argument(
        "--input", required=True, metavar="REC", help="recording (.npz, MSRC-12, Kinect v2, ...)"
    )
    parser.add_argument(
        "--format",
        choices=KINECT_FORMATS,
        default=None,
        help="format of --input (default: guessed from the extension and the data lines)",
    )
    parser.add_argument(
        "--joint-map",
        nargs="+",
        metavar="MAP",
        help="read --input as a generic per-joint CSV/JSON: a joint-map file (JSON or "
        "name=KinectName lines) or name=KinectName pairs (docs/input.md)",
    )
    parser.add_argument(
        "--body",
        type=types.integer(0),
        default=0,
        help="which body of an NTU or Azure Kinect file (default 0)",
    )
    parser.add_argument("--out", required=True, metavar="OUT.npz", help="output .npz")
    parser.add_argument(
        "--optimizer",
        default=None,
        help="registered optimiser (default: the sensor pipeline's, closed-form for a Kinect v2, "
        "else local-search)",
    )
    parser.add_argument(
        "--selector", default=None, choices=["graph", "brute-force"], help="(default graph)"
    )
    parser.add_argument("--no-ragdoll", action="store_true", help="skip the ragdoll stage")
    parser.add_argument(
        "--method",
        metavar="NAME",
        help="a method name instead of --optimizer/--selector/--no-ragdoll: raw, holt[:PRESET], "
        "kalman[:PRESET], one-euro[:PRESET] (filters, +map: through the sensor's definition "
        "map), shum[:OPTIMIZER], fpg[:OPTIMIZER], each optionally +ragdoll (see fpg_gym.methods)",
    )
    parser.add_argument("--seed", type=types.seed, default=0, help="optimiser seed (default 0)")
    parser.add_argument(
        "--budget",
        type=types.integer(0),
        default=2000,
        help="energy evaluations per frame (default 2000)",
    )
    parser.add_argument(
        "--k", type=types.integer(1), default=30, help="candidates per frame (default 30)"
    )
    parser.add_argument(
        "--prior",
        type=float,
        default=0.0,
        metavar="W",
        help="weight of the latent prior Ep (beyond the papers; default 0 = the papers' energy, "
        "0.1 was chosen on a validation split)",
    )
    add_calibration_arguments(parser)
    parser.add_argument(
        "--checkpoint-s",
        type=float,
        default=30.0,
        metavar="S",
        help="write the frames done so far to --out every S seconds, so a killed run keeps them "
        "(metadata 'partial': true; default 30, 0 = never)",
    )
    parser.add_argument(
        "--progress",
        action=argparse.BooleanOptionalAction,
        default=None,
        help="a progress bar on stderr (default: when stderr is a terminal)",
    )
    parser.add_argument(
        "-q",
        "--quiet",
        action="store_true",
        help="no progress bar and no summary lines (errors and warnings still; --json still "
        "prints its line)",
    )
    parser.add_argument("--json", action="store_true", help="last stdout line is a JSON summary")


def add_calibration_arguments(parser: Any) -> None:
    """``--sensor``, ``--preset``, ``--sensor-map``, ``--output-map``, ``--sensor-blend``,
    ``--calibrate-output`` and ``--calibration-map`` (reconstruct, compare and live)."""
    parser.add_argument(
        "--sensor-map",
        metavar="MAP",
        help="joint-definition map from the sensor's to the database's joints: a JSON file "
        "(fpg-gym fit-map) or a packaged name (kinect-v2-to-vicon, kinect-v2-to-embedded, "
        "kinect-v2-to-bandai)",
    )
    parser.add_argument(
        "--output-map",
        metavar="MAP",
        help="joint-definition map applied to the output (database -> wanted definitions)",
    )
    parser.add_argument(
        "--sensor",
        metavar="NAME",
        help="the sensor that made the input (default: what the recording says, else its "
        "reader's format: kinect-v2, kinect-v1, azure-kinect, simulated; unknown otherwise)",
    )
    parser.add_argument(
        "--preset",
        choices=("auto", "papers"),
        default="auto",
        help="auto (default): the pipeline measured best on real data for the sensor "
        "(docs/real-data.md); papers: Shum 2013 / FPG 2016 as published. Any of --sensor-map, "
        "--output-map, --calibrate-output, --calibration-map, --sensor-blend replaces it",
    )
    parser.add_argument(
        "--sensor-blend",
        type=float,
        default=None,
        metavar="F",
        help="after the search, move each joint this fraction of the way to the (mapped) "
        "sensor, times its reliability (beyond the papers; 0 without a preset)",
    )
    parser.add_argument(
        "--calibrate-output",
        action="store_true",
        help="fit the output's joint definitions to the sensor's while the stream runs, from "
        "its tracked joints (instead of --output-map; beyond the papers)",
    )
    parser.add_argument(
        "--calibration-map",
        metavar="MAP",
        help="with --calibrate-output: map from the sensor to the definitions wanted in the "
        "output (default: the sensor's own)",
    )


def definition_maps(
    sensor_map: str | None,
    output_map: str | None,
    calibrate_output: bool = False,
    calibration_map: str | None = None,
) -> dict[str, Any]:
    """Reconstructor settings of the joint-definition arguments, maps read from their files
    (absent when not given).

    Raises
    ------
    ValueError
        ``--calibrate-output`` with ``--output-map``, or ``--calibration-map`` without
        ``--calibrate-output``.
    """

    if calibrate_output and output_map:
        raise ValueError("--calibrate-output and --output-map: give one (both set the output map)")
    if calibration_map and not calibrate_output:
        raise ValueError("--calibration-map: only used with --calibrate-output")
    from fpg_gym.definitions import load_map

    maps: dict[str, Any] = {}
    if sensor_map:
        maps["sensor_map"] = load_map(sensor_map)
    if output_map:
        maps["output_map"] = load_map(output_map)
    if calibrate_output:
        maps["calibrate_output"] = True
    if calibration_map:
        maps["calibration_map"] = load_map(calibration_map)
    return maps


def choose_pipeline(
    args: argparse.Namespace, recording: Any, graph: Any = None, say: Any = None
) -> Any:
    """The pipeline of the arguments for ``recording`` (:func:`fpg_gym.reconstruct.presets.
    choose_pipeline`; ``recording`` None: only ``--sensor`` names the sensor), printed once
    (by ``say``, else as a summary line)."""
    import sys

    from fpg_gym.reconstruct.presets import choose_pipeline as choose
    from fpg_gym.reconstruct.presets import sensor_of

    tuning = definition_maps(
        args.sensor_map, args.output_map, args.calibrate_output, args.calibration_map
    )
    tuning["sensor_blend"] = args.sensor_blend
    chosen = choose(args.preset, sensor_of(recording, args.sensor), graph, tuning)
    line = f"configuration    {chosen.preset}: {chosen.description}"
    if say is not None:
        say(" ".join(line.split()))
    else:
        _say(args, line)
    if chosen.note:
        print(f"note: {chosen.note}", file=sys.stderr)
    return chosen


def resolve_graph(name: str | None, recording: Any, sensor: str | None) -> Any:
    """The pose graph ``--graph`` names for ``recording`` (``default``: the sensor's)."""
    from fpg_gym.graph import load_graph
    from fpg_gym.reconstruct.presets import default_graph_name, sensor_of

    if name in (None, "default"):
        name = default_graph_name(sensor_of(recording, sensor))
    return load_graph(name)


def read_input(args: argparse.Namespace) -> Any:
    """The recording of ``--input`` (with ``--format``, ``--body`` and ``--joint-map``)."""
    from fpg_gym.io import read_recording
    from fpg_gym.io.trackers import JointMap

    joint_map = None
    items = getattr(args, "joint_map", None)
    if items:
        if len(items) == 1 and "=" not in items[0]:
            joint_map = JointMap.load(items[0])
        else:
            try:
                joint_map = JointMap.from_pairs(items)
            except ValueError as error:
                raise ValueError(f"--joint-map: {error}") from None
    return read_recording(
        args.input, format=args.format, body=getattr(args, "body", 0), joint_map=joint_map
    )


def _histogram(errors: Any) -> list[int]:
    from fpg_gym.core.metrics import error_histogram

    counts: list[int] = error_histogram(errors, (*HISTOGRAM_EDGES, float("inf"))).tolist()
    return counts


def _error_summary(recording: Any, poses: Any) -> tuple[dict[str, Any], dict[str, Any]]:
    """Per-frame errors of the raw input and of ``poses`` against ``recording``'s ground truth:
    the arrays (``frame_error_raw``, ``frame_error``) and the summary entries (mean error and
    Err0.2 of each)."""
    import numpy as np

    from fpg_gym.core import metrics

    raw_errors = metrics.frame_error(recording.ground_truth, recording.positions)
    errors = metrics.frame_error(recording.ground_truth, poses)
    arrays = {"frame_error_raw": raw_errors, "frame_error": errors}
    summary: dict[str, Any] = {
        "raw_mean_error_m": float(raw_errors.mean()),
        "mean_error_m": float(errors.mean()),
        "raw_err02_pct": 100.0 * metrics.err_ratio(raw_errors),
        "err02_pct": 100.0 * metrics.err_ratio(errors),
        "raw_jitter_ms2": _mean_jitter(recording.positions),
        "jitter_ms2": _mean_jitter(poses),
        "truth_jitter_ms2": _mean_jitter(recording.ground_truth),
        "lag_frames": metrics.lag(poses, recording.ground_truth),
    }
    spread = metrics.settled_bone_spread(poses, timestamps=recording.timestamps)
    summary["settled_bone_spread_mm"] = (
        float(1000.0 * np.nanmax(spread)) if np.isfinite(spread).any() else None
    )
    return arrays, summary


def _mean_jitter(poses: Any) -> float:
    """Mean acceleration magnitude (m/s²) over joints and frames; NaN, quietly, for a stream
    too short to have one (fewer than 3 frames)."""
    import numpy as np

    from fpg_gym.core import metrics

    values = np.asarray(metrics.jitter(poses), dtype=np.float64)
    finite = values[np.isfinite(values)]
    return float(finite.mean()) if finite.size else float("nan")


def _number(value: Any, digits: int) -> str:
    """``value`` with ``digits`` decimals, or ``–`` when there is none (NaN, None)."""
    import math

    return "–" if value is None or not math.isfinite(value) else f"{value:.{digits}f}"


def _print_errors(args: argparse.Namespace, summary: dict[str, Any], label: str) -> None:
    """The raw input's and the output's mean error and Err0.2 lines (none with ``--quiet``)."""
    _say(
        args,
        f"raw input        mean error {summary['raw_mean_error_m']:.4f} m, "
        f"Err0.2 {summary['raw_err02_pct']:.1f} %",
    )
    _say(
        args,
        f"{label:<16} mean error {summary['mean_error_m']:.4f} m, "
        f"Err0.2 {summary['err02_pct']:.1f} %",
    )
    spread = summary["settled_bone_spread_mm"]
    _say(
        args,
        f"jitter (m/s²)    input {_number(summary['raw_jitter_ms2'], 1)}, output "
        f"{_number(summary['jitter_ms2'], 1)}, truth {_number(summary['truth_jitter_ms2'], 1)}; "
        f"lag {_number(summary['lag_frames'], 2)} frames; bone spread after 1 s "
        + ("–" if spread is None else f"{spread:.1f} mm"),
    )


def _show_progress(args: argparse.Namespace) -> bool:
    """``--progress``/``--no-progress``, else a bar when stderr is a terminal (not ``--quiet``)."""
    import sys

    if args.quiet:
        return False
    return sys.stderr.isatty() if args.progress is None else bool(args.progress)


def _say(args: argparse.Namespace, text: str) -> None:
    """Print a summary line unless ``--quiet``."""
    if not args.quiet:
        print(text)


def _check_out(args: argparse.Namespace) -> Path:
    """The output path, checked before any work (not an input, not a folder, writable)."""
    from fpg_gym.core.outputs import check_output
    from fpg_gym.graph import GRAPH_NAMES

    inputs = [args.input]
    if args.graph and args.graph not in GRAPH_NAMES:
        inputs.append(args.graph)
    return check_output(args.out, inputs, npz=True)


def run(args: argparse.Namespace) -> int:
    """Reconstruct, write the ``.npz`` and print the summary (errors when ground truth exists)."""
    import numpy as np

    from fpg_gym.core.outputs import interrupts_deferred
    from fpg_gym.methods import Method, MethodRunner
    from fpg_gym.methods.names import BASE_OF_SELECTOR
    from fpg_gym.reconstruct import EnergyWeights

    _check_arguments(args)
    args.selector = args.selector or "graph"
    args.out = _check_out(args)
    if args.method:
        from fpg_gym.methods import parse_method

        method = parse_method(args.method)
        if method.is_filter:
            return _run_filter(args, method)
        assert method.optimizer is not None and method.selector is not None
        args.optimizer, args.selector = method.optimizer, method.selector
        args.no_ragdoll = not method.ragdoll
    if not args.graph:
        raise ValueError("--graph: a pose graph is needed (a .npz file or 'default')")
    recording = read_input(args)
    graph = resolve_graph(args.graph, recording, args.sensor)
    chosen = choose_pipeline(args, recording, graph)
    args.pipeline = chosen.summary()
    args.optimizer = args.optimizer or chosen.optimizer or "local-search"
    method = Method(BASE_OF_SELECTOR[args.selector], args.optimizer, not args.no_ragdoll)
    options = {"k": args.k, "weights": EnergyWeights(prior=args.prior), **chosen.options}
    start = time.perf_counter()

    def checkpoint(partial: Any) -> None:  # survives kill -9: the frames done so far, on disk
        _save_result(args, recording, partial, time.perf_counter() - start, partial=True)

    with MethodRunner(graph, budget=args.budget, reconstructor_options=options) as runner:
        result = runner.run(
            method,
            recording,
            np.random.default_rng(args.seed),
            progress=_show_progress(args),
            stop_on_interrupt=True,
            checkpoint=checkpoint,
            checkpoint_s=args.checkpoint_s,
        )
    # the frames are done: an interrupt from here on waits until they are written
    with interrupts_deferred():
        summary, out = _save_result(args, recording, result, time.perf_counter() - start)
    _print_summary(args, summary, result, recording.num_frames, out)
    return 130 if result.interrupted else 0


def _check_arguments(args: argparse.Namespace) -> None:
    """Refuse out-of-range numbers, ``--method`` beside the options it sets, and an unknown
    ``--optimizer``, before any work."""
    from optimizers import make

    if args.budget < 0:
        raise ValueError(f"--budget: expected >= 0, got {args.budget}")
    if args.k < 1:
        raise ValueError(f"--k: expected >= 1, got {args.k}")
    if not args.prior >= 0:
        raise ValueError(f"--prior: expected >= 0, got {args.prior}")
    if not args.checkpoint_s >= 0:
        raise ValueError(f"--checkpoint-s: expected >= 0 seconds, got {args.checkpoint_s}")
    given = [
        name
        for name, value in (
            ("--optimizer", args.optimizer),
            ("--selector", args.selector),
            ("--no-ragdoll", args.no_ragdoll or None),
        )
        if value is not None
    ]
    if args.method and given:
        raise ValueError(
            f"--method {args.method} and {', '.join(given)}: give one (a method name says the "
            "optimiser, selector and ragdoll, e.g. fpg:cma-es or shum:local-search+ragdoll)"
        )
    if args.optimizer:
        make(args.optimizer)  # an unknown name fails before any work


def _print_summary(
    args: argparse.Namespace, summary: dict[str, Any], result: Any, total: int, out: Path
) -> None:
    """The run's summary lines (errors and their histogram when ground truth exists)."""
    from fpg_gym.commands.output import emit_json

    frames = result.num_frames
    state = " (interrupted)" if result.interrupted else ""
    _say(args, f"frames           {frames} of {total}{state}")
    _say(
        args,
        f"optimizer        {args.optimizer}, selector {args.selector}, ragdoll "
        f"{'off' if args.no_ragdoll else 'on'}, seed {args.seed}, budget {args.budget}",
    )
    if frames:
        _say(
            args,
            f"ms per frame     median {summary['ms_per_frame_median']:.2f}, "
            f"p95 {summary['ms_per_frame_p95']:.2f}",
        )
        _say(
            args,
            f"evaluations      mean {summary['evaluations_mean']:.0f} per frame, "
            f"recoveries {summary['recoveries']}",
        )
    if summary["mean_error_m"] is not None:
        _print_errors(args, summary, "reconstruction")
        labels = [f"{lo:.2f}-{hi:.2f}" for lo, hi in itertools.pairwise(HISTOGRAM_EDGES)] + [
            f">={HISTOGRAM_EDGES[-1]:.2f}"
        ]
        _say(args, "error histogram  (m: raw / reconstruction frames)")
        for label, raw, rec in zip(
            labels, summary["raw_histogram"], summary["histogram"], strict=True
        ):
            _say(args, f"  {label:>10}  {raw:6d} / {rec:6d}")
    _say(args, f"written          {out}")
    if args.json:
        emit_json({**summary, "out": str(out)})


def _save_result(
    args: argparse.Namespace,
    recording: Any,
    result: Any,
    seconds: float,
    *,
    partial: bool = False,
) -> tuple[dict[str, Any], Path]:
    """Write the reconstruction (``partial``: a checkpoint of the frames done so far) with its
    errors and metadata to ``args.out``; return the summary and the path written."""
    import numpy as np

    from fpg_gym.core.outputs import save_npz

    arrays = result.arrays()
    frames = result.num_frames
    total = recording.num_frames

    summary: dict[str, Any] = {
        "frames": frames,
        "input_frames": total,
        "interrupted": result.interrupted,
        "optimizer": args.optimizer,
        "selector": args.selector,
        "ragdoll": not args.no_ragdoll,
        "seed": args.seed,
        "budget": args.budget,
        "raw_mean_error_m": None,
        "mean_error_m": None,
        "raw_err02_pct": None,
        "err02_pct": None,
        "ms_per_frame_median": float(np.median(arrays["ms_per_frame"])) if frames else None,
        "ms_per_frame_p95": float(np.percentile(arrays["ms_per_frame"], 95)) if frames else None,
        "evaluations_mean": float(arrays["evaluations"].mean()) if frames else None,
        "recoveries": int(arrays["recovered"].sum()),
        "seconds": round(seconds, 3),
        "bone_settling": {k: v for k, v in result.bones.items() if not k.endswith("lengths_m")},
    }
    if recording.ground_truth is not None and frames:
        error_arrays, error_summary = _error_summary(recording.head(frames), result.poses)
        arrays.update(error_arrays)
        summary.update(
            error_summary,
            histogram_edges_m=list(HISTOGRAM_EDGES),
            raw_histogram=_histogram(error_arrays["frame_error_raw"]),
            histogram=_histogram(error_arrays["frame_error"]),
        )
    metadata = {
        "input": str(args.input),
        "graph": str(args.graph),
        **{k: summary[k] for k in ("optimizer", "selector", "ragdoll", "seed", "budget")},
        "prior": args.prior,
        "k": args.k,
        "pipeline": getattr(args, "pipeline", None),
        "interrupted": result.interrupted,
        "partial": partial,  # a checkpoint: the run was still going when it was written
        "frames": frames,
        "input_frames": total,
        "bone_settling": result.bones,
    }
    arrays["metadata"] = np.array(json.dumps(metadata, sort_keys=True))
    out = save_npz(args.out, arrays)  # beside the target, then renamed: never half-written
    return summary, out


def _run_filter(args: argparse.Namespace, method: Any) -> int:
    """``--method raw|holt|kalman[+ragdoll]``: run a reference filter and write its output."""
    import numpy as np

    from fpg_gym.commands.output import emit_json
    from fpg_gym.core.outputs import save_npz
    from fpg_gym.methods import MethodRunner

    recording = read_input(args)
    options: dict[str, Any] = {}
    if method.mapped:  # the sensor's map into the definitions a reconstruction would output
        graph = resolve_graph(args.graph, recording, args.sensor)
        options = choose_pipeline(args, recording, graph).options
    start = time.perf_counter()
    with MethodRunner(reconstructor_options=options) as runner:
        result = runner.run(method, recording)
    seconds = time.perf_counter() - start
    arrays: dict[str, Any] = result.arrays()
    summary: dict[str, Any] = {
        "frames": result.num_frames,
        "input_frames": recording.num_frames,
        "method": method.name,
        "raw_mean_error_m": None,
        "mean_error_m": None,
        "raw_err02_pct": None,
        "err02_pct": None,
        "ms_per_frame_median": float(np.median(result.ms)),
        "ms_per_frame_p95": float(np.percentile(result.ms, 95)),
        "seconds": round(seconds, 3),
    }
    if recording.ground_truth is not None:
        error_arrays, error_summary = _error_summary(recording, result.poses)
        arrays.update(error_arrays)
        summary.update(error_summary)
    metadata = {"input": str(args.input), "method": method.name, "frames": result.num_frames}
    arrays["metadata"] = np.array(json.dumps(metadata, sort_keys=True))
    out = save_npz(args.out, arrays)
    _say(args, f"frames           {result.num_frames}")
    _say(args, f"method           {method.name}")
    _say(args, f"ms per frame     median {summary['ms_per_frame_median']:.3f}")
    if summary["mean_error_m"] is not None:
        _print_errors(args, summary, method.name)
    _say(args, f"written          {out}")
    if args.json:
        emit_json({**summary, "out": str(out)})
    return 0

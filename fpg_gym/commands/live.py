"""``fpg-gym live``: reconstruct frames as they arrive (JSON lines on stdin or UDP)."""

from __future__ import annotations

import argparse
import json
import sys
from typing import Any

from fpg_gym.commands.reconstruct import add_calibration_arguments, choose_pipeline, resolve_graph

NAME = "live"
HELP = (
    "reconstruct a live stream: JSON-line frames from stdin or udp://HOST:PORT, each "
    "reconstructed frame written at once (stdout or UDP); see docs/live.md"
)


def add_arguments(parser: argparse.ArgumentParser) -> None:
    """Register the command's arguments."""
    parser.add_argument(
        "--graph",
        default="default",
        metavar="FILE",
        help="pose graph .npz or a name: 'default' (the --sensor's default database), "
        "'embedded', 'uiprmd' (default: 'default')",
    )
    parser.add_argument(
        "--input", default="-", metavar="SRC", help="'-' (stdin, the default) or udp://HOST:PORT"
    )
    parser.add_argument(
        "--output", default="-", metavar="DST", help="'-' (stdout, the default) or udp://HOST:PORT"
    )
    parser.add_argument(
        "--method",
        default=None,
        metavar="NAME",
        help="a reconstruction method (fpg[:OPTIMIZER], shum[:OPTIMIZER], optionally +ragdoll; "
        "default: fpg with the sensor pipeline's optimiser, closed-form for a Kinect v2, else "
        "local-search) or a reference filter (raw, holt, kalman, one-euro, each "
        "optionally +map)",
    )
    add_calibration_arguments(parser)
    parser.add_argument("--seed", type=int, default=0, help="optimiser seed (default 0)")
    parser.add_argument(
        "--budget", type=int, default=2000, help="energy evaluations per frame (default 2000)"
    )
    parser.add_argument(
        "--queue", type=int, default=2, metavar="N", help="frames waiting at most (default 2)"
    )
    parser.add_argument(
        "--max-age-ms",
        type=float,
        default=100.0,
        metavar="MS",
        help="skip a waiting frame older than this when a newer one waits (default 100; 0 = "
        "never skip by age)",
    )
    parser.add_argument(
        "--idle-timeout-s",
        type=float,
        default=0.0,
        metavar="S",
        help="with UDP input, stop after S seconds without a datagram, counted from the first "
        "one (default 0 = never)",
    )
    parser.add_argument(
        "--max-frames", type=int, default=None, metavar="N", help="stop after N output frames"
    )


def run(args: argparse.Namespace) -> int:
    """Run the stream until its end (stdin EOF, ``{"end": true}``, idle timeout, Ctrl-C);
    print the counts and latencies to stderr as one JSON line.

    The input is bound and read first, then the graph loads and the pipeline warms up: the
    frames that arrive meanwhile wait and are all reconstructed
    (:class:`fpg_gym.methods.live.FrameQueue`).
    Two lines on stderr mark the start: ``listening on udp://...`` (UDP input, once bound) and
    ``ready`` (the first frame can be reconstructed at once).
    """
    import threading

    from fpg_gym.io import udp
    from fpg_gym.methods import live, parse_method, ragdoll_factory
    from fpg_gym.reconstruct import EnergyWeights, Reconstructor

    if args.queue < 1:
        raise ValueError(f"--queue: expected >= 1, got {args.queue}")
    if not args.max_age_ms >= 0:
        raise ValueError(f"--max-age-ms: expected >= 0, got {args.max_age_ms}")
    if not args.idle_timeout_s >= 0:
        raise ValueError(
            f"--idle-timeout-s: expected >= 0 seconds (0 = never), got {args.idle_timeout_s}"
        )
    if args.budget < 0:
        raise ValueError(f"--budget: expected >= 0, got {args.budget}")
    if args.max_frames is not None and args.max_frames < 1:
        raise ValueError(f"--max-frames: expected >= 1, got {args.max_frames}")
    method = parse_method(args.method or "fpg")
    if method.is_filter and method.ragdoll:
        raise ValueError(f"--method {method.name}: live runs the filters without the ragdoll")
    if args.input != "-":
        udp.parse_address(args.input, "--input")
    if args.output == "-":

        def emit(frame: dict[str, Any]) -> None:
            print(json.dumps(frame, separators=(",", ":")), flush=True)

    else:
        send = udp.udp_sender(args.output, "--output")

        def emit(frame: dict[str, Any]) -> None:
            send(json.dumps(frame, separators=(",", ":")))

    def say(text: str) -> None:
        print(f"fpg-gym live: {text}", file=sys.stderr, flush=True)

    stop = threading.Event()
    sock = None
    reconstructor = None
    try:
        # Listen and read before the graph loads: frames sent meanwhile wait, none is lost.
        if args.input == "-":
            lines: Any = udp.stdin_lines()
        else:
            sock = udp.open_udp_input(args.input, "--input")
            idle = args.idle_timeout_s if args.idle_timeout_s > 0 else None
            lines = udp.udp_lines(sock, stop, idle)
            host, port = sock.getsockname()[:2]
            say(f"listening on udp://{host}:{port}")
        reader = live.LiveReader(lines, args.queue)
        graph = resolve_graph(args.graph, None, args.sensor)
        chosen = choose_pipeline(args, None, graph, say)
        if args.method is None and chosen.optimizer:
            method = parse_method(f"fpg:{chosen.optimizer}")
        step: Any
        if method.is_filter:
            step = live.FilterStep(method, chosen.options)
        else:
            assert method.optimizer is not None and method.selector is not None
            reconstructor = Reconstructor(
                graph,
                ragdoll=ragdoll_factory(method.ragdoll),
                selector=method.selector,
                max_evaluations=args.budget,
                weights=EnergyWeights().with_prior() if method.prior else EnergyWeights(),
                **chosen.options,
            )
            step = live.ReconstructorStep(reconstructor, method.optimizer, args.seed)
        say("ready")
        stats = live.run_live(
            reader,
            step,
            emit,
            max_age_s=args.max_age_ms / 1000.0 if args.max_age_ms > 0 else None,
            max_frames=args.max_frames,
            notify=say,
        )
    finally:
        stop.set()
        if reconstructor is not None:
            reconstructor.close()
        if sock is not None:
            sock.close()
    print(json.dumps({"live": stats.summary()}), file=sys.stderr, flush=True)
    return 130 if stats.interrupted else 0

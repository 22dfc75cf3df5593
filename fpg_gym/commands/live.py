"""``fpg-gym live``: reconstruct frames as they arrive (JSON lines on stdin or UDP)."""

from __future__ import annotations

import argparse
import json
import sys
from typing import Any

NAME = "live"
HELP = (
    "reconstruct a live stream: JSON-line frames from stdin or udp://HOST:PORT, each "
    "reconstructed frame written at once (stdout or UDP); see docs/live.md"
)


def add_arguments(parser: argparse.ArgumentParser) -> None:
    """Register the command's arguments."""
    parser.add_argument(
        "--graph", required=True, metavar="FILE", help="pose graph .npz or 'default'"
    )
    parser.add_argument(
        "--input", default="-", metavar="SRC", help="'-' (stdin, the default) or udp://HOST:PORT"
    )
    parser.add_argument(
        "--output", default="-", metavar="DST", help="'-' (stdout, the default) or udp://HOST:PORT"
    )
    parser.add_argument(
        "--method",
        default="fpg:local-search",
        metavar="NAME",
        help="a reconstruction method (fpg[:OPTIMIZER], shum[:OPTIMIZER], optionally +ragdoll; "
        "default fpg:local-search)",
    )
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
        help="with UDP input, stop after S seconds without a datagram (default 0 = never)",
    )
    parser.add_argument(
        "--max-frames", type=int, default=None, metavar="N", help="stop after N output frames"
    )


def run(args: argparse.Namespace) -> int:
    """Run the stream until its end (stdin EOF, ``{"end": true}``, idle timeout, Ctrl-C);
    print the counts and latencies to stderr as one JSON line."""
    import socket
    import threading

    from fpg_gym import live
    from fpg_gym.graph import load_graph
    from fpg_gym.methods import parse_method
    from fpg_gym.reconstruct import EnergyWeights, Reconstructor

    if args.queue < 1:
        raise ValueError(f"--queue: expected >= 1, got {args.queue}")
    if not args.max_age_ms >= 0:
        raise ValueError(f"--max-age-ms: expected >= 0, got {args.max_age_ms}")
    if args.budget < 0:
        raise ValueError(f"--budget: expected >= 0, got {args.budget}")
    method = parse_method(args.method)
    if method.is_filter:
        raise ValueError(
            f"--method: live runs reconstruction methods (fpg, shum), got {method.name}"
        )
    inbound = None if args.input == "-" else live.parse_address(args.input, "--input")
    outbound = None if args.output == "-" else live.parse_address(args.output, "--output")
    assert method.optimizer is not None and method.selector is not None
    reconstructor = Reconstructor(
        load_graph(args.graph),
        ragdoll=method.ragdoll,
        selector=method.selector,
        max_evaluations=args.budget,
        weights=EnergyWeights().with_prior() if method.prior else EnergyWeights(),
    )
    step = live.ReconstructorStep(reconstructor, method.optimizer, args.seed)
    stop = threading.Event()
    lines: Any
    sock = None
    if inbound is None:
        lines = live.stdin_lines()
    else:
        sock = socket.socket(
            socket.AF_INET6 if ":" in inbound[0] else socket.AF_INET, socket.SOCK_DGRAM
        )
        sock.bind(inbound)
        idle = args.idle_timeout_s if args.idle_timeout_s > 0 else None
        lines = live.udp_lines(sock, stop, idle)
        host, port = sock.getsockname()[:2]
        print(f"fpg-gym live: listening on udp://{host}:{port}", file=sys.stderr, flush=True)
    if outbound is None:

        def emit(frame: dict[str, Any]) -> None:
            print(json.dumps(frame, separators=(",", ":")), flush=True)

    else:
        send = live.udp_sender(*outbound)

        def emit(frame: dict[str, Any]) -> None:
            send(json.dumps(frame, separators=(",", ":")))

    try:
        stats = live.run_live(
            lines,
            step,
            emit,
            queue_size=args.queue,
            max_age_s=args.max_age_ms / 1000.0 if args.max_age_ms > 0 else None,
            max_frames=args.max_frames,
        )
    finally:
        stop.set()
        reconstructor.close()
        if sock is not None:
            sock.close()
    print(json.dumps({"live": stats.summary()}), file=sys.stderr, flush=True)
    return 130 if stats.interrupted else 0

"""``fpg-gym warm-up``: compile the numba kernels now, on every core, rather than on first use."""

from __future__ import annotations

import argparse
import os

NAME = "warm-up"
HELP = (
    "compile the compiled kernels (fpg-gym[fast]) into numba's disk cache now, shared between "
    "processes, so that a first compare or reconstruction does not wait for them (the demo "
    "compiles them in the background when they are missing)"
)


def add_arguments(parser: argparse.ArgumentParser) -> None:
    """Register the command's arguments."""
    parser.add_argument(
        "--workers", type=int, default=None, help="processes (default: the CPU count)"
    )


def run(args: argparse.Namespace) -> int:
    """Compile (or load) every kernel and say how long it took."""
    from fpg_gym.core.compiled import numba_available
    from fpg_gym.experiments.warm import warm_kernels

    workers = (os.cpu_count() or 1) if args.workers is None else args.workers
    if workers < 1:
        raise ValueError(f"--workers: expected a positive integer, got {workers}")
    if not numba_available():
        print("numba is not installed (pip install 'fpg-gym[fast]'): nothing to compile")
        return 0
    seconds = warm_kernels(workers)
    print(f"compiled kernels ready in numba's disk cache: {seconds:.1f} s ({workers} processes)")
    return 0

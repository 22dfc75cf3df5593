"""The ``fpg-gym`` command line: one sub-command per module in :mod:`fpg_gym.commands`.

Each command module defines ``NAME``, ``HELP``, ``add_arguments(parser)`` and ``run(args) -> int``
and imports its heavy dependencies inside ``run`` so that ``fpg-gym --help`` stays fast.
"""

from __future__ import annotations

import argparse
import importlib
import sys
from collections.abc import Sequence

from fpg_gym import __version__
from fpg_gym.errors import FpgGymError

#: Command modules under ``fpg_gym.commands``, in the order ``--help`` lists them.
COMMAND_MODULES: tuple[str, ...] = (
    "read",
    "build_graph",
    "reconstruct",
    "simulate",
    "import_uiprmd",
    "fit_map",
    "compare",
    "demo",
    "bench",
    "train_sampler",
)


def build_parser() -> argparse.ArgumentParser:
    """The argument parser with every sub-command registered."""
    parser = argparse.ArgumentParser(
        prog="fpg-gym",
        description="Kinect pose reconstruction with the Filtered Pose Graph (Plantard, Shum & "
        "Multon 2016) and Shum et al. 2013, as a Gymnasium environment. An argument @FILE "
        "is replaced by the lines of FILE, one argument per line (e.g. lists of takes).",
        fromfile_prefix_chars="@",
    )
    parser.add_argument("--version", action="version", version=f"fpg-gym {__version__}")
    subparsers = parser.add_subparsers(dest="command", metavar="COMMAND")
    for module_name in COMMAND_MODULES:
        module = importlib.import_module(f"fpg_gym.commands.{module_name}")
        sub = subparsers.add_parser(module.NAME, help=module.HELP, description=module.HELP)
        module.add_arguments(sub)
        sub.set_defaults(run=module.run)
    return parser


def main(argv: Sequence[str] | None = None) -> int:
    """Entry point of the ``fpg-gym`` console script; returns the exit status."""
    parser = build_parser()
    args = parser.parse_args(argv)
    if not getattr(args, "run", None):
        parser.print_help()
        return 2
    try:
        return int(args.run(args) or 0)
    except KeyboardInterrupt:
        print("fpg-gym: interrupted; results written so far are kept", file=sys.stderr)
        return 130
    except (FpgGymError, FileNotFoundError, ValueError) as error:
        print(f"fpg-gym {args.command}: error: {error}", file=sys.stderr)
        return 2


if __name__ == "__main__":  # pragma: no cover
    sys.exit(main())

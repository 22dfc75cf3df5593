"""The ``fpg-gym`` command line: one sub-command per module in :mod:`fpg_gym.commands`.

Each command module defines ``NAME``, ``HELP``, ``add_arguments(parser)`` and ``run(args) -> int``
and imports its heavy dependencies inside ``run`` so that ``fpg-gym --help`` stays fast.

Errors: a bad argument or bad input prints one line, ``fpg-gym COMMAND: error: ...``, and exits
with status 2 (never a traceback). An argument ``@FILE`` is replaced by the lines of FILE, one
argument per line; a line is always an argument, never an option (a line starting with ``-`` is
refused). SIGTERM stops a command as Ctrl-C does: what was finished is written, status 130.
Every command takes ``--accept-unusual``: its readers then accept inputs that are well formed
but not a person in metres at a real frame rate (:mod:`fpg_gym.io.plausibility`).
"""

from __future__ import annotations

import argparse
import importlib
import signal
import sys
from collections.abc import Iterator, Sequence
from contextlib import contextmanager
from pathlib import Path
from types import FrameType
from typing import Any, NoReturn

from fpg_gym import __version__
from fpg_gym.core.errors import FpgGymError, interrupt_in
from fpg_gym.io.plausibility import accepting_unusual
from optimizers import OptimizerError

#: Command modules under ``fpg_gym.commands``, in the order ``--help`` lists them.
COMMAND_MODULES: tuple[str, ...] = (
    "read",
    "build_graph",
    "reconstruct",
    "live",
    "export",
    "view",
    "simulate",
    "import_uiprmd",
    "fit_map",
    "compare",
    "demo",
    "bench",
    "warm_up",
    "train_sampler",
)


#: Prefix of an argument naming a file of arguments.
FROMFILE_PREFIX = "@"


class CommandLineError(FpgGymError, ValueError):
    """A bad ``@FILE`` argument list (the message names the file and line)."""


def expand_argument_files(arguments: Sequence[str]) -> list[str]:
    """``arguments`` with every ``@FILE`` replaced by the lines of FILE.

    Each non-blank line is one argument (surrounding whitespace removed), taken literally: a
    line is never an option (one starting with ``-`` is refused) and never another ``@FILE``.

    Raises
    ------
    CommandLineError
        If FILE cannot be read, is not text, or a line starts with ``-``.
    """
    expanded: list[str] = []
    for argument in arguments:
        if not argument.startswith(FROMFILE_PREFIX) or argument == FROMFILE_PREFIX:
            expanded.append(argument)
            continue
        path = Path(argument[len(FROMFILE_PREFIX) :])
        try:
            text = path.read_bytes().decode("utf-8")
        except FileNotFoundError:
            raise CommandLineError(f"{argument}: no such file") from None
        except IsADirectoryError:
            raise CommandLineError(f"{argument}: is a folder, expected a text file") from None
        except OSError as error:
            raise CommandLineError(f"{argument}: cannot read ({error.strerror})") from None
        except UnicodeDecodeError:
            raise CommandLineError(f"{argument}: not a UTF-8 text file") from None
        for number, line in enumerate(text.splitlines(), start=1):
            item = line.strip()
            if not item:
                continue
            if item.startswith("-"):
                raise CommandLineError(
                    f"{path}, line {number}: {item[:60]!r} starts with '-'; lines of an "
                    "@FILE are arguments (file names, takes), never options"
                )
            expanded.append(item)
    return expanded


class _Parser(argparse.ArgumentParser):
    """An ``ArgumentParser`` whose errors are one line: ``PROG: error: MESSAGE``."""

    def error(self, message: str) -> NoReturn:
        self.exit(2, f"{self.prog}: error: {message} (see {self.prog} --help)\n")


@contextmanager
def _sigterm_interrupts() -> Iterator[None]:
    """Within the block, SIGTERM raises ``KeyboardInterrupt`` (commands then keep and write
    what they finished, as on Ctrl-C); the previous handler is restored after it."""

    def interrupt(signum: int, frame: FrameType | None) -> Any:
        raise KeyboardInterrupt(f"signal {signum}")

    try:
        previous = signal.signal(signal.SIGTERM, interrupt)
    except ValueError:  # not the main thread: leave signals alone
        yield
        return
    try:
        yield
    finally:
        signal.signal(signal.SIGTERM, previous)


def build_parser() -> argparse.ArgumentParser:
    """The argument parser with every sub-command registered (``@FILE`` arguments are
    expanded by :func:`main`, see :func:`expand_argument_files`)."""
    parser = _Parser(
        prog="fpg-gym",
        description="Kinect pose reconstruction with the Filtered Pose Graph (Plantard, Shum & "
        "Multon 2016) and Shum et al. 2013, as a Gymnasium environment. An argument @FILE "
        "is replaced by the lines of FILE, one argument per line (e.g. lists of takes); a line "
        "is always an argument, never an option.",
    )
    parser.add_argument("--version", action="version", version=f"fpg-gym {__version__}")
    subparsers = parser.add_subparsers(dest="command", metavar="COMMAND", parser_class=_Parser)
    for module_name in COMMAND_MODULES:
        module = importlib.import_module(f"fpg_gym.commands.{module_name}")
        sub = subparsers.add_parser(module.NAME, help=module.HELP, description=module.HELP)
        module.add_arguments(sub)
        sub.add_argument(
            "--accept-unusual",
            action="store_true",
            help="read inputs that are well formed but not a person in metres at a real frame "
            "rate (a body outside 0.4-3 m head to ankles, a coordinate beyond 1000 m, a frame "
            "rate outside 1-1000 Hz), as they are",
        )
        sub.set_defaults(run=module.run)
    return parser


def main(argv: Sequence[str] | None = None) -> int:
    """Entry point of the ``fpg-gym`` console script; returns the exit status."""
    parser = build_parser()
    arguments = list(sys.argv[1:] if argv is None else argv)
    try:
        arguments = expand_argument_files(arguments)
    except CommandLineError as error:
        command = next((a for a in arguments if not a.startswith(("-", "@"))), "")
        print(f"fpg-gym{' ' + command if command else ''}: error: {error}", file=sys.stderr)
        return 2
    args, extras = parser.parse_known_args(arguments)
    if extras:
        command = f" {args.command}" if getattr(args, "command", None) else ""
        print(
            f"fpg-gym{command}: error: unrecognized arguments: {' '.join(extras)} (see "
            f"fpg-gym{command} --help)",
            file=sys.stderr,
        )
        return 2
    if not getattr(args, "run", None):
        parser.print_help()
        return 2
    try:
        with _sigterm_interrupts(), accepting_unusual(getattr(args, "accept_unusual", False)):
            return int(args.run(args) or 0)
    except (KeyboardInterrupt, SystemError) as error:
        if interrupt_in(error) is None:
            raise
        print("fpg-gym: interrupted; results written so far are kept", file=sys.stderr)
        return 130
    except (FpgGymError, OptimizerError, OSError, ValueError) as error:
        print(f"fpg-gym {args.command}: error: {_one_line(error)}", file=sys.stderr)
        return 2


def _one_line(error: BaseException) -> str:
    """The error's message on one line (an OSError without its own message names its file)."""
    if isinstance(error, OSError) and not isinstance(error, FpgGymError) and error.strerror:
        text = f"{error.filename}: {error.strerror}" if error.filename else error.strerror
    else:
        text = str(error) or type(error).__name__
    return " ".join(text.split())


if __name__ == "__main__":  # pragma: no cover
    sys.exit(main())

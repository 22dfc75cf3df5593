"""Argument types shared by the commands: integers with bounds, refused by argparse itself.

A bad value is then a one-line ``fpg-gym COMMAND: error: argument --seed: ...`` with exit
status 2 before any work, naming the option, instead of a late refusal (or none) from deep
inside a run.
"""

from __future__ import annotations

import argparse
from collections.abc import Callable


def integer(low: int, high: int | None = None) -> Callable[[str], int]:
    """An argparse ``type`` for integers in ``[low, high]`` (``high`` None: unbounded)."""

    def parse(text: str) -> int:
        bounds = f"an integer >= {low}" if high is None else f"an integer in [{low}, {high}]"
        try:
            value = int(text)
        except ValueError:
            raise argparse.ArgumentTypeError(f"expected {bounds}, got {text!r}") from None
        if value < low or (high is not None and value > high):
            raise argparse.ArgumentTypeError(f"expected {bounds}, got {value}")
        return value

    parse.__name__ = f"integer >= {low}"  # argparse names the type in some messages
    return parse


#: Seeds: numpy's generators take non-negative integers.
seed = integer(0)
#: Process counts (``--workers``): at least one.
workers = integer(1)

"""The learned-sampler study of ``scripts/learned_samplers.py``, one module per protocol
(:mod:`.compare`: embedded and Bandai; :mod:`.uiprmd`; :mod:`.sim`; :mod:`.rl`) on shared
training (:mod:`.training`), scoring (:mod:`.scoring`) and tables (:mod:`.tables`)."""

from __future__ import annotations

import argparse
import shlex
from pathlib import Path

REPO = Path(__file__).resolve().parents[2]
#: The scenarios every protocol simulates.
SCENARIOS = "front-many,left45-many,right45-many"


def study_command(args: argparse.Namespace) -> str:
    """The command line that ran the study (a trained model's record)."""
    return "python scripts/learned_samplers.py " + " ".join(
        shlex.quote(a) for a in (args.argv or [])
    )

"""Step throughput of one KinectPoseEnv (random actions, no search), with and without ragdoll.

Calls :func:`fpg_gym.episodes.measure_env_throughput` (what ``fpg-gym bench`` reports) and
prints one JSON object. BLAS threads are limited to one (``OPENBLAS_NUM_THREADS=1`` unless set):
the per-frame matrices are tiny and multi-threaded BLAS roughly halves the step rate.

Usage::

    python scripts/bench_env.py                       # 600 steps each, default env
    python scripts/bench_env.py --steps 2000 --simulator-seeds 4 --json out.json
"""

from __future__ import annotations

import os

os.environ.setdefault("OPENBLAS_NUM_THREADS", "1")
os.environ.setdefault("OMP_NUM_THREADS", "1")

import argparse
import json
import sys
from pathlib import Path
from typing import Any


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--steps", type=int, default=600, help="steps per measurement (600)")
    parser.add_argument("--repeats", type=int, default=2, help="measurements per setting (2)")
    parser.add_argument("--seed", type=int, default=0)
    parser.add_argument(
        "--simulator-seeds", type=int, default=None, help="env simulator_seeds (cached episodes)"
    )
    parser.add_argument("--json", type=Path, default=None, help="also write the result here")
    args = parser.parse_args(argv)

    from fpg_gym.episodes import measure_env_throughput

    env_kwargs: dict[str, Any] = {}
    if args.simulator_seeds is not None:
        env_kwargs["simulator_seeds"] = args.simulator_seeds
    result: dict[str, Any] = {"steps": args.steps, "env_kwargs": env_kwargs, "runs": {}}
    for ragdoll in (True, False):
        runs = [
            measure_env_throughput(args.steps, ragdoll, seed=args.seed + i, env_kwargs=env_kwargs)
            for i in range(args.repeats)
        ]
        best = max(runs, key=lambda r: r["steps_per_second"])
        result["runs"]["ragdoll" if ragdoll else "no_ragdoll"] = {
            "steps_per_second": [r["steps_per_second"] for r in runs],
            "step_only_per_second": [r["step_only_per_second"] for r in runs],
            "best": best,
        }
    text = json.dumps(result, indent=2)
    print(text)
    if args.json is not None:
        args.json.write_text(text + "\n")
    return 0


if __name__ == "__main__":
    sys.exit(main())

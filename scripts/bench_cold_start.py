"""A cold start against a warm one: ``fpg-gym demo`` with an empty numba cache, then again.

For each checkout (its root on ``PYTHONPATH``, as ``scripts/bench_against.py`` does: the same
installed packages, e.g. a ``git worktree`` of the baseline), a round runs the demo with
``NUMBA_CACHE_DIR`` pointing to a new empty folder (every kernel compiles, as on a fresh
install) and then a second time with the same folder (every kernel loads), and reports the wall
time and the CPU time (user + system of the demo and its worker processes) of both and their
difference. A cold demo that leaves a process compiling in the background (its last line names
the pid) is followed until that process ends, and the process's CPU seconds are reported on their
own; the warm demo starts after it. The checkouts alternate round by round, so that both see the
same load of this shared machine. What the background process compiles, function by function:
``scripts/bench_compiled_modules.py``.

Usage::

    git worktree add /tmp/base ccc59f8
    python scripts/bench_cold_start.py . /tmp/base --rounds 2 --json /tmp/cold.json
    python scripts/bench_cold_start.py . --rounds 1 -- --quick --workers 1
"""

from __future__ import annotations

import argparse
import json
import os
import re
import resource
import shutil
import subprocess
import sys
import tempfile
import time
from pathlib import Path
from typing import Any


def _demo(checkout: Path, cache: Path, demo_args: list[str]) -> tuple[float, float, float]:
    """Wall and CPU seconds of one ``fpg-gym demo`` of ``checkout`` with numba's cache in
    ``cache``, and the CPU seconds of the process it left compiling in the background (waited
    for; 0 without one)."""
    env = dict(os.environ, NUMBA_CACHE_DIR=str(cache), PYTHONPATH=str(checkout))
    out = cache.parent / (cache.name + "_demo")
    command = [sys.executable, "-m", "fpg_gym.cli", "demo", "--out", str(out), *demo_args]
    before = resource.getrusage(resource.RUSAGE_CHILDREN)
    started = time.perf_counter()
    # run in the checkout: ``python -m`` puts the working directory first on sys.path
    done = subprocess.run(
        command, env=env, check=True, stdout=subprocess.PIPE, text=True, cwd=checkout
    )
    wall = time.perf_counter() - started
    after = resource.getrusage(resource.RUSAGE_CHILDREN)
    cpu = after.ru_utime - before.ru_utime + after.ru_stime - before.ru_stime
    shutil.rmtree(out, ignore_errors=True)
    background = _BACKGROUND.search(done.stdout)
    return wall, cpu, _follow(int(background.group(1))) if background else 0.0


#: The demo's line on a cold cache naming the process that compiles in the background.
_BACKGROUND = re.compile(r"at the lowest priority \(pid (\d+)\)")


def _follow(pid: int) -> float:
    """CPU seconds of process ``pid`` (user + system, with its waited-for children) from
    ``/proc``, read until it ends (Linux only; the last 0.1 s may be missed)."""
    ticks = os.sysconf("SC_CLK_TCK")
    seconds = 0.0
    while True:
        try:
            fields = Path(f"/proc/{pid}/stat").read_text().rsplit(")", 1)[1].split()
        except (FileNotFoundError, ProcessLookupError):
            return seconds
        if fields[0] == "Z":
            return seconds
        seconds = sum(int(f) for f in fields[11:15]) / ticks  # utime stime cutime cstime
        time.sleep(0.1)


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("checkouts", nargs="+", type=Path, help="checkout roots")
    parser.add_argument("--rounds", type=int, default=2)
    parser.add_argument("--json", type=Path, default=None, help="write the figures here")
    argv = sys.argv[1:] if argv is None else argv
    split = argv.index("--") if "--" in argv else len(argv)
    args = parser.parse_args(argv[:split])  # after "--": fpg-gym demo's own arguments
    args.demo_args = argv[split + 1 :]
    figures: dict[str, list[dict[str, Any]]] = {}
    for round_ in range(args.rounds):
        for checkout in args.checkouts if round_ % 2 == 0 else args.checkouts[::-1]:
            folder = Path(tempfile.mkdtemp(prefix="fpg-gym-cold-"))
            cold = _demo(checkout.resolve(), folder / "numba", args.demo_args)
            warm = _demo(checkout.resolve(), folder / "numba", args.demo_args)
            load = os.getloadavg()[0]
            figures.setdefault(str(checkout), []).append({"cold": cold, "warm": warm, "load": load})
            print(
                f"round {round_} {checkout}: cold {cold[0]:.1f} s ({cold[1]:.1f} CPU s), warm "
                f"{warm[0]:.1f} s ({warm[1]:.1f} CPU s): +{cold[0] - warm[0]:.1f} s "
                f"(+{cold[1] - warm[1]:.1f} CPU s), compiling in the background after the cold "
                f"demo {cold[2]:.1f} CPU s, load {load:.1f}",
                flush=True,
            )
            shutil.rmtree(folder, ignore_errors=True)
    if args.json is not None:
        args.json.write_text(json.dumps(figures, indent=1), encoding="utf-8")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())

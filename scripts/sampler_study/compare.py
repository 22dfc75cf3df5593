"""The embedded and Bandai protocols: ``fpg-gym train-sampler`` for the supervised and the PPO
sampler, then ``fpg-gym compare`` on the ``*-many`` scenarios against the local search, with
random search and each sampler's anchor and mean alone as diagnostics."""

from __future__ import annotations

import argparse
import shlex
import subprocess
import sys
import time
from pathlib import Path
from typing import Any

import numpy as np

import optimizers
from fpg_gym.experiments import CompareConfig, run_compare
from fpg_gym.experiments.report import markdown_table
from fpg_gym.experiments.store import frames_path, load_frames, read_rows
from policies.learned_optimizers import LearnedSampler
from policies.loading import load_sampler
from policies.sampler import AnchorSampler
from sampler_study import REPO, SCENARIOS
from sampler_study.scoring import mean_only


def sh(args: list[str], log: Path) -> float:
    """Run a command (echoed, output appended to ``log``); returns its wall time."""
    line = " ".join(shlex.quote(a) for a in args)
    print(f"$ {line}", flush=True)
    start = time.perf_counter()
    with log.open("a") as handle:
        handle.write(f"$ {line}\n")
        handle.flush()
        subprocess.run(args, check=True, stdout=handle, stderr=subprocess.STDOUT, cwd=REPO)
    seconds = time.perf_counter() - start
    print(f"  ({seconds:.1f} s)", flush=True)
    return seconds


def aggregate(folder: Path) -> dict[str, dict[str, float]]:
    """Frame-pooled figures per method of a compare folder."""
    out: dict[str, dict[str, list[np.ndarray]]] = {}
    for row in read_rows(folder / "results.csv"):
        path = frames_path(folder, row["episode"], row["method"])
        frames = load_frames(path, ("errors", "ms", "energy", "evaluations"))
        acc = out.setdefault(row["method"], {"errors": [], "ms": [], "energy": [], "ev": []})
        acc["errors"].append(frames["errors"])
        acc["ms"].append(frames["ms"])
        acc["energy"].append(frames["energy"])
        acc["ev"].append(frames["evaluations"])
    table = {}
    for method, acc in out.items():
        errors = np.concatenate(acc["errors"])
        table[method] = {
            "episodes": len(acc["errors"]),
            "frames": len(errors),
            "mean_energy": float(np.mean(np.concatenate(acc["energy"]))),
            "mean_error": float(np.mean(errors)),
            "err02": float(100 * np.mean(errors >= 0.2)),
            "ms": float(np.mean(np.concatenate(acc["ms"]))),
            "evaluations": float(np.mean(np.concatenate(acc["ev"]))),
        }
    return table


def markdown(table: dict[str, dict[str, float]], names: dict[str, str], baseline: str) -> str:
    """Each method's row of :func:`aggregate`'s table (``names``: its label), its mean error's
    change against ``baseline``'s."""
    base = table[baseline]["mean_error"]
    columns = ["method", "evaluations/frame", "mean energy", "mean error (m)", "vs local search"]
    columns += ["Err0.2 (%)", "ms/frame"]
    rows = [
        [
            names.get(method, method),
            f"{row['evaluations']:.0f}",
            f"{row['mean_energy']:.4f}",
            f"{row['mean_error']:.4f}",
            f"{100 * (row['mean_error'] / base - 1):+.1f} %",
            f"{row['err02']:.1f}",
            f"{row['ms']:.2f}",
        ]
        for method, row in table.items()
    ]
    return markdown_table(columns, rows)


def diagnostics(
    folder: Path, graph: str, clips: list[str], models: dict[str, str], max_frames: int | None
) -> None:
    """random-search (200), the anchor alone and each sampler's mean alone, on the same
    episodes as the main comparison (in this process: the extra optimisers are registered
    here)."""

    def anchor_only(path: str, **_: Any) -> Any:
        return LearnedSampler(AnchorSampler(load_sampler(path).spec), samples=1)

    optimizers.register_prefix("mean-only", mean_only, overwrite=True)
    optimizers.register_prefix("anchor-only", anchor_only, overwrite=True)
    first = next(iter(models.values()))
    methods = [f"fpg:anchor-only:{first}"] + [f"fpg:mean-only:{m}" for m in models.values()]
    common = {
        "graph": graph,
        "clips": clips,
        "scenarios": SCENARIOS.split(","),
        "max_frames": max_frames,
        "workers": 1,
    }
    for name, budget, chosen in (
        ("diagnostics", 2000, methods),
        ("random200", 200, ["fpg:random-search"]),
    ):
        config = CompareConfig(
            out=str(folder / name), methods=chosen, budget=budget, baseline=chosen[0], **common
        )
        print(f"compare (API) {name}: {', '.join(chosen)} budget {budget}", flush=True)
        run_compare(config, progress=False, plots=False, log=lambda _: None)


def protocol(
    name: str,
    out: Path,
    graph: str,
    train_clips: list[str],
    eval_clips: list[str],
    args: argparse.Namespace,
    extra_train: list[str],
) -> str:
    folder = out / name
    folder.mkdir(parents=True, exist_ok=True)
    log = folder / "log.txt"
    timings: dict[str, float] = {}
    models = {"supervised": str(folder / "sampler_sup"), "ppo": str(folder / "sampler_ppo")}
    base = ["fpg-gym", "train-sampler", "--graph", graph, "--quiet", *extra_train]
    if train_clips:
        base += ["--clips", *train_clips]
    timings["train supervised"] = sh(
        [*base, "--kind", "supervised", "--out", models["supervised"], "--timesteps",
         str(args.sup_timesteps)],
        log,
    )  # fmt: skip
    timings["train ppo"] = sh(
        [*base, "--kind", "rl", "--algo", "ppo", "--out", models["ppo"], "--timesteps",
         str(args.rl_timesteps)],
        log,
    )  # fmt: skip
    optimizer_list = ["local-search"] + [
        f"{kind}:{path}" for path in models.values() for kind in ("learned", "learned+search")
    ]
    frames = ["--max-frames", str(args.max_frames)] if args.max_frames else []
    compare = folder / "compare"
    timings["compare"] = sh(
        ["fpg-gym", "compare", "--graph", graph, "--clips", *eval_clips, *frames,
         "--scenarios", SCENARIOS, "--optimizers", ",".join(optimizer_list),
         "--workers", "1", "--fresh", "--no-plots", "--quiet", "--out", str(compare)],
        log,
    )  # fmt: skip
    diagnostics(folder, graph, eval_clips, models, args.max_frames)
    table: dict[str, dict[str, float]] = {}
    table.update(aggregate(compare))
    table.update(aggregate(folder / "random200"))
    table.update(aggregate(folder / "diagnostics"))
    names = {"fpg:local-search": "local-search (2,000)", "fpg:random-search": "random-search (200)"}
    for kind, path in models.items():
        names[f"fpg:learned:{path}"] = f"learned:{kind} (200)"
        names[f"fpg:learned+search:{path}"] = f"learned+search:{kind} (200)"
        names[f"fpg:mean-only:{path}"] = f"{kind} mean alone (1)"
    names[f"fpg:anchor-only:{models['supervised']}"] = "anchor alone (1)"
    text = markdown(table, names, "fpg:local-search")
    timing = ", ".join(f"{k} {v:.0f} s" for k, v in timings.items())
    report = f"### {name}\n\n{text}\n\nWall times: {timing}.\n"
    (folder / "table.md").write_text(report)
    print(report, flush=True)
    return report


def embedded_protocol(args: argparse.Namespace) -> str:
    """The embedded DeepMimic clips: the default graph without the four evaluated clips."""
    return protocol("embedded", args.out, "default", [], ["default"], args, [])


def bandai_protocol(args: argparse.Namespace) -> str:
    """Bandai Namco dataset-1 split by whole takes (``scripts/holdout_split.py``): a graph of
    the graph takes, the first ``--eval-takes`` held-out takes (``--max-frames``) evaluated."""
    folder = args.out / "bandai"
    split = folder / "split"
    log = folder / "log.txt"
    folder.mkdir(parents=True, exist_ok=True)
    sh(
        [sys.executable, "scripts/holdout_split.py", "--data", str(args.data),
         "--out-dir", str(split), "--eval-count", str(args.eval_takes)],
        log,
    )  # fmt: skip
    graph = folder / "graph.npz"
    if not graph.is_file():
        sh(["fpg-gym", "build-graph", f"@{split}/graph_takes.txt", "--out", str(graph),
            "--quiet"], log)  # fmt: skip
    eval_takes = (split / "eval_takes.txt").read_text().split()
    return protocol(
        "bandai",
        args.out,
        str(graph),
        [f"@{split}/graph_takes.txt"],
        eval_takes,
        args,
        ["--max-frames", str(args.max_frames)],
    )

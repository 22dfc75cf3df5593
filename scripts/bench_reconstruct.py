"""Accuracy and speed of the reconstruction pipeline on held-out Bandai Namco takes.

What it measures (issue 5's acceptance):

1. **Accuracy.** The Bandai Namco ``dataset-1`` takes (whole files) are split with a fixed seed:
   ``--holdout`` of them (20 %) are held out, the graph is built from the others
   (``thres1 = 0.2``; ``--with-dataset2`` adds all of ``dataset-2`` to the graph). ``--clips``
   held-out takes (the first ones of the shuffled held-out list, each cut to ``--frames``
   frames) are simulated in every ``*-many`` scenario (seed = ``--seed`` + clip number) and
   reconstructed by several configurations (selector x optimiser, no ragdoll). The table gives
   FPG Eq. 13 mean error and Err0.2 of the raw stream and of each reconstruction.
2. **Speed.** Median / p95 frame time and median selection time of graph and brute-force
   selection on graphs of three sizes (``thres1`` 0.2, 0.1, 0.06 on the same training takes).
3. **Determinism.** The main configuration twice with the same seed: identical output.

BLAS threads are limited to one (``OPENBLAS_NUM_THREADS=1`` unless set): the per-frame matrices
are tiny and multi-threaded BLAS only adds contention.

Usage::

    python scripts/bench_reconstruct.py                      # default subset (~3 min on 2 cores)
    python scripts/bench_reconstruct.py --clips 16 --frames 0 --json out.json   # larger
"""

from __future__ import annotations

import os

os.environ.setdefault("OPENBLAS_NUM_THREADS", "1")
os.environ.setdefault("OMP_NUM_THREADS", "1")

import argparse
import json
import sys
import time
from pathlib import Path
from typing import Any

import numpy as np

from fpg_gym.core.holdout import HOLDOUT_SEED, HOLDOUT_SHARE, split_takes

REPO = Path(__file__).resolve().parents[1]
DEFAULT_DATA = REPO.parent / "shared" / "data"
SCENARIOS = ("front-many", "left45-many", "right45-many")
CONFIGS: dict[str, tuple[str, str, dict[str, Any]]] = {
    "graph + local-search": ("graph", "local-search", {}),
    "brute-force + local-search": ("brute-force", "local-search", {}),
    "graph + none": ("graph", "none", {}),
    "graph + random-search": ("graph", "random-search", {}),
    "graph + local-search (generic length prior)": (
        "graph",
        "local-search",
        {"length_prior": "default"},
    ),
    "graph + local-search (no left/right fix)": (
        "graph",
        "local-search",
        {"left_right_fix": False},
    ),
    "graph + local-search (no recovery)": ("graph", "local-search", {"recovery_factor": None}),
    "graph + local-search (paper's strict stop)": ("graph", "local-search-strict", {}),
}


def make_optimizer(name: str) -> Any:
    """A registered optimiser; ``local-search-strict`` is local search with Shum's stop rule."""
    import optimizers

    if name == "local-search-strict":
        return optimizers.make("local-search", shrink=None)
    return optimizers.make(name)


def summarise(truth: np.ndarray, estimate: np.ndarray) -> tuple[float, float]:
    from fpg_gym.core import metrics

    errors = metrics.frame_error(truth, estimate)
    return float(errors.mean()), 100.0 * metrics.err_ratio(errors)


def parse_args(argv: list[str] | None) -> argparse.Namespace:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--data", type=Path, default=DEFAULT_DATA)
    parser.add_argument("--holdout", type=float, default=HOLDOUT_SHARE)
    parser.add_argument("--split-seed", type=int, default=HOLDOUT_SEED)
    parser.add_argument("--clips", type=int, default=8, help="held-out takes evaluated")
    parser.add_argument("--frames", type=int, default=240, help="frames per take (0: all)")
    parser.add_argument("--seed", type=int, default=0, help="simulator / optimiser seed")
    parser.add_argument("--with-dataset2", action="store_true", help="add dataset-2 to the graph")
    parser.add_argument("--mirror", action="store_true", help="mirrored graph augmentation")
    parser.add_argument("--configs", default=",".join(CONFIGS), help="comma-separated subset")
    parser.add_argument("--skip-speed", action="store_true")
    parser.add_argument("--json", type=Path, help="write all figures as JSON")
    return parser.parse_args(argv)


def load_inputs(
    args: argparse.Namespace, folder: Path
) -> tuple[Any, list[Any], list[Path], list[Any]]:
    """The take split, the graph of the graph takes and the simulated held-out episodes:
    ``(graph, graph clips, evaluated files, [(clip name, scenario, recording)])``."""
    from fpg_gym.graph import FilteredPoseGraph
    from fpg_gym.io import load_clips
    from fpg_gym.simulate import simulate

    files = sorted(folder.glob("*.bvh"))
    train_files, held_files = split_takes(files, args.holdout, args.split_seed)
    eval_files = held_files[: args.clips]
    print(
        f"takes: {len(files)} in dataset-1, {len(train_files)} for the graph, "
        f"{len(held_files)} held out (split seed {args.split_seed}), {len(eval_files)} evaluated"
    )
    print("evaluated takes: " + ", ".join(f.name for f in eval_files))
    graph_inputs: list[Path] = list(train_files)
    if args.with_dataset2:
        graph_inputs += sorted((args.data / "bandai_namco" / "dataset-2").glob("*.bvh.gz"))
    train_clips = load_clips(graph_inputs, progress=True)
    eval_clips = load_clips(eval_files, progress=False)
    start = time.perf_counter()
    graph = FilteredPoseGraph.build(train_clips, thres1=0.2, mirror=args.mirror, progress=False)
    print(
        f"graph: {graph} from {sum(c.num_frames for c in train_clips)} poses "
        f"in {time.perf_counter() - start:.1f} s"
    )

    recordings = []
    for i, clip in enumerate(eval_clips):
        positions = clip.positions if args.frames <= 0 else clip.positions[: args.frames]
        for scenario in SCENARIOS:
            rec = simulate(positions, scenario, seed=args.seed + i)
            recordings.append((clip.name, scenario, rec))
    frames = sum(r.num_frames for _, _, r in recordings)
    print(f"recordings: {len(recordings)} ({frames} frames)")
    return graph, train_clips, eval_files, recordings


def selection_ms(arrays: dict[str, np.ndarray]) -> np.ndarray:
    """Each frame's selection time (ms) of a reconstruction's arrays."""
    return arrays["ms_stages"][:, list(arrays["stage_names"]).index("selection")]


def run_config(
    graph: Any, name: str, recordings: list[Any], seed: int
) -> tuple[np.ndarray, dict[str, Any], dict[str, list[np.ndarray]]]:
    """One configuration of :data:`CONFIGS` on every recording: its concatenated poses, its
    figures but the accuracy (times, recoveries, evaluations, relabelled frames) and its
    frame errors by scenario."""
    from tqdm import tqdm

    from fpg_gym.core import metrics
    from fpg_gym.reconstruct import Reconstructor

    selector, optimizer, overrides = CONFIGS[name]
    reconstructor = Reconstructor(graph, selector=selector, **overrides)
    poses, ms, selection = [], [], []
    recoveries = relabelled = 0
    evaluations: list[np.ndarray] = []
    by_scenario: dict[str, list[np.ndarray]] = {}
    for _clip_name, scenario, rec in tqdm(recordings, desc=name, leave=False):
        result = reconstructor.reconstruct(rec, make_optimizer(optimizer), rng=seed)
        poses.append(result.poses)
        arrays = result.arrays()
        ms.append(arrays["ms_per_frame"])
        selection.append(selection_ms(arrays))
        recoveries += int(arrays["recovered"].sum())
        evaluations.append(arrays["evaluations"])
        relabelled += int(np.count_nonzero(arrays["labelling"]))
        by_scenario.setdefault(scenario, []).append(
            metrics.frame_error(rec.ground_truth, result.poses)
        )
    all_ms = np.concatenate(ms)
    figures = {
        "ms_per_frame_median": float(np.median(all_ms)),
        "ms_per_frame_p95": float(np.percentile(all_ms, 95)),
        "selection_ms_median": float(np.median(np.concatenate(selection))),
        "recoveries": recoveries,
        "evaluations_mean": float(np.concatenate(evaluations).mean()),
        "relabelled_frames": relabelled,
    }
    return np.concatenate(poses), figures, by_scenario


def accuracy(
    graph: Any, recordings: list[Any], selected: list[str], seed: int, report: dict[str, Any]
) -> dict[str, np.ndarray]:
    """Every selected configuration's figures into ``report`` (``accuracy``, ``raw``,
    ``per_scenario_mean_error_m``); returns each configuration's poses."""
    truth = np.concatenate([r.ground_truth for _, _, r in recordings])
    raw = np.concatenate([r.positions for _, _, r in recordings])
    raw_mean, raw_err = summarise(truth, raw)
    per_scenario: dict[str, dict[str, list[np.ndarray]]] = {}
    outputs: dict[str, np.ndarray] = {}
    for name in selected:
        out, figures, by_scenario = run_config(graph, name, recordings, seed)
        for scenario, errors in by_scenario.items():
            per_scenario.setdefault(scenario, {})[name] = errors
        outputs[name] = out
        mean, err = summarise(truth, out)
        report["accuracy"][name] = {
            "mean_error_m": mean,
            "err02_pct": err,
            "mean_error_reduction_pct": 100.0 * (1 - mean / raw_mean),
            "err02_reduction_pct": 100.0 * (1 - err / raw_err) if raw_err > 0 else None,
            **figures,
        }
    report["raw"] = {"mean_error_m": raw_mean, "err02_pct": raw_err}
    per_raw = {}
    per_mean: dict[str, dict[str, float]] = {}
    for scenario in SCENARIOS:
        t = np.concatenate([r.ground_truth for _, s, r in recordings if s == scenario])
        p = np.concatenate([r.positions for _, s, r in recordings if s == scenario])
        per_raw[scenario] = summarise(t, p)[0]
        per_mean[scenario] = {
            n: float(np.concatenate(per_scenario[scenario][n]).mean()) for n in selected
        }
    report["per_scenario_mean_error_m"] = {"raw": per_raw, **per_mean}
    return outputs


def print_accuracy(report: dict[str, Any], selected: list[str]) -> None:
    """The accuracy table, each configuration's counts and the table by scenario."""
    raw_mean, raw_err = report["raw"]["mean_error_m"], report["raw"]["err02_pct"]
    print()
    print(
        "| configuration (no ragdoll) | mean error (m) | Err0.2 (%) | mean error cut | "
        "Err0.2 cut | ms/frame median | ms/frame p95 | selection ms |"
    )
    print("| --- | --- | --- | --- | --- | --- | --- | --- |")
    print(f"| raw Kinect (simulated) | {raw_mean:.4f} | {raw_err:.1f} | | | | | |")
    for name in selected:
        acc = report["accuracy"][name]
        mean, err = acc["mean_error_m"], acc["err02_pct"]
        cut = 100 * (1 - mean / raw_mean)
        ecut = f"{100 * (1 - err / raw_err):.0f} %" if raw_err > 0 else "n/a"
        print(
            f"| {name} | {mean:.4f} | {err:.1f} | {cut:.0f} % | {ecut} | "
            f"{acc['ms_per_frame_median']:.2f} | {acc['ms_per_frame_p95']:.2f} | "
            f"{acc['selection_ms_median']:.3f} |"
        )
    print()
    for name in selected:
        acc = report["accuracy"][name]
        print(
            f"{name}: {acc['evaluations_mean']:.0f} evaluations per frame, "
            f"{acc['recoveries']} recoveries, {acc['relabelled_frames']} relabelled "
            f"frames of {report['frames']}"
        )
    print()
    per = report["per_scenario_mean_error_m"]
    print("| scenario | raw | " + " | ".join(selected) + " |")
    print("| --- | --- | " + " | ".join("---" for _ in selected) + " |")
    for scenario in SCENARIOS:
        cells = " | ".join(f"{per[scenario][n]:.4f}" for n in selected)
        print(f"| {scenario} | {per['raw'][scenario]:.4f} | {cells} |")


def deterministic(
    graph: Any, name: str, recordings: list[Any], first: np.ndarray, seed: int
) -> bool:
    """Whether configuration ``name`` gives the first recording's ``first`` poses again."""
    from fpg_gym.reconstruct import Reconstructor

    selector, optimizer, overrides = CONFIGS[name]
    _, _, rec = recordings[0]
    again = Reconstructor(graph, selector=selector, **overrides).reconstruct(
        rec, make_optimizer(optimizer), rng=seed
    )
    return bool(np.array_equal(again.poses, first[: rec.num_frames]))


def speed(train_clips: list[Any], recordings: list[Any], args: argparse.Namespace) -> list[Any]:
    """Graph and brute-force selection on graphs of three sizes (printed as a table)."""
    from fpg_gym.graph import FilteredPoseGraph
    from fpg_gym.reconstruct import Reconstructor

    print(
        "\n| graph thres1 | nodes | mean degree | selector | nodes scored | "
        "selection ms (median) | ms/frame median | ms/frame p95 |"
    )
    print("| --- | --- | --- | --- | --- | --- | --- | --- |")
    rows = []
    recs = [r for _, s, r in recordings if s == SCENARIOS[0]][:3]
    for thres1 in (0.2, 0.1, 0.06):
        g = FilteredPoseGraph.build(train_clips, thres1=thres1, mirror=args.mirror, progress=False)
        for selector in ("graph", "brute-force"):
            reconstructor = Reconstructor(g, selector=selector)
            ms, sel, scored = [], [], []
            for rec in recs:
                arrays = reconstructor.reconstruct(rec, "local-search", rng=args.seed).arrays()
                ms.append(arrays["ms_per_frame"])
                sel.append(selection_ms(arrays))
                scored.append(arrays["num_scored"])
            m, s = np.concatenate(ms), np.concatenate(sel)
            row = {
                "thres1": thres1,
                "nodes": g.num_nodes,
                "mean_degree": g.stats["mean_degree"],
                "selector": selector,
                "nodes_scored_median": float(np.median(np.concatenate(scored))),
                "selection_ms_median": float(np.median(s)),
                "ms_per_frame_median": float(np.median(m)),
                "ms_per_frame_p95": float(np.percentile(m, 95)),
            }
            rows.append(row)
            print(
                f"| {thres1} | {g.num_nodes} | {row['mean_degree']:.1f} | {selector} | "
                f"{row['nodes_scored_median']:.0f} | {row['selection_ms_median']:.3f} | "
                f"{row['ms_per_frame_median']:.2f} | {row['ms_per_frame_p95']:.2f} |"
            )
    return rows


def main(argv: list[str] | None = None) -> int:
    args = parse_args(argv)
    folder = args.data / "bandai_namco" / "dataset-1"
    if not folder.is_dir():
        print(
            f"bench_reconstruct: {folder} is absent (see ../shared/data/README.md)", file=sys.stderr
        )
        return 2
    graph, train_clips, eval_files, recordings = load_inputs(args, folder)
    report: dict[str, Any] = {
        "graph": {"nodes": graph.num_nodes, "edges": graph.num_edges, "thres2": graph.thres2},
        "evaluated_takes": [f.name for f in eval_files],
        "frames": sum(r.num_frames for _, _, r in recordings),
        "accuracy": {},
    }
    selected = [c.strip() for c in args.configs.split(",") if c.strip()]
    outputs = accuracy(graph, recordings, selected, args.seed, report)
    print_accuracy(report, selected)
    # Determinism: the main configuration again with the same seed.
    main_name = selected[0]
    identical = deterministic(graph, main_name, recordings, outputs[main_name], args.seed)
    report["deterministic"] = identical
    print(f"\ndeterminism: {main_name}, same seed twice -> identical output: {identical}")
    if not args.skip_speed:
        report["speed"] = speed(train_clips, recordings, args)
    if args.json:
        args.json.write_text(json.dumps(report, indent=2))
        print(f"\nwritten {args.json}")
    return 0


if __name__ == "__main__":
    sys.exit(main())

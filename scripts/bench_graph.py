"""Scaling benchmark of the Filtered Pose Graph build (FPG Alg. 1–4) on Bandai Namco data.

Reads every clip once (the read time is reported, not counted in build times), then builds
graphs for several input sizes and thres1 values, with and without mirroring, and prints a
markdown table: poses in, nodes, edges, mean degree, thres2, build seconds, peak MiB.

Subsets are whole takes: a fixed permutation (``--seed``) of the files picks the first
``fraction`` of them, which are then built in their sorted (input) order. Peak memory is the
build's peak of traced allocations (``tracemalloc``, numpy arrays included), measured in a
separate untimed build unless ``--no-memory``; the process's peak RSS is printed at the end.

Examples
--------
python scripts/bench_graph.py                      # the scaling table (a minute or two)
python scripts/bench_graph.py --full-only          # full set at thres1 = 0.2, with/without mirror
python scripts/bench_graph.py --fractions 0.1 --thres1 0.2 0.3 --no-memory
"""

from __future__ import annotations

import argparse
import json
import resource
import sys
import time
import tracemalloc
from pathlib import Path

import numpy as np

REPO = Path(__file__).resolve().parents[1]
DEFAULT_DATA = REPO.parent / "shared" / "data" / "bandai_namco"


def parse_args(argv: list[str] | None = None) -> argparse.Namespace:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--data", type=Path, default=DEFAULT_DATA, help="Bandai Namco folder")
    parser.add_argument("--fractions", type=float, nargs="+", default=[0.125, 0.25, 0.5, 1.0])
    parser.add_argument("--thres1", type=float, nargs="+", default=[0.1, 0.15, 0.2, 0.3])
    parser.add_argument(
        "--mirror-fractions",
        type=float,
        nargs="*",
        default=[0.25, 1.0],
        help="fractions also built with --mirror (at every thres1)",
    )
    parser.add_argument("--full-only", action="store_true", help="only the full set at 0.2 m")
    parser.add_argument("--no-memory", action="store_true", help="skip the tracemalloc builds")
    parser.add_argument("--seed", type=int, default=0, help="seed of the subset permutation")
    parser.add_argument("--workers", type=int, default=None, help="reader processes")
    parser.add_argument("--json", type=Path, default=None, help="also write the rows as JSON")
    return parser.parse_args(argv)


def measure(clips: list, thres1: float, mirror: bool, memory: bool) -> dict[str, object]:
    """Build once for the time (and stats), once more under tracemalloc for the peak."""
    from fpg_gym.graph import FilteredPoseGraph

    graph = FilteredPoseGraph.build(clips, thres1=thres1, mirror=mirror, progress=False)
    row: dict[str, object] = {
        key: graph.stats[key]
        for key in ("poses", "intra_nodes", "nodes", "edges", "mean_degree", "thres2", "seconds")
    }
    row.update(thres1=thres1, mirror=mirror, clips=len(clips), peak_mib=None)
    for stage in ("normalise", "intra", "inter", "edges"):
        row[f"seconds_{stage}"] = graph.stats[f"seconds_{stage}"]
    if memory:
        del graph
        tracemalloc.start()
        tracemalloc.reset_peak()
        FilteredPoseGraph.build(clips, thres1=thres1, mirror=mirror, progress=False)
        row["peak_mib"] = tracemalloc.get_traced_memory()[1] / 2**20
        tracemalloc.stop()
    return row


def print_table(rows: list[dict[str, object]]) -> None:
    print(
        "| poses in | clips | mirror | thres1 (m) | after Alg. 1 | nodes | edges | mean degree "
        "| thres2 (m) | build s | (intra / inter / edges s) | peak MiB |"
    )
    print("|" + " ---: |" * 12)
    for r in rows:
        peak = "–" if r["peak_mib"] is None else f"{r['peak_mib']:.0f}"
        print(
            f"| {r['poses']:,} | {r['clips']} | {'yes' if r['mirror'] else 'no'} "
            f"| {r['thres1']:.2f} "
            f"| {r['intra_nodes']:,} | {r['nodes']:,} | {r['edges']:,} | {r['mean_degree']:.1f} "
            f"| {r['thres2']:.3f} | {r['seconds']:.2f} | {r['seconds_intra']:.2f} / "
            f"{r['seconds_inter']:.2f} / {r['seconds_edges']:.2f} | {peak} |"
        )
    sys.stdout.flush()


def main(argv: list[str] | None = None) -> int:
    from fpg_gym.io import load_clips

    args = parse_args(argv)
    start = time.perf_counter()
    clips = load_clips([args.data], workers=args.workers, progress=False)
    read_seconds = time.perf_counter() - start
    frames = sum(c.num_frames for c in clips)
    print(f"read {len(clips)} clips, {frames:,} poses from {args.data} in {read_seconds:.2f} s")
    order = np.random.default_rng(args.seed).permutation(len(clips))

    configs: list[tuple[float, float, bool]] = []
    if args.full_only:
        configs = [(1.0, 0.2, False), (1.0, 0.2, True)]
    else:
        for fraction in args.fractions:
            for thres1 in args.thres1:
                configs.append((fraction, thres1, False))
                if any(np.isclose(fraction, f) for f in args.mirror_fractions):
                    configs.append((fraction, thres1, True))

    rows = []
    for fraction, thres1, mirror in configs:
        count = max(1, round(fraction * len(clips)))
        subset = [clips[i] for i in sorted(order[:count].tolist())]
        row = measure(subset, thres1, mirror, memory=not args.no_memory)
        row["fraction"] = fraction
        rows.append(row)
        print(
            f"  fraction {fraction:g}, thres1 {thres1:g}, mirror {mirror}: {row['nodes']} nodes, "
            f"{row['seconds']:.2f} s",
            file=sys.stderr,
        )
    print_table(rows)
    peak_rss = resource.getrusage(resource.RUSAGE_SELF).ru_maxrss / 1024
    print(f"process peak RSS {peak_rss:.0f} MiB (includes the {frames:,} loaded poses)")
    if args.json:
        args.json.write_text(json.dumps({"read_seconds": read_seconds, "rows": rows}, indent=1))
    return 0


if __name__ == "__main__":
    sys.exit(main())

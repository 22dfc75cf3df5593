"""Split Bandai Namco takes into a graph set and an evaluation set, by whole files.

Accuracy is only meaningful on takes the pose graph was not built from (``../shared/data/
README.md``: "split by take (whole files), with a fixed, documented seed or list, never by
frame"). For each dataset folder, the sorted take files are shuffled with ``--seed`` and the
first ``--eval-share`` of them are held out for evaluation; the rest build the graph. The
split is :func:`fpg_gym.core.holdout.split_takes` with its default seed (2016) and share (0.2), as
in ``fpg-gym bench``, so both use the same held-out takes of ``dataset-1``.

Writes two lists, one path per line, usable as ``@file`` arguments of every ``fpg-gym`` command::

    python scripts/holdout_split.py --out-dir runs/split
    fpg-gym build-graph @runs/split/graph_takes.txt --out runs/bandai.npz
    fpg-gym compare --graph runs/bandai.npz --clips @runs/split/eval_takes.txt ...

``--eval-count N`` keeps only the first N held-out takes in ``eval_takes.txt`` (the others are
still left out of the graph: they are in ``eval_takes_all.txt``).
"""

from __future__ import annotations

import argparse
import sys
from pathlib import Path

from fpg_gym.core.holdout import HOLDOUT_SEED, HOLDOUT_SHARE, split_takes

REPO = Path(__file__).resolve().parents[1]
DEFAULT_DATA = REPO.parent / "shared" / "data" / "bandai_namco"


def _takes(folder: Path) -> list[Path]:
    return sorted(p for p in folder.iterdir() if p.name.endswith((".bvh", ".bvh.gz")))


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--data", type=Path, default=DEFAULT_DATA, help="bandai_namco folder")
    parser.add_argument(
        "--datasets", default="dataset-1", help="comma-separated subfolders (dataset-1,dataset-2)"
    )
    parser.add_argument(
        "--eval-share", type=float, default=HOLDOUT_SHARE, help="held-out share (0.2)"
    )
    parser.add_argument("--seed", type=int, default=HOLDOUT_SEED, help="shuffle seed (2016)")
    parser.add_argument("--eval-count", type=int, default=None, help="takes in eval_takes.txt")
    parser.add_argument("--out-dir", type=Path, required=True, help="folder for the lists")
    args = parser.parse_args(argv)
    if not 0 < args.eval_share < 1:
        parser.error(f"--eval-share: expected a share in (0, 1), got {args.eval_share}")
    graph_all: list[Path] = []
    held_all: list[Path] = []
    for name in [d.strip() for d in args.datasets.split(",") if d.strip()]:
        folder = args.data / name
        if not folder.is_dir():
            print(f"holdout_split: {folder}: no such folder", file=sys.stderr)
            return 2
        takes = _takes(folder)
        if len(takes) < 2:
            print(f"holdout_split: {folder}: fewer than two takes", file=sys.stderr)
            return 2
        graph, held = split_takes(takes, args.eval_share, args.seed)
        graph_all += graph
        held_all += held
        print(f"{name}: {len(takes)} takes -> {len(graph)} graph, {len(held)} held out")
    evaluated = held_all if args.eval_count is None else held_all[: args.eval_count]
    args.out_dir.mkdir(parents=True, exist_ok=True)
    outputs = {
        "graph_takes.txt": graph_all,
        "eval_takes_all.txt": held_all,
        "eval_takes.txt": evaluated,
    }
    for file_name, paths in outputs.items():
        (args.out_dir / file_name).write_text("".join(f"{p}\n" for p in paths))
        print(f"written {args.out_dir / file_name} ({len(paths)} takes)")
    assert not set(graph_all) & set(held_all), "a take is in both sets"
    print(f"split seed {args.seed}, eval share {args.eval_share}; evaluated takes:")
    for path in evaluated:
        print(f"  {path.name}")
    return 0


if __name__ == "__main__":
    sys.exit(main())

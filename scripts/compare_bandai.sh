#!/usr/bin/env bash
# Reproduce the README's comparison tables on held-out Bandai Namco takes (issues 8 and 11).
#
# 1. Split dataset-1 by whole take files (seed 2016, 20 % held out; scripts/holdout_split.py).
# 2. Build the pose graph from the graph takes only (thres1 0.2 m, no mirroring).
# 3. Simulate the first EVAL_TAKES held-out takes (first MAX_FRAMES frames) in the *-many
#    scenarios and compare
#    a. the optimisers x both selectors, with the reference filters (issue 8), and
#    b. raw, holt, kalman, shum and fpg, each with and without the ragdoll (issue 11).
#
# Usage: scripts/compare_bandai.sh [OUT_DIR]   (about 2.5 + 1.5 min on 2 cores)
# Environment: DATA (default ../shared/data/bandai_namco), EVAL_TAKES (4), MAX_FRAMES (150),
#              WORKERS (CPU count).
set -euo pipefail
cd "$(dirname "$0")/.."
OUT=${1:-runs/bandai}
DATA=${DATA:-../shared/data/bandai_namco}
EVAL_TAKES=${EVAL_TAKES:-4}
MAX_FRAMES=${MAX_FRAMES:-150}
WORKERS=${WORKERS:-$(python -c "import os; print(os.cpu_count() or 1)")}

python scripts/holdout_split.py --data "$DATA" --out-dir "$OUT/split" --eval-count "$EVAL_TAKES"
fpg-gym build-graph @"$OUT/split/graph_takes.txt" --out "$OUT/graph.npz" --quiet
fpg-gym compare --graph "$OUT/graph.npz" --clips @"$OUT/split/eval_takes.txt" \
    --max-frames "$MAX_FRAMES" --scenarios front-many,left45-many,right45-many \
    --optimizers none,random-search,local-search,cma-es --selectors graph,brute-force \
    --methods raw,holt,kalman --workers "$WORKERS" --out "$OUT/optimizers"
fpg-gym compare --graph "$OUT/graph.npz" --clips @"$OUT/split/eval_takes.txt" \
    --max-frames "$MAX_FRAMES" --scenarios front-many,left45-many,right45-many \
    --methods raw,holt,holt:smoothed,kalman,shum,fpg --ragdoll both \
    --workers "$WORKERS" --out "$OUT/filters"

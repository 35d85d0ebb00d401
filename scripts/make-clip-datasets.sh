#!/usr/bin/env bash
# The clip datasets fabric from video trains on (docs/DATASETS.md): per garment, clips of a
# sampled body in its own size moving through a built-in motion (speed and amplitude
# drawn), the fabric drawn inside one of the 54 fabric classes in turn. Resumable and fair
# between garments: each pass makes one more shard (32 clips) of every garment not yet
# complete; run it again to go on.
#   CLIPS=540 PASSES=1 GARMENTS=tshirt bash scripts/make-clip-datasets.sh
set -euo pipefail
cd "$(dirname "$0")/.."
TRYON=${TRYON:-.venv/bin/tryon}
CLIPS=${CLIPS:-1080}
PASSES=${PASSES:-1000}
GARMENTS=${GARMENTS:-"tshirt skirt dress trousers longsleeve"}
EDGE=${EDGE:-0.03}
export OMP_NUM_THREADS=${OMP_NUM_THREADS:-1}
export NUMBA_NUM_THREADS=${NUMBA_NUM_THREADS:-1}
for pass in $(seq "$PASSES"); do
  for garment in $GARMENTS; do
    echo "pass $pass: $garment $(date -u +%H:%M:%S)"
    # one garment's error (no size dresses) leaves the others going
    "$TRYON" dataset clips --garment "$garment" --count "$CLIPS" --edge-length "$EDGE" --frames 25 --fps 5 \
      --bmi 17 38 --seed 0 --out "data/clips-v1/$garment" --limit 32 --quiet || echo "clips of $garment stopped"
  done
done

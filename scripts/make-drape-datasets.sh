#!/usr/bin/env bash
# The drape datasets the learned models of every garment train on (docs/DATASETS.md):
# each garment in XS-XXL, every body draped in the four sizes around its own (one smaller,
# its own, two larger), the fabric drawn per drape from the ten measured presets, a quarter
# of them blended between two. Resumable and fair between garments: each pass makes one
# more shard (32 drapes) of every garment not yet complete; run it again to go on.
#   BODIES=200 PASSES=1 bash scripts/make-drape-datasets.sh
set -euo pipefail
cd "$(dirname "$0")/.."
TRYON=${TRYON:-.venv/bin/tryon}
BODIES=${BODIES:-200}
PASSES=${PASSES:-1000}
GARMENTS=${GARMENTS:-"tshirt longsleeve trousers skirt dress"}
FABRICS="ivory-rib-knit pink-ribbon-brown white-dots-on-blk navy-sparkle-sweat camel-ponte-roma gray-interlock
 11oz-black-denim white-swim-solid tango-red-jet-set royal-target"
export OMP_NUM_THREADS=${OMP_NUM_THREADS:-1}
# one thread for numba too: two of these scripts side by side (GARMENTS=...) then share two cores without contention
export NUMBA_NUM_THREADS=${NUMBA_NUM_THREADS:-1}
for pass in $(seq "$PASSES"); do
  for garment in $GARMENTS; do
    echo "pass $pass: $garment $(date -u +%H:%M:%S)"
    # shellcheck disable=SC2086
    "$TRYON" dataset drape --garment "$garment" --sizes XS S M L XL XXL --size-window 4 --count "$BODIES" \
      --fabrics $FABRICS --fabric-mix 0.25 --edge-length 0.015 --bmi 17 38 --extrapolation-bmi 34 --seed 0 \
      --out "data/drapes-v3/$garment" --limit 32 --quiet
  done
done

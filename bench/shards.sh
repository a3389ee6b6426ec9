#!/usr/bin/env bash
# Merging parts at scale: the 49,152-facet Itokawa model subdivided twice (786,432
# facets), a spin of STEPS steps (default 128) with the default 10 W/m² CDF bins, run as
# PARTS time parts (default 64), then `slim merge` of them timed REPEAT times (default 3)
# (tables as Parquet only: CSV=true adds the CSV tables, as the scene default does)
# with /usr/bin/time -v (wall time and peak memory). Also prints the merge's own stage
# times from its run.json (reading and combining the parts against writing the tables)
# and the size of the parts on disk.
#
#   bench/shards.sh [PARTS] [STEPS] [REPEAT] [OUT]    (from the repository root)
set -euo pipefail
cd "$(dirname "$0")/.."
source bench/common.sh
PARTS=${1:-64} STEPS=${2:-128} REPEAT=${3:-3}
bench_init bench/results/shards "${4:-}"
mesh=$(subdivided_itokawa 2)
spin_scene itokawa-786k "$mesh" "$STEPS" "${CSV:-false}" >"$OUT/scene.toml"
start=$(date +%s)
for k in $(seq 1 "$PARTS"); do
  "$B" run "$OUT/scene.toml" --shard "$k/$PARTS" -o "$OUT/parts/$k" --quiet
done
echo "ran $PARTS parts in $(( $(date +%s) - start )) s; parts on disk: $(du -sh "$OUT/parts" | cut -f1)"
for r in $(seq 1 "$REPEAT"); do
  /usr/bin/time -v "$B" merge "$OUT"/parts/* -o "$OUT/merged" --quiet 2>"$OUT/time-$r.txt"
  wall=$(grep "Elapsed (wall" "$OUT/time-$r.txt" | awk '{print $NF}')
  rss=$(grep "Maximum resident" "$OUT/time-$r.txt" | awk '{print $NF}')
  stages=$(python3 -c "import json; r=json.load(open('$OUT/merged/run.json')); print(', '.join(f'{s} {t:.2f} s' for s, t in r['timings_s']))")
  echo "merge $r: wall $wall, peak $((rss / 1024)) MiB; stages: $stages"
done
echo "machine: $(grep -m1 'model name' /proc/cpuinfo | cut -d: -f2 | xargs), $(nproc) cores, $(date -u +%F)"

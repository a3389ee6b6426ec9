#!/usr/bin/env bash
# Runs that help each other build a horizon map: RUNS runs (default 2) of one scene
# started together, one thread each, the cache empty, against the same scene run alone.
# The scene: the 49,152-facet Itokawa model subdivided LEVELS times (default 0), a spin of
# 36 steps, `shadows = "horizon"`, Parquet tables only. Each case is timed REPEAT times
# (default 3), alternating, as whole processes (/usr/bin/time -v for the single run, the
# shell's clock around the group); every run's record says how many parts it built for
# another (`helped_parts`) and the tables of all runs must be byte-identical.
#
#   bench/helped_build.sh [RUNS] [LEVELS] [REPEAT] [OUT]    (from the repository root)
set -euo pipefail
cd "$(dirname "$0")/.."
source bench/common.sh
RUNS=${1:-2} LEVELS=${2:-0} REPEAT=${3:-3}
bench_init bench/results/helped_build "${4:-}"
if [[ $LEVELS == 0 ]]; then
  mesh=$(realpath data/shapes/itokawa/ItokawaHayabusa.obj)
else
  mesh=$(subdivided_itokawa "$LEVELS")
fi
spin_scene "itokawa-helped" "$mesh" 36 false 'shadows = "horizon"' >"$OUT/scene.toml"
seconds() { date +%s.%N; }
for r in $(seq 1 "$REPEAT"); do
  rm -rf "$SLIM_CACHE_DIR" "$OUT"/alone "$OUT"/run-*
  /usr/bin/time -v "$B" run "$OUT/scene.toml" -o "$OUT/alone" --threads 1 --quiet 2>"$OUT/time.txt"
  alone=$(grep "Elapsed (wall" "$OUT/time.txt" | awk '{print $NF}')
  rm -rf "$SLIM_CACHE_DIR"
  start=$(seconds)
  for k in $(seq 1 "$RUNS"); do
    "$B" run "$OUT/scene.toml" -o "$OUT/run-$k" --threads 1 --quiet &
  done
  wait
  together=$(printf "%.1f" "$(echo "$(seconds) - $start" | bc)")
  helped=$(python3 -c "
import json, sys
print(' '.join(str(m['helped_parts']) for k in range(1, $RUNS + 1)
               for m in json.load(open(f'$OUT/run-{k}/run.json'))['horizon_maps']))")
  for k in $(seq 1 "$RUNS"); do
    for t in "$OUT"/alone/*.parquet; do
      cmp -s "$t" "$OUT/run-$k/$(basename "$t")" || { echo "run $k: $(basename "$t") differs" >&2; exit 1; }
    done
  done
  echo "round $r: alone $alone (m:ss); $RUNS together ${together} s; parts built for another: $helped"
done
echo "machine: $(grep -m1 'model name' /proc/cpuinfo | cut -d: -f2 | xargs), $(nproc) cores, $(date -u +%F)"

#!/usr/bin/env bash
# A year of hourly steps at scale: the 49,152-facet Itokawa model subdivided LEVELS times
# (default 2: 786,432 facets), a spin scene of PERIODS spins × 12 steps (8,760 steps of
# 1.01 h), Parquet tables only. MODE (default approximate) is the horizon map's
# `horizon_mode` with `shadows = "horizon"`; MODE=auto leaves `shadows` to the plan (rays
# through the BVH at a year of steps). `slim run` is timed REPEAT times (default 3) with
# /usr/bin/time -v (wall time, peak memory) and each run's stage times from run.json.
#
# PERIODS (environment, default 730.04) is not a whole number, so that the spins do not
# repeat exactly and every step is computed, as a year on a real orbit would be. With
# PERIODS=730 each spin repeats the first bit for bit, and the run computes the light of
# one spin and hands it on (docs/scene.md, "Repeated steps").
#
# HOURS=1 lists instead the Sun of every true hour of Itokawa's 12.132371 h spin (8,760
# Suns of a fixed geometry, the same 1.1 AU and 15° sub-solar latitude): the spin then
# fits no whole number of steps, and 12 steps back the Sun stands 3.9° from where it
# stood, not 0.02° as in the spin scene, as on a real orbit. (Until 2026-11-29 this used
# the spin scene's 12.13 h, which is 1,213 hours to 100 spins: the year's Suns were 1,213
# directions, each listed about 7 times, bit for bit but for rounding.)
#
# The map is kept in bench/results/horizon-year-cache between invocations (its key
# follows the mesh, the settings and the map's source), so the first run of a fresh
# clone builds it: about 24 minutes on 2 cores at 786k facets; later runs read it.
#
#   [PERIODS=P | HOURS=1] bench/horizon_year.sh [LEVELS] [REPEAT] [MODE] [OUT]    (from the repository root)
set -euo pipefail
cd "$(dirname "$0")/.."
source bench/common.sh
LEVELS=${1:-2} REPEAT=${2:-3} MODE=${3:-approximate}
bench_init bench/results/horizon_year "${4:-}"
export SLIM_CACHE_DIR
SLIM_CACHE_DIR=$(realpath -m bench/results/horizon-year-cache)
mesh=$(subdivided_itokawa "$LEVELS")
PERIODS=${PERIODS:-730.04}
run_line="shadows = \"horizon\"
horizon_mode = \"$MODE\""
[[ $MODE == auto ]] && run_line=""
if [[ ${HOURS:-0} == 1 ]]; then
  hourly_scene "itokawa-hours-x4-$LEVELS" "$mesh" 8760 "$run_line" >"$OUT/scene.toml"
else
  spin_scene "itokawa-year-x4-$LEVELS" "$mesh" 12 false "$run_line" |
    sed "s/^steps_per_period = 12\$/steps_per_period = 12\nperiods = $PERIODS/" >"$OUT/scene.toml"
fi
for r in $(seq 1 "$REPEAT"); do
  if ! /usr/bin/time -v "$B" run "$OUT/scene.toml" -o "$OUT/run-$r" --quiet 2>"$OUT/time-$r.txt"; then
    cat "$OUT/time-$r.txt" >&2
    exit 1
  fi
  wall=$(grep "Elapsed (wall" "$OUT/time-$r.txt" | awk '{print $NF}')
  rss=$(grep "Maximum resident" "$OUT/time-$r.txt" | awk '{print $NF}')
  stages=$(python3 -c "import json; r=json.load(open('$OUT/run-$r/run.json')); print(', '.join(f'{s} {t:.1f} s' for s, t in r['timings_s']))")
  echo "run $r: wall $wall, peak $((rss / 1024)) MiB; stages: $stages"
  rm -rf "$OUT/run-$r"/*.parquet
done
echo "machine: $(grep -m1 'model name' /proc/cpuinfo | cut -d: -f2 | xargs), $(nproc) cores, $(date -u +%F)"

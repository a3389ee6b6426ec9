#!/usr/bin/env bash
# Checks `slim slurm --dry-run` against a real part: the 49,152-facet Itokawa model
# subdivided LEVELS times (default 3: 3,145,728 facets), a spin of STEPS steps (default
# 8,760, a year of hourly steps) with shadow rays (a year would pick a horizon map,
# whose build is another benchmark), split into PARTS time parts (default 64). Prints the
# dry run's estimate of one part, then runs part 1 under /usr/bin/time -v.
#
#   bench/slurm_estimate.sh [LEVELS] [STEPS] [PARTS] [OUT]    (from the repository root)
set -euo pipefail
cd "$(dirname "$0")/.."
source bench/common.sh
LEVELS=${1:-3} STEPS=${2:-8760} PARTS=${3:-64}
bench_init bench/results/slurm_estimate "${4:-}"
mesh=$(subdivided_itokawa "$LEVELS")
spin_scene itokawa-estimate "$mesh" "$STEPS" false 'shadows = "rays"' >"$OUT/scene.toml"
"$B" slurm "$OUT/scene.toml" --shards "$PARTS" --dry-run -o "$OUT/batch" | head -4
/usr/bin/time -v "$B" run "$OUT/scene.toml" --shard "1/$PARTS" -o "$OUT/part1" --quiet 2>"$OUT/time.txt"
echo "part 1/$PARTS measured: wall $(grep 'Elapsed (wall' "$OUT/time.txt" | awk '{print $NF}'), \
peak $(( $(grep 'Maximum resident' "$OUT/time.txt" | awk '{print $NF}') / 1024 )) MiB"
echo "machine: $(grep -m1 'model name' /proc/cpuinfo | cut -d: -f2 | xargs), $(nproc) cores, $(date -u +%F)"

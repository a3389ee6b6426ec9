#!/usr/bin/env bash
# A planned route across the 49,152-facet Eros model over a week of ~hourly steps (issue
# 19's target: under 2 s), end to end: `slim route data/eros-week.toml data/eros-route.json`
# (mesh, Eros's gravity and spin, the scene's light over 160 steps, the planner with an
# optimality gap of 0.5),
# timed as a whole process with /usr/bin/time; and the same request with gaps 1 and 0 (the
# exact search, which needs far more labels) to show what the gap buys.
#
# Out: per gap the wall times of RUNS runs (default 5; median, min, max, s), peak memory,
# labels, cost and route totals; the machine and the date.
#   bench/route_eros.sh [RUNS] [OUT_DIR]    (default 5, target/route-eros)
set -euo pipefail
cd "$(dirname "$0")/.."
source bench/common.sh
RUNS=${1:-5}
bench_init target/route-eros "${2:-}"
for GAP in 0.5 1 0; do
  python3 -c "import json,sys; d=json.load(open('data/eros-route.json')); d['optimality_gap']=$GAP; json.dump(d, open(sys.argv[1],'w'))" "$OUT/request-$GAP.json"
  for _ in $(seq "$RUNS"); do
    if /usr/bin/time -f '%e %M' -o "$OUT/time.txt" $B route data/eros-week.toml "$OUT/request-$GAP.json" \
         -o "$OUT/route-$GAP.json" -q 2> "$OUT/error-$GAP.txt"; then
      cat "$OUT/time.txt"
    else
      echo "failed: $(tail -1 "$OUT/error-$GAP.txt")" >&2
      tail -1 "$OUT/time.txt"
    fi
  done > "$OUT/times-$GAP.txt"
done
OUT="$OUT" python3 - <<'PY'
import json, os, statistics, subprocess
out = os.environ["OUT"]
cpu = [l.split(":", 1)[1].strip() for l in subprocess.run(["lscpu"], capture_output=True, text=True).stdout.splitlines() if l.startswith("Model name")]
print(f"machine: {cpu[0] if cpu else '?'}, {os.cpu_count()} cores; {subprocess.run(['date', '-u', '+%F'], capture_output=True, text=True).stdout.strip()}")
for gap in ["0.5", "1", "0"]:
    rows = [l.split() for l in open(f"{out}/times-{gap}.txt") if l.strip()]
    wall = [float(r[0]) for r in rows]
    mem = max(int(r[1]) for r in rows) / 1024
    line = f"gap {gap}: {statistics.median(wall):.2f} s median ({min(wall):.2f}–{max(wall):.2f}), {mem:.0f} MB"
    path = f"{out}/route-{gap}.json"
    err = open(f"{out}/error-{gap}.txt").read().strip()
    if err:
        line += f"; {err.splitlines()[-1]}"
    elif os.path.exists(path):
        p = json.load(open(path))["properties"]
        line += (f"; {p['labels']} labels, cost {p['cost_total']:.0f}, {len(p['facets'])} facets, "
                 f"{p['distance_m']/1000:.1f} km in {(p['driving_s']+p['waiting_s'])/3600:.1f} h, "
                 f"{p['energy_wh']:.0f} Wh, least charge {p['min_charge_wh']:.1f} Wh; "
                 f"last run: light {p['light_s']:.2f} s, search {p['search_s']:.2f} s")
    print(line)
PY

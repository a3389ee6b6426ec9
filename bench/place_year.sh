#!/usr/bin/env bash
# A year of hourly steps for one place and panel through `slim serve` (issue 19's target:
# under 50 ms per query once the horizon is cached, while a job computes).
#
# In: data/moon-haworth-year.toml (8,784 steps) copied with its kernels and shapes into a
# temporary data folder; QUERIES queries (default 20) of one place (87.9° S, 10° E) with a
# 2 m Sun-tracking panel. Out: the first query's time (builds the ephemeris' steps and the
# place's horizon), then the median, minimum and maximum of the others (s), the machine
# and the date. The year job is submitted first and computes on one thread meanwhile, as
# the target asks; on 2 cores that job shares the machine with the queries. With ALBEDO
# the scene gets `[scatter] albedo = ALBEDO`, and the panel the light its terrain scatters.
#   bench/place_year.sh [QUERIES] [OUT_DIR] [ALBEDO]    (default 20, target/place-year)
set -euo pipefail
cd "$(dirname "$0")/.."
source bench/common.sh
QUERIES=${1:-20}
bench_init target/place-year "${2:-}"
mkdir -p "$OUT/data/scenes" "$OUT/data/shapes"
cp -r "$DATA/kernels" "$OUT/data/"
cp -r "$DATA/shapes/moon" "$OUT/data/shapes/"
SCATTER=()
[ -n "${3:-}" ] && SCATTER=(-e "s|^\[ephemeris\]|[scatter]\nalbedo = $3\n\n[ephemeris]|")
sed -e 's|"kernels/|"../kernels/|' -e 's|"shapes/|"../shapes/|' "${SCATTER[@]}" \
  data/moon-haworth-year.toml > "$OUT/data/scenes/year.toml"
$B serve --data "$OUT/data" --listen 127.0.0.1:0 --job-threads 1 2> "$OUT/serve.log" &
SERVER=$!
trap 'kill $SERVER 2>/dev/null || true' EXIT
for _ in $(seq 100); do
  grep -q '^listening on ' "$OUT/serve.log" && break
  sleep 0.1
done
BASE="http://$(sed -n 's/^listening on //p' "$OUT/serve.log" | head -1)"
ID=$(curl -sf -X POST "$BASE/v1/jobs" -H 'Content-Type: application/json' \
  -d '{"scene_file": "scenes/year.toml"}' | python3 -c 'import json,sys; print(json.load(sys.stdin)["id"])')
QUERY='{"targets": [{"lat_deg": -87.9, "lon_deg": 10, "height_m": 2, "panel": {"mount": "sun_tracking"}}]}'
ask() {
  curl -sf -o "$OUT/answer.json" -w '%{time_total}\n' -X POST "$BASE/v1/jobs/$ID/irradiance" \
    -H 'Content-Type: application/json' -d "$QUERY"
}
ask > "$OUT/first.txt"
for _ in $(seq "$QUERIES"); do ask; done > "$OUT/times.txt"
STATE=$(curl -sf "$BASE/v1/jobs/$ID" | python3 -c 'import json,sys; print(json.load(sys.stdin)["state"])')
OUT="$OUT" STATE="$STATE" python3 - <<'PY'
import json, os, statistics as st
out = os.environ["OUT"]
first = float(open(f"{out}/first.txt").read())
times = [float(x) for x in open(f"{out}/times.txt").read().split()]
panel = json.load(open(f"{out}/answer.json"))["series"][0]["panel"]
print(f"first query (steps and horizon built): {first:.3f} s")
print(f"{len(times)} queries after it: median {st.median(times):.4f} s, "
      f"min {min(times):.4f} s, max {max(times):.4f} s")
print(f"{len(panel['irradiance_w_m2'])} steps; panel lit {100 * panel['lit_fraction']:.1f} % "
      f"of the year; the year job was {os.environ['STATE']} at the end")
if "scattered" in panel:
    s = panel["scattered"]
    w = s["irradiance_w_m2"]
    print(f"terrain light: {s['facets']} facets, mean {sum(w) / len(w):.3f} W/m², "
          f"largest {max(w):.2f} W/m²")
PY
lscpu | sed -n 's/^Model name: *//p'
echo "cores: $(nproc); $(date -u +%Y-%m-%dT%H:%MZ)"

#!/usr/bin/env bash
# Horizon maps against rays on the Haworth month (data/moon-haworth.toml): per wedge count
# and mode, the map's build time, the direct stage's time per step with the map cached,
# and the largest errors of mean, max, lit fraction and F(x) over all facets. Prints the
# table in docs/accuracy.md. About ten seconds on 2 cores (2026-12-03).
#   bench/horizon_accuracy.sh [OUT_DIR]    (default target/horizon-accuracy)
set -euo pipefail
cd "$(dirname "$0")/.."
source bench/common.sh
bench_init target/horizon-accuracy "${1:-}"
# The scene with `keys` added to [run], paths made absolute, written to $OUT/NAME.toml.
scene() {
  sed -e "s|^\[run\]|[run]\n$2|" "${ABSOLUTE[@]}" data/moon-haworth.toml > "$OUT/$1.toml"
}
scene rays 'shadows = "rays"'
$B run "$OUT/rays.toml" -o "$OUT/rays" > /dev/null 2>&1
for A in 32 64 128 256; do
  for mode in approximate exact; do
    rm -rf "$OUT/cache-$A"
    scene "$mode-$A" "shadows = \"horizon\"\nhorizon_mode = \"$mode\"\nhorizon_azimuths = $A\ncache_dir = \"$OUT/cache-$A\""
    $B run "$OUT/$mode-$A.toml" -o "$OUT/$mode-$A-build" > /dev/null 2>&1
    $B run "$OUT/$mode-$A.toml" -o "$OUT/$mode-$A" > /dev/null 2>&1
  done
done
# The month's scene names its Sun a point (as the tables it feeds); this run turns it into
# a disk.
scene disk-128 "shadows = \"horizon\"\ncache_dir = \"$OUT/cache-128\""
sed -i 's/^sun = "point".*/sun = "disk"/' "$OUT/disk-128.toml"
$B run "$OUT/disk-128.toml" -o "$OUT/disk-128" > /dev/null 2>&1
OUT="$OUT" python3 - <<'PY'
import csv, json, os
out = os.environ["OUT"]
def summary(d):
    rows = csv.DictReader(open(f"{out}/{d}/summary.csv"))
    return {int(r["facet"]): [float(r[k]) for k in ("mean_w_m2", "max_w_m2", "lit_fraction")]
            for r in rows if r["body"] == "haworth"}
def cdf(d):
    rows = csv.DictReader(open(f"{out}/{d}/cdf.csv"))
    return {(int(r["facet"]), r["irradiance_w_m2"]): float(r["cdf"]) for r in rows if r["body"] == "haworth"}
def record(d):
    return json.load(open(f"{out}/{d}/run.json"))
def direct_s(d):
    return sum(v for k, v in record(d)["timings_s"] if k == "direct irradiance")
ref, ref_cdf = summary("rays"), cdf("rays")
print(f"rays: direct stage {direct_s('rays') / 720 * 1e3:.2f} ms per step")
print("| wedges | mode | build (s, 2 threads) | direct stage per step (ms) | max |Δmean| (W/m²) "
      "| mean |Δmean| (W/m²) | max |Δmax| (W/m²) | max |Δlit fraction| | max |ΔF(x)| |")
print("|---:|---|---:|---:|---:|---:|---:|---:|---:|")
for a in (32, 64, 128, 256):
    for mode in ("approximate", "exact"):
        d = f"{mode}-{a}"
        s, c = summary(d), cdf(d)
        build = record(d + "-build")["horizon_maps"][0]["build_s"]
        dm = [abs(s[k][0] - ref[k][0]) for k in ref]
        dx = max(abs(s[k][1] - ref[k][1]) for k in ref)
        dl = max(abs(s[k][2] - ref[k][2]) for k in ref)
        dc = max(abs(c[k] - ref_cdf[k]) for k in ref_cdf)
        print(f"| {a} | {mode} | {build:.1f} | {direct_s(d) / 720 * 1e3:.2f} | {max(dm):.3g} "
              f"| {sum(dm) / len(dm):.3g} | {dx:.3g} | {dl:.4f} | {dc:.4f} |")
s = summary("disk-128")
dm = [abs(s[k][0] - ref[k][0]) for k in ref]
print(f"disk Sun (128 wedges, uniform) against point-Sun rays: mean |Δmean| {sum(dm) / len(dm):.3g}, "
      f"max {max(dm):.3g} W/m²; {direct_s('disk-128') / 720 * 1e3:.2f} ms per step")
PY

#!/usr/bin/env bash
# Mars-shine on Phobos (data/phobos-scatter.toml, one spin, 360 steps): error against run
# time of the planet-shine quadrature, per node count and reuse tolerance, and the
# example's own time and peak memory (three runs with an empty cache, three reading
# Phobos's form factors from it). Prints the tables in docs/scattered-light.md. The runs
# of the sweep all read the form factors the first runs cached. About
# four minutes on 2 cores; run it on an idle machine.
#   bench/planet_shine.sh [OUT_DIR]    (default target/planet-shine)
set -euo pipefail
cd "$(dirname "$0")/.."
source bench/common.sh
bench_init target/planet-shine "${1:-}"
# The example with `keys` added to [scatter], paths made absolute, run into $OUT/NAME;
# its wall time (s) and peak memory (kB) go to $OUT/NAME.time.
run() {
  sed -e "s|^albedo = 0.07 .*|albedo = 0.07\n$2|" "${ABSOLUTE[@]}" data/phobos-scatter.toml \
    > "$OUT/$1.toml"
  /usr/bin/time -f "%e %M" -o "$OUT/$1.time" $B run "$OUT/$1.toml" -o "$OUT/$1" > /dev/null 2>&1
}
for k in 1 2 3; do rm -rf "$SLIM_CACHE_DIR"; run "cold-$k" ""; done
run none 'inter_body_tolerance = 1.0\nplanet_shine = "facets"'
for n in 4 8 16; do run "order-$n" "planet_order = $n\nplanet_reuse = 0.1"; done
for r in 0.1 0.03 0.01 0; do run "reuse-$r" "planet_reuse = $r"; done
for k in 1 2 3; do run "default-$k" ""; done
OUT="$OUT" python3 - <<'PY'
import csv, os, statistics as st
out = os.environ["OUT"]
def scattered(d):
    rows = [r for r in csv.DictReader(open(f"{out}/{d}/summary.csv")) if r["body"] == "phobos"]
    return ([float(r["scattered_mean_w_m2"]) for r in rows],
            [float(r["scattered_max_w_m2"]) for r in rows])
def time(d):
    s, kb = open(f"{out}/{d}.time").read().split()[-2:]
    return float(s), int(kb) / 1024
none = scattered("none")[0]
def row(d, ref, label):
    (m, x), (mr, xr) = scattered(d), scattered(ref)
    shine = max(a - b for a, b in zip(mr, none))
    em = max(abs(a - b) for a, b in zip(m, mr))
    ex = max(abs(a - b) for a, b in zip(x, xr))
    s, mb = time(d)
    print(f"| {label} | {em:.3f} ({100 * em / shine:.1f} %) | {ex:.2f} | {s:.1f} s | {mb:.0f} MB |")
print("| setting | largest error of a facet's mean scattered (W/m², % of the largest mean Mars-shine) | of its max (W/m²) | run time | peak memory |")
print("|---|---:|---:|---:|---:|")
for n in (4, 8): row(f"order-{n}", "order-16", f"planet_order = {n} (against 16), reuse 0.1")
for r in ("0.1", "0.03", "0.01"): row(f"reuse-{r}", "reuse-0", f"planet_reuse = {r} (against 0), order 8")
s, mb = time("reuse-0"); print(f"| planet_reuse = 0 (weights rebuilt every step) | — | — | {s:.1f} s | {mb:.0f} MB |")
s, mb = time("none"); print(f"| no Mars-shine (its light left out) | — | — | {s:.1f} s | {mb:.0f} MB |")
cold = [time(f"cold-{k}") for k in (1, 2, 3)]
print(f"\ndata/phobos-scatter.toml, first run (empty cache): {st.median(t[0] for t in cold):.1f} s "
      f"median of 3, peak memory {max(t[1] for t in cold):.0f} MB")
times = [time(f"default-{k}") for k in (1, 2, 3)]
print(f"data/phobos-scatter.toml, later runs (form factors cached): {st.median(t[0] for t in times):.1f} s median of 3, "
      f"peak memory {max(t[1] for t in times):.0f} MB; largest mean Mars-shine on a facet "
      f"{max(a - b for a, b in zip(scattered('default-1')[0], none)):.2f} W/m²")
PY

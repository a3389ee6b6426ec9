# Sourced by the benchmark scripts (bench/*.sh), from the repository root.
#   bench_init DEFAULT_OUT [OUT]: builds the release binary; sets OUT (emptied), DATA
#   (the data folder, absolute) and B (the binary); points SLIM_CACHE_DIR at OUT/cache
#   so that no run reads a cache the benchmark did not build.
#   ABSOLUTE: sed arguments that make a shipped scene's kernel and shape paths absolute.
bench_init() {
  cargo build --release --quiet
  OUT=$(realpath -m "${2:-$1}")
  rm -rf "$OUT" && mkdir -p "$OUT"
  DATA=$(realpath data)
  B=${CARGO_TARGET_DIR:-target}/release/slim
  export SLIM_CACHE_DIR="$OUT/cache"
  ABSOLUTE=(-e "s|\"kernels/|\"$DATA/kernels/|" -e "s|\"shapes/|\"$DATA/shapes/|")
}

# subdivided_itokawa LEVELS: prints the path of the 49,152-facet Itokawa model split
# LEVELS times (×4 facets each), made once into bench/results/meshes.
subdivided_itokawa() {
  local mesh
  mesh=$(realpath -m "bench/results/meshes/itokawa-x4^$1.obj")
  if [[ ! -f $mesh ]]; then
    mkdir -p "$(dirname "$mesh")"
    python3 bench/subdivide_obj.py data/shapes/itokawa/ItokawaHayabusa.obj "$1" "$mesh.partial"
    mv "$mesh.partial" "$mesh"
  fi
  echo "$mesh"
}

# spin_scene NAME MESH STEPS CSV [RUN_LINE]: prints a spin scene of the Itokawa-like body
# with MESH (km) at 1.1 AU, STEPS steps per 12.13 h spin, `csv = CSV`, a point Sun (as
# the figures in docs/ were taken), and RUN_LINE (e.g. `shadows = "rays"`) in [run].
spin_scene() {
  cat <<TOML
[run]
name = "$1"
sun = "point"
${5:-}
[output]
csv = $4
[ephemeris]
mode = "spin"
distance_au = 1.1
subsolar_latitude_deg = 15.0
steps_per_period = $3
[[body]]
name = "itokawa"
mesh = "$2"
units = "km"
spin_period_h = 12.13
TOML
}

# hourly_scene NAME MESH STEPS [RUN_LINE]: the body of spin_scene (Parquet only) under a
# fixed geometry that lists the Sun of STEPS true hours of its spin, in the body's frame
# (the spin turns the Sun by -2π·t/P about the z axis). P is Itokawa's measured
# 12.132371 h, not the spin scene's 12.13 h: 12.13 h is 1,213 hours to 100 spins, so a
# year would list each of 1,213 Suns about 7 times.
hourly_scene() {
  cat <<TOML
[run]
name = "$1"
sun = "point"
${4:-}
[output]
csv = false
[ephemeris]
mode = "fixed"
step_s = 3600.0
TOML
  python3 - "$3" <<'PY'
import math, sys
lat, period_h = math.radians(15.0), 12.132371
for k in range(int(sys.argv[1])):
    turn = -2.0 * math.pi * k / period_h
    x, y, z = math.cos(lat) * math.cos(turn), math.cos(lat) * math.sin(turn), math.sin(lat)
    print(f"[[ephemeris.sun]]\ndirection = [{x:.15f}, {y:.15f}, {z:.15f}]\ndistance_au = 1.1")
PY
  cat <<TOML
[[body]]
name = "itokawa"
mesh = "$2"
units = "km"
TOML
}

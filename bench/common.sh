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

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

#!/usr/bin/env bash
# Fuzzes the readers of untrusted files with cargo fuzz (libFuzzer): the map file (whole files,
# and bodies wrapped in a valid header so the decoding past the checksum is reached), the
# camera file and the --config YAML. Each target runs SECONDS (default 600) from a seed corpus
# of real inputs (a map saved by `dwslam run`, the shared camera files, the config examples).
# A crash stops with the input in fuzz/artifacts/TARGET/; reproduce with
# `cargo fuzz run TARGET fuzz/artifacts/TARGET/crash-…`.
#
#   bench/fuzz/run.sh [SECONDS] [TARGET…]      (from the repository root; installs cargo-fuzz)
#
# cargo fuzz needs nightly flags (-Zsanitizer); the machine's one stable toolchain takes them
# with RUSTC_BOOTSTRAP=1.
set -euo pipefail
cd "$(dirname "$0")/../.."
SECONDS_EACH=${1:-600}
shift || true
TARGETS=("$@")
[ ${#TARGETS[@]} -eq 0 ] && TARGETS=(map_file map_body camera_file config)
command -v cargo-fuzz >/dev/null || cargo install cargo-fuzz --locked
DATA=${DWSLAM_DATA:-../shared/data}
CORPUS=fuzz/corpus
mkdir -p "$CORPUS"/{map_file,map_body,camera_file,config}
if [ -z "$(ls -A "$CORPUS/map_file")" ]; then
  cargo build --release --bin dwslam
  tmp=$(mktemp -d)
  ./target/release/dwslam run "$DATA/seven_scenes_redkitchen_1000" --depth-frames-only --max-frames 12 \
    --deterministic --quiet --out "$tmp/out" --save-map "$CORPUS/map_file/kitchen12.map"
  ./target/release/dwslam run "$DATA/seven_scenes_redkitchen_1000" --sensor mono --max-frames 40 \
    --deterministic --quiet --out "$tmp/mono" --save-map "$CORPUS/map_file/kitchen-mono40.map"
  for m in "$CORPUS"/map_file/*.map; do tail -c +29 "$m" > "$CORPUS/map_body/$(basename "$m").body"; done
  rm -rf "$tmp"
fi
find "$DATA" -name 'camera*.yaml' -o -name '*.yaml' -path '*calib*' 2>/dev/null | head -20 | while read -r f; do
  cp "$f" "$CORPUS/camera_file/$(echo "$f" | tr '/' '_')"; done
find crates/system crates/data -name '*.yaml' 2>/dev/null | head -20 | while read -r f; do
  cp "$f" "$CORPUS/camera_file/$(echo "$f" | tr '/' '_')"; cp "$f" "$CORPUS/config/$(echo "$f" | tr '/' '_')"; done
printf 'tracker:\n  search_radius: 4\nloops:\n  enabled: false\n' > "$CORPUS/config/example.yaml"
# Set only now: it changes cargo's fingerprints, and the corpus's release build above would be
# built again from scratch under it.
export RUSTC_BOOTSTRAP=1
failed=()
for t in "${TARGETS[@]}"; do
  echo "== $t: $SECONDS_EACH s (log: fuzz/$t.log)"
  if cargo fuzz run "$t" "$CORPUS/$t" -- -max_total_time="$SECONDS_EACH" -rss_limit_mb=4096 \
      -max_len=4000000 > "fuzz/$t.log" 2>&1; then
    grep -E "^#[0-9]+ +DONE|^Done" "fuzz/$t.log" | tail -2
  else
    grep -E "panicked|ERROR|SUMMARY|crash-|Test unit written" "fuzz/$t.log" | head -8
    failed+=("$t")
  fi
done
if [ ${#failed[@]} -gt 0 ]; then
  echo "findings in: ${failed[*]}"
  exit 1
fi
echo "no findings"

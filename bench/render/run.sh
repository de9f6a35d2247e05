#!/usr/bin/env bash
# Times `dwslam render` for every scene × sensor at 640×480 with anti-aliasing (3×3 at
# silhouettes, mip-mapped textures), on one core, in a release build, each run under the shared
# build lock. Reports the rendering time per frame (texture-tile generation included, PNG
# encoding excluded: the CLI measures it apart), the best of REPEATS runs of FRAMES frames from
# the start of each sequence, and beside it, measured in the same run on the same images, the
# front-end's kernels the renderer has to keep up with (pyramid, FAST, quadtree, LK of 300
# features; `--frontend-timing`).
#
# Usage: bench/render/run.sh [FRAMES] [REPEATS]      (defaults 300 and 3)
# Output: a Markdown table on stdout, raw logs in out/bench-render/.
set -euo pipefail
cd "$(dirname "$0")/../.."
FRAMES=${1:-300}
REPEATS=${2:-3}
LOCK=/work/.release-build.lock
OUT=out/bench-render
mkdir -p "$OUT"
flock "$LOCK" cargo build --release -p dwslam >/dev/null 2>&1
BIN=target/release/dwslam
TMP=$(mktemp -d)
trap 'rm -rf "$TMP"' EXIT

echo "| scene | sensor | render ms/frame (best of $REPEATS) | tiles ms/frame | front-end ms/frame | render / front-end |"
echo "|---|---|---:|---:|---:|---:|"
for scene in room building courtyard; do
  for sensor in mono stereo rgbd; do
    best=""
    for r in $(seq 1 "$REPEATS"); do
      log="$OUT/$scene-$sensor-$r.log"
      rm -rf "$TMP/seq"
      RAYON_NUM_THREADS=1 flock "$LOCK" "$BIN" render "$scene" --sensor "$sensor" --frames "$FRAMES" \
        --threads 1 --frontend-timing --out "$TMP/seq" >"$log" 2>&1
      ms=$(sed -n 's/.*rendering \([0-9.]*\) ms per frame.*/\1/p' "$log")
      tiles=$(sed -n 's/.*generated, \([0-9.]*\) ms per frame.*/\1/p' "$log")
      fe=$(sed -n 's/.*LK of 300 features): \([0-9.]*\) ms per frame.*/\1/p' "$log")
      if [ -z "$best" ] || awk "BEGIN{exit !($ms < $best)}"; then
        best=$ms; best_tiles=$tiles; best_fe=$fe
      fi
    done
    ratio=$(awk "BEGIN{printf \"%.1f\", $best / $best_fe}")
    echo "| $scene | $sensor | $best | $best_tiles | $best_fe | $ratio |"
  done
done

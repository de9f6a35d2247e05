#!/usr/bin/env bash
# vision vs OpenCV on the same images, single-threaded both. Creates its own venv
# (bench/vision/.venv, gitignored) with opencv-python-headless and numpy, builds the release
# driver, runs the heavy real-data tests, and writes the table to bench/vision/RESULTS.md
# (copied into bench/README.md by hand when it changes).
# Usage: bench/vision/run.sh        (DWSLAM_DATA overrides <repo>/../shared/data)
set -euo pipefail
HERE=$(cd "$(dirname "$0")" && pwd)
ROOT=$(cd "$HERE/../.." && pwd)
DATA=${DWSLAM_DATA:-$ROOT/../shared/data}
VENV=$HERE/.venv
if [ ! -x "$VENV/bin/python" ] || ! "$VENV/bin/python" -c "import cv2, numpy" 2>/dev/null; then
  python3 -m venv "$VENV"
  "$VENV/bin/pip" install -q opencv-python-headless numpy
fi
export RAYON_NUM_THREADS=1
cd "$ROOT"
cargo build --release -p vision --example vision_bench
LOG=$HERE/rust_real_data.log
DWSLAM_DATA=$DATA cargo test --release -p vision --test real_data -- --include-ignored --nocapture 2>&1 | tee "$LOG" || true
"$VENV/bin/python" "$HERE/compare.py" --bin "$ROOT/target/release/examples/vision_bench" \
  --data "$DATA" --out "$HERE/RESULTS.md" --rust-log "$LOG"

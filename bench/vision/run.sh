#!/usr/bin/env bash
# vision vs OpenCV on the same images, single-threaded both. Creates its own venv
# (bench/vision/.venv, gitignored) with opencv-python-headless and numpy, builds the release
# driver, runs the heavy real-data tests, and writes the table to bench/vision/RESULTS.md
# (copied into bench/README.md by hand when it changes).
# Usage: bench/vision/run.sh [compare.py options]   (DWSLAM_DATA overrides <repo>/../shared/data)
#   e.g. --ref-bin OLD_vision_bench (compare FAST, LK, stereo, flow with the code before a change),
#        --budget 0.3 (shorter timing while iterating; recorded runs use the default 1 s),
#        --only speed,lk. VISION_BENCH_SKIP_TESTS=1 skips the real-data tests.
# The peer is opencv-contrib-python-headless: the same OpenCV as opencv-python-headless plus the
# contrib modules (DualTVL1 lives in cv2.optflow); the two wheels cannot share a venv.
set -euo pipefail
HERE=$(cd "$(dirname "$0")" && pwd)
ROOT=$(cd "$HERE/../.." && pwd)
DATA=${DWSLAM_DATA:-$ROOT/../shared/data}
VENV=$HERE/.venv
if [ ! -x "$VENV/bin/python" ] || ! "$VENV/bin/python" -c "import cv2, numpy; cv2.optflow" 2>/dev/null; then
  python3 -m venv "$VENV"
  "$VENV/bin/pip" uninstall -q -y opencv-python-headless 2>/dev/null || true
  "$VENV/bin/pip" install -q opencv-contrib-python-headless numpy
fi
export RAYON_NUM_THREADS=1
cd "$ROOT"
cargo build --release -p vision --example vision_bench
LOG=$HERE/rust_real_data.log
if [ -z "${VISION_BENCH_SKIP_TESTS:-}" ]; then
  DWSLAM_DATA=$DATA cargo test --release -p vision --test real_data -- --include-ignored --nocapture 2>&1 | tee "$LOG" || true
else
  LOG=/dev/null
fi
"$VENV/bin/python" "$HERE/compare.py" --bin "$ROOT/target/release/examples/vision_bench" \
  --data "$DATA" --out "$HERE/RESULTS.md" --rust-log "$LOG" "$@"

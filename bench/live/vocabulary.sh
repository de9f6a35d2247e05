#!/usr/bin/env bash
# Times the training of the place-recognition vocabulary (`dwslam vocabulary`, thesis §6.4.2)
# against the peer trainer of the ORB-SLAM3 set-up (../shared/peers/live/train_vocab.py:
# OpenCV ORB + numpy k-majority, DBoW2 text format) on the same images and tree shape, one core
# each, in one run; then runs the long 7-Scenes place-recognition evaluation (250 keyframes).
#
# Usage: bench/live/vocabulary.sh   (env: DWSLAM_DATA, LIVE_PEERS_VENV, PEERS (default
# $DWSLAM_DATA/../peers/live), REPS=3)
# Needs the peers' venv (../shared/peers/live/setup.sh); without it only dwslam is timed.
# The whole script runs under the shared build lock (timings with nobody compiling).
set -euo pipefail
LOCK=/work/.release-build.lock
if [ -z "${DWSLAM_LOCKED:-}" ] && [ -e "$LOCK" ]; then
  exec env DWSLAM_LOCKED=1 flock "$LOCK" "$0" "$@"
fi
HERE=$(cd "$(dirname "$0")" && pwd)
REPO=$(cd "$HERE/../.." && pwd)
export DWSLAM_DATA=${DWSLAM_DATA:-$REPO/../shared/data}
V=${LIVE_PEERS_VENV:-$HOME/.cache/dwslam-live-peers}
PEERS=${PEERS:-$DWSLAM_DATA/../peers/live}
REPS=${REPS:-3}
OUT=$(mktemp -d)
trap 'rm -rf "$OUT"' EXIT

cargo build --release -q -p dwslam --manifest-path "$REPO/Cargo.toml"
BIN=$REPO/target/release/dwslam
D=$DWSLAM_DATA
# The default training set of system::place_recognition::vocabulary; the peer's folder filter
# drops the depth and disparity images the same way (it keeps rgbd_pair/1.png, a duplicate).
DIRS=("$D/slambook2_sample_images" "$D/middlebury_stereo" "$D/tum_rgbd_fr1_xyz_fragment")

seconds() {  # wall seconds of "$@" on core 0
  local t0 t1
  t0=$(date +%s.%N)
  taskset -c 0 "$@" >/dev/null 2>&1
  t1=$(date +%s.%N)
  echo "$t1 - $t0" | bc -l
}
median() { sort -g | awk '{a[NR]=$1} END {print a[int((NR+1)/2)]}'; }

echo "dwslam vocabulary (default training set):"
RAYON_NUM_THREADS=1 "$BIN" vocabulary --out "$OUT/dwslam.yml" | sed 's/^/  /'
K=$(awk '$1 == "k:" {print $2; exit}' "$OUT/dwslam.yml")
L=$(awk '$1 == "L:" {print $2; exit}' "$OUT/dwslam.yml")
OURS=$(for _ in $(seq "$REPS"); do RAYON_NUM_THREADS=1 seconds "$BIN" vocabulary --out "$OUT/dwslam.yml"; done | median)
printf 'median of %s runs, one core: dwslam %.2f s' "$REPS" "$OURS"
if [ -x "$V/bin/python" ] && [ -f "$PEERS/train_vocab.py" ]; then
  PEER=$(for _ in $(seq "$REPS"); do OMP_NUM_THREADS=1 OPENBLAS_NUM_THREADS=1 seconds \
    "$V/bin/python" "$PEERS/train_vocab.py" "$OUT/peer.txt" "${DIRS[@]}" --k "$K" --L "$L" --feat 1000; done | median)
  printf ', peer train_vocab.py (k = %s, L = %s, 1000 features) %.2f s: the peer takes %.1f× as long\n' \
    "$K" "$L" "$PEER" "$(echo "$PEER / $OURS" | bc -l)"
else
  printf ' (no peer: %s not found, run ../shared/peers/live/setup.sh)\n' "$V"
fi

echo "7-Scenes place recognition, every 4th frame (the #[ignore]d long evaluation):"
cargo test --release -q -p system --manifest-path "$REPO/Cargo.toml" \
  --test place_recognition_7scenes -- --ignored --nocapture seven_scenes_revisits_every_fourth_frame 2>&1 |
  grep -E "keyframes;|recall|relative pose|time:|test result"

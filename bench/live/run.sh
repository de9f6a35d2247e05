#!/usr/bin/env bash
# dwslam's live system beside ORB-SLAM3 (PyPI pyorbslam3) and Open3D RGB-D odometry on the same
# sequences in one run, each pinned to one core, ATE by evo_ape -a; prints a markdown table
# (also written to OUT/table.md).
#   bench/live/run.sh [OUT]      env: ORB_RUNS (default 3), DWSLAM_DATA, LIVE_PEERS_VENV,
#                                     DWSLAM_BUILD_LOCK (a lock file serialising builds/timings),
#                                     RENDERED (folder of the rendered sequences, rendered there
#                                     when missing, ~8 GB; default OUT/rendered; "none" skips them),
#                                     ONLY (comma-separated parts of sequence names, e.g. "mono")
set -euo pipefail
HERE=$(cd "$(dirname "$0")" && pwd)
ROOT=$(cd "$HERE/../.." && pwd)
DATA=${DWSLAM_DATA:-$ROOT/../shared/data}
PEERS=${PEERS:-$ROOT/../shared/peers/live}
V=${LIVE_PEERS_VENV:-$HOME/.cache/dwslam-live-peers}
OUT=${1:-$ROOT/out/bench-live}
mkdir -p "$OUT"
lock() { if [ -n "${DWSLAM_BUILD_LOCK:-}" ]; then flock "$DWSLAM_BUILD_LOCK" "$@"; else "$@"; fi; }
lock cargo build -q --release -p dwslam --manifest-path "$ROOT/Cargo.toml"
DWSLAM_DATA=$DATA bash "$PEERS/setup.sh" >/dev/null
export DWSLAM_DATA=$DATA OMP_NUM_THREADS=1
# An array, so that ONLY and RENDERED may hold spaces ("7-Scenes RGB-D").
opts=()
[ "${RENDERED:-}" = none ] || opts+=(--rendered "${RENDERED:-$OUT/rendered}")
[ -z "${ONLY:-}" ] || opts+=(--only "$ONLY")
lock "$V/bin/python" "$HERE/run.py" --dwslam "$ROOT/target/release/dwslam" --data "$DATA" \
  --peers "$PEERS" --venv "$V" --out "$OUT" --orb-runs "${ORB_RUNS:-3}" ${opts[@]+"${opts[@]}"}

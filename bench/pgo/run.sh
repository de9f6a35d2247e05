#!/usr/bin/env bash
# bench/pgo: every pose graph of ../shared/data/pose_graph_g2o through dwslam, GTSAM and g2o in
# one run, single-threaded (each process pinned to one CPU with taskset), and a markdown table.
#
#   bench/pgo/run.sh [DATASET ...]        (default: all 12; names without .g2o, or paths to .g2o
#                                           files, e.g. from make_non_pd.py; see non_pd.sh)
#
# Outputs go to out/pgo/ (gitignored): NAME.init.g2o (the file completed with dwslam's initial
# poses, which the peers read so all three start from the same poses), NAME.{dwslam,gtsam,g2o}.json
# and .g2o (optimised poses), and table.md. `dwslam pgo` is optional: if target/release/dwslam
# has no `pgo` subcommand yet its columns read n/a.
set -euo pipefail
cd "$(dirname "$0")/../.."
ROOT="$PWD"
DATA="${DWSLAM_DATA:-$ROOT/../shared/data}"
OUT="$ROOT/out/pgo"
mkdir -p "$OUT"
export OMP_NUM_THREADS=1 OPENBLAS_NUM_THREADS=1 MKL_NUM_THREADS=1 TBB_NUM_THREADS=1 RAYON_NUM_THREADS=1
PIN="taskset -c 0"
command -v taskset >/dev/null || PIN=""

bash bench/pgo/setup_venvs.sh
# Neither wheel may bring its own thread pool; say so if that ever changes.
for so in bench/pgo/.venv-gtsam/lib/python3*/site-packages/gtsam.libs/*.so* \
          bench/pgo/.venv-g2o/lib/python3*/site-packages/g2o/*.so; do
  if ldd "$so" 2>/dev/null | grep -q -E "tbb|gomp|omp\.so"; then
    echo "warning: $so links a thread pool (TBB/OpenMP); pinned to one CPU by taskset" >&2
  fi
done

# $DWSLAM_BUILD_LOCK: a lock file that serialises release builds on a shared machine (optional).
if [ -n "${DWSLAM_BUILD_LOCK:-}" ]; then flock "$DWSLAM_BUILD_LOCK" cargo build -q --release -p data -p dwslam --examples --bins; else cargo build -q --release -p data -p dwslam --examples --bins; fi
HAVE_DWSLAM=0
if [ -x target/release/dwslam ] && target/release/dwslam pgo --help >/dev/null 2>&1; then
  HAVE_DWSLAM=1
else
  echo "note: target/release/dwslam pgo not available: dwslam columns are n/a" >&2
fi

DATASETS=("$@")
if [ ${#DATASETS[@]} -eq 0 ]; then
  DATASETS=(sphere2500 parking-garage torus3D smallGrid3D tinyGrid3D intel city10000 M3500 manhattan CSAIL MIT kitti_00)
fi
declare -A GROUND_TRUTH=(
  [sphere2500]=sphere2500_groundtruth.txt
  [city10000]=city10000_groundtruth.txt
  [M3500]=manhattanOlson3500_groundtruth.txt
)

NAMES=()
for name in "${DATASETS[@]}"; do
  if [[ "$name" == *.g2o ]]; then
    src="$name"
    name=$(basename "$name" .g2o)
  else
    src="$DATA/pose_graph_g2o/$name.g2o"
  fi
  NAMES+=("$name")
  echo "== $name" >&2
  target/release/examples/g2o_complete "$src" "$OUT/$name.init.g2o" > "$OUT/$name.init.json"
  rm -f "$OUT/$name.dwslam.json" "$OUT/$name".*.rmse.json
  if [ $HAVE_DWSLAM = 1 ]; then
    $PIN target/release/dwslam pgo "$src" --json "$OUT/$name.dwslam.json" --out "$OUT/$name.dwslam.g2o" \
      > "$OUT/$name.dwslam.log" 2>&1 || echo "dwslam pgo failed on $name (see $OUT/$name.dwslam.log)" >&2
  fi
  (cd bench/pgo && $PIN .venv-gtsam/bin/python gtsam_pgo.py "$OUT/$name.init.g2o" \
      --out "$OUT/$name.gtsam.g2o" --json "$OUT/$name.gtsam.json" >/dev/null)
  (cd bench/pgo && $PIN .venv-g2o/bin/python g2o_pgo.py "$OUT/$name.init.g2o" \
      --out "$OUT/$name.g2o.g2o" --json "$OUT/$name.g2o.json" >/dev/null)
  if [ -n "${GROUND_TRUTH[$name]:-}" ]; then
    for who in dwslam gtsam g2o; do
      if [ -f "$OUT/$name.$who.g2o" ] && [ -f "$OUT/$name.$who.json" ]; then
        target/release/examples/pgo_ground_truth_rmse \
          "$DATA/pose_graph_groundtruth_isam/${GROUND_TRUTH[$name]}" "$OUT/$name.$who.g2o" \
          > "$OUT/$name.$who.rmse.json"
      fi
    done
  fi
done
python3 bench/pgo/table.py "$OUT" "${NAMES[@]}" | tee "$OUT/table.md"

#!/usr/bin/env bash
# Runs evo (PyPI, in bench/eval/.venv-evo, created here if missing) on the trajectories of
# ../shared/data/trajectories_evo and prints its statistics at full precision, one JSON line per
# case. These are the numbers recorded in crates/data/tests/eval_evo.rs; the ignored test
# `cargo test -p data --test eval_evo -- --ignored` runs this script and compares live.
set -euo pipefail
HERE="$(cd "$(dirname "$0")" && pwd)"
DATA="${DWSLAM_DATA:-$HERE/../../../shared/data}/trajectories_evo"
if [ ! -x "$HERE/.venv-evo/bin/evo_ape" ]; then
  python3 -m venv "$HERE/.venv-evo"
  "$HERE/.venv-evo/bin/pip" install -q evo
fi
export MPLBACKEND=Agg
E="$HERE/.venv-evo/bin"
TMP="$(mktemp -d)"
trap 'rm -rf "$TMP"' EXIT
cd "$DATA"
run() { # name, evo command...
  local name="$1"; shift
  "$E/$1" "${@:2}" --save_results "$TMP/$name.zip" --no_warnings > /dev/null
  (cd "$TMP" && rm -f stats.json && unzip -q -o "$name.zip" stats.json)
  printf '{"case": "%s", "command": "%s", "stats": %s}\n' "$name" "$*" "$(cat "$TMP/stats.json")"
}
run ape_fr2_desk_se3 evo_ape tum fr2_desk_groundtruth.txt fr2_desk_ORB.txt --align
run ape_fr1_xyz_mono_sim3 evo_ape tum freiburg1_xyz-groundtruth.txt freiburg1_xyz-ORB_kf_mono.txt --align --correct_scale
run ape_fr1_xyz_drift_none evo_ape tum freiburg1_xyz-groundtruth.txt freiburg1_xyz-rgbdslam_drift.txt
run ape_kitti00_se3 evo_ape kitti KITTI_00_gt.txt KITTI_00_ORB.txt --align
run ape_v102_se3 evo_ape euroc V102_groundtruth.csv V102.txt --align
run rpe_fr1_xyz_trans evo_rpe tum freiburg1_xyz-groundtruth.txt freiburg1_xyz-rgbdslam.txt --delta 1
run rpe_fr1_xyz_rot evo_rpe tum freiburg1_xyz-groundtruth.txt freiburg1_xyz-rgbdslam.txt --delta 1 --pose_relation angle_rad
run rpe_kitti00_trans_d10 evo_rpe kitti KITTI_00_gt.txt KITTI_00_ORB.txt --delta 10
run rpe_fr2_desk_all_pairs_d5 evo_rpe tum fr2_desk_groundtruth.txt fr2_desk_ORB.txt --delta 5 --all_pairs
run rpe_fr1_xyz_mono_sim3 evo_rpe tum freiburg1_xyz-groundtruth.txt freiburg1_xyz-ORB_kf_mono.txt --delta 1 --align --correct_scale

#!/usr/bin/env bash
# `dwslam eval` against evo (PyPI `evo`, installed here in bench/eval/.venv-evo if missing) on
# every trajectory pair of ../shared/data/trajectories_evo (or $DWSLAM_DATA/trajectories_evo),
# with each alignment mode (none, se3 = evo --align, sim3 = evo --align --correct_scale):
# ATE (evo_ape, translation part), RPE translation (evo_rpe, delta 1) and RPE rotation
# (evo_rpe --pose_relation angle_deg). Every statistic (rmse, mean, median, std, min, max) must
# agree to 1e-6 relative (|a − b| ≤ 1e-6·max(|b|, 1e-9): a 1 nm / 1e-9° floor for the statistics
# that are exactly 0, such as the ATE minimum of KITTI without alignment, whose first poses are
# both the identity). Prints a markdown table (also out/eval/evo_table.md) and exits non-zero if
# any case disagrees.
#
# Builds target/release/dwslam first (under the lock named by $DWSLAM_BUILD_LOCK, if set).
set -euo pipefail
HERE="$(cd "$(dirname "$0")" && pwd)"
ROOT="$(cd "$HERE/../.." && pwd)"
DATA="${DWSLAM_DATA:-$ROOT/../shared/data}/trajectories_evo"
OUT="$ROOT/out/eval"
mkdir -p "$OUT"
if [ ! -x "$HERE/.venv-evo/bin/evo_ape" ]; then
  python3 -m venv "$HERE/.venv-evo"
  "$HERE/.venv-evo/bin/pip" install -q evo
fi
build() { (cd "$ROOT" && cargo build --release -q -p dwslam); }
if [ -n "${DWSLAM_BUILD_LOCK:-}" ]; then
  flock "$DWSLAM_BUILD_LOCK" bash -c "cd '$ROOT' && cargo build --release -q -p dwslam"
else
  build
fi
DWSLAM="$ROOT/target/release/dwslam"
export MPLBACKEND=Agg
E="$HERE/.venv-evo/bin"
TMP="$(mktemp -d)"
trap 'rm -rf "$TMP"' EXIT

# name | evo file format | ground truth | estimate
PAIRS=(
  "fr2_desk|tum|fr2_desk_groundtruth.txt|fr2_desk_ORB.txt"
  "fr1_xyz_orb_mono|tum|freiburg1_xyz-groundtruth.txt|freiburg1_xyz-ORB_kf_mono.txt"
  "fr1_xyz_rgbdslam|tum|freiburg1_xyz-groundtruth.txt|freiburg1_xyz-rgbdslam.txt"
  "fr1_xyz_rgbdslam_drift|tum|freiburg1_xyz-groundtruth.txt|freiburg1_xyz-rgbdslam_drift.txt"
  "kitti_00|kitti|KITTI_00_gt.txt|KITTI_00_ORB.txt"
  "v102|euroc|V102_groundtruth.csv|V102.txt"
)
evo_stats() { # out-name, evo command...
  local name="$1"; shift
  "$E/$1" "${@:2}" --save_results "$TMP/$name.zip" --no_warnings > /dev/null
  (cd "$TMP" && rm -f stats.json && unzip -q -o "$name.zip" stats.json && mv stats.json "$name.evo.json")
}
for pair in "${PAIRS[@]}"; do
  IFS='|' read -r name fmt gt est <<< "$pair"
  for mode in none se3 sim3; do
    case "$mode" in
      none) flags=() ;;
      se3) flags=(--align) ;;
      sim3) flags=(--align --correct_scale) ;;
    esac
    case="${name}_${mode}"
    (cd "$DATA" && evo_stats "${case}_ape" evo_ape "$fmt" "$gt" "$est" "${flags[@]}")
    (cd "$DATA" && evo_stats "${case}_rpe_t" evo_rpe "$fmt" "$gt" "$est" --delta 1 "${flags[@]}")
    (cd "$DATA" && evo_stats "${case}_rpe_r" evo_rpe "$fmt" "$gt" "$est" --delta 1 --pose_relation angle_deg "${flags[@]}")
    "$DWSLAM" eval "$DATA/$gt" "$DATA/$est" --align "$mode" --rpe-delta 1 --json "$TMP/$case.dwslam.json" > /dev/null
    echo "$case" >> "$TMP/cases.txt"
  done
done

"$E/python" - "$TMP" "$OUT/evo_table.md" <<'EOF'
import json, sys, os
tmp, table = sys.argv[1], sys.argv[2]
keys = ["rmse", "mean", "median", "std", "min", "max"]
rows, worst_all, failed = [], 0.0, []
for case in open(os.path.join(tmp, "cases.txt")).read().split():
    ours = json.load(open(os.path.join(tmp, case + ".dwslam.json")))
    for metric, evo_name, mine in [
        ("ATE", "ape", ours["ate"]),
        ("RPE t", "rpe_t", ours["rpe"]["translation"]),
        ("RPE rot", "rpe_r", ours["rpe"]["rotation_deg"]),
    ]:
        evo = json.load(open(os.path.join(tmp, f"{case}_{evo_name}.evo.json")))
        rel = max(abs(mine[k] - evo[k]) / max(abs(evo[k]), 1e-9) for k in keys)
        worst_all = max(worst_all, rel)
        ok = rel <= 1e-6
        if not ok:
            failed.append(f"{case} {metric}")
        rows.append(f"| {case} | {metric} | {evo['rmse']:.9g} | {mine['rmse']:.9g} | {rel:.1e} | {'yes' if ok else 'NO'} |")
lines = ["| case | metric | evo rmse | dwslam rmse | worst relative difference (6 statistics) | ≤ 1e-6 |",
         "|---|---|---:|---:|---:|---|"] + rows
lines.append("")
lines.append(f"{len(rows)} comparisons, worst relative difference {worst_all:.1e}; "
             + ("all within 1e-6" if not failed else "FAILED: " + ", ".join(failed)))
text = "\n".join(lines)
print(text)
open(table, "w").write(text + "\n")
sys.exit(1 if failed else 0)
EOF

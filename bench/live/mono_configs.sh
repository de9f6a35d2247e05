#!/usr/bin/env bash
# Deterministic monocular runs of one build with one configuration over the monocular sequences
# (the shared KITTI 04 and 06 snippets and 7-Scenes, the rendered town (seeds 1, 2), room,
# courtyard and building): keyframes, loops accepted, Sim(3) ATE live / after the run, KITTI's
# drift, median and mean ms per frame, and the median of tracking alone (frames.csv
# `tracking_ms`: the frame's corner tracks, re-finding and exploration with a keyframe's window
# BA, not its place recognition; issue 42's bar: ≤ 10 ms at 640×480, ≤ 20 ms on KITTI). For
# comparing defaults on several inputs at once (the rendered runs are chaotic: one sequence
# moves by ±50 % with any small change).
#   bench/live/mono_configs.sh BINARY TAG [CONFIG.yaml|""] [CORE] [sequence keys...]
#   keys: k04 k06 7s town town2 room court bldg (default: all)
#   env: THREADED=1 (the live system's threads — loop closure, the keyframe window BA — instead
#        of --deterministic; give CORE as 0,1), DWSLAM_DATA (../shared/data), RENDERED (folder of the renders: town-mono,
#        town-mono-seed2, room-mono, courtyard-mono, building-mono; `dwslam render SCENE
#        --sensor mono --layout kitti [--seed 2] --out ...`), OUT (/tmp/dwslam-mono-configs)
set -euo pipefail
HERE=$(cd "$(dirname "$0")" && pwd)
BIN=$1; TAG=$2; CFG=${3:-}; CORE=${4:-0}; shift $(( $# < 4 ? $# : 4 ))
D=${DWSLAM_DATA:-$HERE/../../../shared/data}
R=${RENDERED:-/work/renders}
OUT=${OUT:-/tmp/dwslam-mono-configs}
declare -A P=([k04]=$D/kitti_odometry_snippets/KITTI_04_0_270 [k06]=$D/kitti_odometry_snippets/KITTI_sequence_1
  [7s]=$D/seven_scenes_redkitchen_1000 [town]=$R/town-mono [town2]=$R/town-mono-seed2 [room]=$R/room-mono
  [court]=$R/courtyard-mono [bldg]=$R/building-mono)
keys=("$@"); [ ${#keys[@]} -gt 0 ] || keys=(k04 k06 7s town town2 room court bldg)
mkdir -p "$OUT"
for s in "${keys[@]}"; do
  out=$OUT/$TAG-$s
  if ! taskset -c "$CORE" "$BIN" run "${P[$s]}" --sensor mono $([ -n "${THREADED:-}" ] || echo --deterministic) --quiet --out "$out" \
      ${CFG:+--config "$CFG"} > "$out.log" 2>&1; then
    echo "$TAG $s: failed (see $out.log)"; continue
  fi
  python3 - "$out" "$TAG" "$s" <<'PY'
import csv, json, statistics, sys
out, tag, seq = sys.argv[1:]
s = json.load(open(out + "/summary.json"))
rows = list(csv.DictReader(open(out + "/frames.csv")))
ms = [float(r["frame_ms"]) for r in rows if float(r["frame_ms"]) > 0]
tracking = [float(r["tracking_ms"]) for r in rows if float(r["tracking_ms"]) > 0]
e = s["evaluation"]
print(f"{tag:8s} {seq:6s} keyframes {s['keyframes']:4d} loops {len(s['loops']):3d} "
      f"ATE live {e['live']['ate_rmse_m'] * 100:8.2f} after {e['final']['ate_rmse_m'] * 100:8.2f} cm "
      f"drift {e['final']['drift_translation_percent'] or 0:5.2f} % median {statistics.median(ms):5.1f} "
      f"mean {statistics.mean(ms):5.1f} ms tracking median {statistics.median(tracking):5.1f} ms tracked {s['frames_with_pose']}/{s['frames']}")
PY
done

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
#   keys: k04 k06 7s town town2 town3 room court bldg (default: all)
#   env: SEEDS="0 1 2 3 4" (each sequence once per feature-selection seed, `mono.seed` added to
#        CONFIG, and a line of medians over the seeds: one deterministic run of a monocular
#        sequence is one draw of a chaotic estimate, so a default is decided on the medians),
#        THREADED=1 (the live system's threads — loop closure, the keyframe window BA — instead
#        of --deterministic; give CORE as 0,1), DWSLAM_DATA (../shared/data), RENDERED (folder of the renders: town-mono,
#        town-mono-seed2, town-mono-seed3, room-mono, courtyard-mono, building-mono; `dwslam render SCENE
#        --sensor mono --layout kitti [--seed 2] --out ...`), OUT (/tmp/dwslam-mono-configs)
set -euo pipefail
HERE=$(cd "$(dirname "$0")" && pwd)
BIN=$1; TAG=$2; CFG=${3:-}; CORE=${4:-0}; shift $(( $# < 4 ? $# : 4 ))
D=${DWSLAM_DATA:-$HERE/../../../shared/data}
R=${RENDERED:-/work/renders}
OUT=${OUT:-/tmp/dwslam-mono-configs}
declare -A P=([k04]=$D/kitti_odometry_snippets/KITTI_04_0_270 [k06]=$D/kitti_odometry_snippets/KITTI_sequence_1
  [7s]=$D/seven_scenes_redkitchen_1000 [town]=$R/town-mono [town2]=$R/town-mono-seed2 [room]=$R/room-mono
  [court]=$R/courtyard-mono [bldg]=$R/building-mono [town3]=$R/town-mono-seed3)
keys=("$@"); [ ${#keys[@]} -gt 0 ] || keys=(k04 k06 7s town town2 town3 room court bldg)
mkdir -p "$OUT"
# CONFIG with `mono.seed: $1` added (after its `mono:` line, or in a `mono:` section of its own).
seeded() {
  local cfg=$OUT/$TAG-seed$1.yaml
  if [ -n "$CFG" ] && grep -q '^mono:' "$CFG"; then
    awk -v seed="$1" '{print} /^mono:/{print "  seed: " seed}' "$CFG" > "$cfg"
  else
    { [ -z "$CFG" ] || cat "$CFG"; printf 'mono:\n  seed: %s\n' "$1"; } > "$cfg"
  fi
  echo "$cfg"
}
for s in "${keys[@]}"; do
  runs=()
  for seed in ${SEEDS:-none}; do
    if [ "$seed" = none ]; then out=$OUT/$TAG-$s; cfg=$CFG; else out=$OUT/$TAG-$s-seed$seed; cfg=$(seeded "$seed"); fi
    if ! taskset -c "$CORE" "$BIN" run "${P[$s]}" --sensor mono $([ -n "${THREADED:-}" ] || echo --deterministic) --quiet --out "$out" \
        ${cfg:+--config "$cfg"} > "$out.log" 2>&1; then
      echo "$TAG $s: failed (see $out.log)"; continue
    fi
    runs+=("$out")
    python3 - "$out" "$TAG" "$s" "$seed" <<'PY'
import csv, json, statistics, sys
out, tag, seq, seed = sys.argv[1:]
s = json.load(open(out + "/summary.json"))
rows = list(csv.DictReader(open(out + "/frames.csv")))
ms = [float(r["frame_ms"]) for r in rows if float(r["frame_ms"]) > 0]
tracking = [float(r["tracking_ms"]) for r in rows if float(r["tracking_ms"]) > 0]
e = s["evaluation"]
label = seq if seed == "none" else f"{seq}/{seed}"
print(f"{tag:8s} {label:8s} keyframes {s['keyframes']:4d} loops {len(s['loops']):3d} "
      f"ATE live {e['live']['ate_rmse_m'] * 100:8.2f} after {e['final']['ate_rmse_m'] * 100:8.2f} cm "
      f"drift {e['final']['drift_translation_percent'] or 0:5.2f} % median {statistics.median(ms):5.1f} "
      f"mean {statistics.mean(ms):5.1f} ms tracking median {statistics.median(tracking):5.1f} ms tracked {s['frames_with_pose']}/{s['frames']}")
# Which criterion made the keyframes (the summary's `keyframe_reasons`).
print(f"{'':8s} {'':8s} keyframes by " + ", ".join(f"{n} {r}" for r, n in sorted(s.get("keyframe_reasons", {}).items())))
PY
  done
  [ ${#runs[@]} -gt 1 ] || continue
  python3 - "$TAG" "$s" "${runs[@]}" <<'PY'
import csv, json, statistics, sys
tag, seq, outs = sys.argv[1], sys.argv[2], sys.argv[3:]
def one(out):
    s = json.load(open(out + "/summary.json"))
    ms = [float(r["frame_ms"]) for r in csv.DictReader(open(out + "/frames.csv")) if float(r["frame_ms"]) > 0]
    e = s["evaluation"]
    return (s["keyframes"], e["live"]["ate_rmse_m"] * 100, e["final"]["ate_rmse_m"] * 100, statistics.median(ms))
k, live, after, ms = zip(*map(one, outs))
m = statistics.median
print(f"{tag:8s} {seq:6s} MEDIAN of {len(outs)} seeds: keyframes {m(k):6.1f} ATE live {m(live):8.2f} "
      f"({min(live):.2f}-{max(live):.2f}) after {m(after):8.2f} ({min(after):.2f}-{max(after):.2f}) cm, "
      f"median ms per frame {m(ms):5.1f}")
PY
done

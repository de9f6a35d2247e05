#!/usr/bin/env bash
# bench/ba/growth.sh: how the cost of one BA iteration grows with the number of points at a
# fixed number of cameras (thesis §4.6.4 predicts O(N·M² + M³), i.e. linear in N), measured
# in instructions (valgrind callgrind), which do not depend on the machine's load.
#
#   bench/ba/growth.sh [N ...]        (default: 1000 10000 100000 points, 50 cameras)
#
# Per-iteration instructions = (count with 3 iterations − count with 1 iteration) / 2, so the
# file reading and set-up, which also grow with N, cancel. Same for Ceres (SPARSE_SCHUR) when
# bench/ba/run.sh has built its driver. Prints a table and the least-squares exponent.
set -euo pipefail
cd "$(dirname "$0")/../.."
OUT=out/ba
mkdir -p "$OUT"
SIZES=("$@"); [ ${#SIZES[@]} = 0 ] && SIZES=(1000 10000 100000)
if [ -n "${DWSLAM_BUILD_LOCK:-}" ]; then flock "$DWSLAM_BUILD_LOCK" cargo build -q --release -p dwslam; else cargo build -q --release -p dwslam; fi
count() { valgrind --tool=callgrind --callgrind-out-file=/tmp/dwslam-growth.out "$@" >/dev/null 2>&1; callgrind_annotate /tmp/dwslam-growth.out | awk '/PROGRAM TOTALS/ && !done {gsub(",", "", $1); print $1; done = 1}'; }
rows=()
for n in "${SIZES[@]}"; do
  f="$OUT/synthetic-$n.txt"
  [ -f "$f" ] || target/release/dwslam ba --synthetic "50,$n" --noise 1 --seed 1 --save-problem "$f" --max-iterations 0 --quiet >/dev/null
  o1=$(count target/release/dwslam ba "$f" --threads 1 --max-iterations 1 --function-tolerance 0 --quiet)
  o3=$(count target/release/dwslam ba "$f" --threads 1 --max-iterations 3 --function-tolerance 0 --quiet)
  c="nan"
  if [ -x "$OUT/ceres_ba" ]; then
    c1=$(count "$OUT/ceres_ba" "$f" --iterations 1 --threads 1)
    c3=$(count "$OUT/ceres_ba" "$f" --iterations 3 --threads 1)
    c=$(( (c3 - c1) / 2 ))
  fi
  rows+=("$n $(( (o3 - o1) / 2 )) $c")
  echo "done N=$n" >&2
done
printf '%s\n' "${rows[@]}" | python3 -c '
import sys, math
rows = [l.split() for l in sys.stdin if l.strip()]
print("| points | dwslam instructions / iteration | Ceres instructions / iteration | ratio |")
print("|---:|---:|---:|---:|")
for n, o, c in rows:
    r = f"{int(o)/int(c):.2f}" if c != "nan" else "n/a"
    cs = f"{int(c):,}" if c != "nan" else "n/a"
    print(f"| {int(n):,} | {int(o):,} | {cs} | {r} |")
def slope(pairs):
    xs = [math.log(a) for a, _ in pairs]; ys = [math.log(b) for _, b in pairs]
    mx, my = sum(xs)/len(xs), sum(ys)/len(ys)
    return sum((x-mx)*(y-my) for x, y in zip(xs, ys)) / sum((x-mx)**2 for x in xs)
print()
print(f"dwslam: instructions per iteration ∝ N^{slope([(int(n), int(o)) for n, o, _ in rows]):.2f} over {len(rows)} sizes")
if all(c != "nan" for _, _, c in rows):
    print(f"Ceres:  instructions per iteration ∝ N^{slope([(int(n), int(c)) for n, _, c in rows]):.2f} over {len(rows)} sizes")
'

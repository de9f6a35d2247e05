#!/usr/bin/env bash
# bench/ba/instructions.sh: instructions executed (valgrind callgrind) by dwslam and Ceres on
# the same BA problems, same iterations, one thread. Unlike wall time this count does not
# depend on what else the machine is doing, so it is the reproducible companion of run.sh's
# timings (it ignores memory stalls and SIMD width, so it is not a time ratio).
#   bench/ba/instructions.sh            (uses out/ba/*.txt written by run.sh)
set -euo pipefail
cd "$(dirname "$0")/../.."
OUT=out/ba
[ -x "$OUT/ceres_ba" ] || { echo "run bench/ba/run.sh first (it builds the Ceres driver and the problems)" >&2; exit 1; }
count() { valgrind --tool=callgrind --callgrind-out-file=/tmp/dwslam-cg.out "$@" >/dev/null 2>&1; callgrind_annotate /tmp/dwslam-cg.out | awk '/PROGRAM TOTALS/ && !done {gsub(",", "", $1); print $1; done = 1}'; }
echo "| problem | iterations | dwslam instructions | Ceres instructions | ratio |"
echo "|---|---:|---:|---:|---:|"
for spec in ladybug-49:10 synthetic-10000:3; do
  p=${spec%%:*}; n=${spec##*:}
  [ -f "$OUT/$p.txt" ] || continue
  ours=$(count target/release/dwslam ba "$OUT/$p.txt" --threads 1 --max-iterations "$n" --function-tolerance 0 --quiet)
  theirs=$(count "$OUT/ceres_ba" "$OUT/$p.txt" --iterations "$n" --threads 1)
  python3 -c "print(f'| $p | $n | {$ours:,} | {$theirs:,} | {$ours/$theirs:.2f} |')"
done

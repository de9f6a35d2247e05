#!/usr/bin/env bash
# bench/ba: bundle adjustment, dwslam against Ceres (Debian libceres-dev, our own driver
# ceres_ba.cc), same problems, same number of iterations, same thread count, in one run.
#
#   bench/ba/run.sh [--quick]     (--quick: skip the 10⁵-point synthetic problem)
#
# Problems: BAL problem-49-7776 (Ladybug) and dubrovnik-3-7 from ../shared/data/bal, and
# synthetic scenes (50 cameras on a circle, 10³/10⁴/10⁵ points, σ = 1 px) written as BAL files
# by `dwslam ba --synthetic … --save-problem`, so both solvers read identical input.
# Solvers: Ceres SPARSE_SCHUR vs dwslam schur-cholesky; Ceres ITERATIVE_SCHUR + SCHUR_JACOBI
# vs dwslam schur-pcg. Threads: 1 and 2. Both are built for the baseline x86-64 target (no
# -march=native), as Debian builds libceres and as cargo builds dwslam. Outputs in out/ba/ (gitignored); the table is printed
# and written to out/ba/table.md.
set -euo pipefail
cd "$(dirname "$0")/../.."
ROOT="$PWD"
DATA="${DWSLAM_DATA:-$ROOT/../shared/data}"
OUT="$ROOT/out/ba"
mkdir -p "$OUT"
QUICK=0
[ "${1:-}" = "--quick" ] && QUICK=1

if ! [ -f /usr/include/ceres/ceres.h ]; then
  echo "installing libceres-dev (Debian)" >&2
  apt-get install -y -q libceres-dev >/dev/null
fi
g++ -O3 -DNDEBUG -std=c++17 bench/ba/ceres_ba.cc -o "$OUT/ceres_ba" \
  -I/usr/include/eigen3 -lceres -lglog -lgflags -lpthread
# $DWSLAM_BUILD_LOCK: a lock file that serialises release builds on a shared machine (optional).
if [ -n "${DWSLAM_BUILD_LOCK:-}" ]; then flock "$DWSLAM_BUILD_LOCK" cargo build -q --release -p dwslam; else cargo build -q --release -p dwslam; fi
DWSLAM="$ROOT/target/release/dwslam"

ITER=10
cp "$DATA/bal/problem-49-7776-pre.txt" "$OUT/ladybug-49.txt"
cp "$DATA/bal/dubrovnik-3-7-pre.txt" "$OUT/dubrovnik-3.txt"
PROBLEMS=(ladybug-49 dubrovnik-3)
SIZES=(1000 10000)
[ $QUICK = 0 ] && SIZES+=(100000)
for n in "${SIZES[@]}"; do
  "$DWSLAM" ba --synthetic "50,$n" --noise 1 --seed 1 --save-problem "$OUT/synthetic-$n.txt" --max-iterations 0 --quiet >/dev/null
  PROBLEMS+=("synthetic-$n")
done

for p in "${PROBLEMS[@]}"; do
  for threads in 1 2; do
    for pair in "sparse_schur:schur-cholesky" "iterative_schur:schur-pcg"; do
      ceres_solver=${pair%%:*}; ours=${pair##*:}
      # Interleave the two programs so both see the same machine load.
      "$DWSLAM" ba "$OUT/$p.txt" --solver "$ours" --threads "$threads" --max-iterations $ITER \
          --function-tolerance 0 --json "$OUT/$p.$ours.t$threads.dwslam.json" > "$OUT/$p.$ours.t$threads.dwslam.log"
      "$OUT/ceres_ba" "$OUT/$p.txt" --solver "$ceres_solver" --preconditioner schur_jacobi --threads "$threads" \
          --iterations $ITER --json "$OUT/$p.$ours.t$threads.ceres.json" > "$OUT/$p.$ours.t$threads.ceres.log"
    done
  done
done
python3 bench/ba/table.py "$OUT" "${PROBLEMS[@]}" | tee "$OUT/table.md"

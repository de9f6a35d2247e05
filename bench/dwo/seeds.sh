#!/usr/bin/env bash
# Monte Carlo trials of thesis §6.5.1 (the thesis averages ten), one seed after another, each
# run single-threaded under the build lock so that no release build shares the machine with a
# timed run; then the table of bench/dwo/table.py.
#
#   bench/dwo/seeds.sh [SEED ...]                        stereo spiral (default seeds 1–10)
#   SCENARIO=double-loop bench/dwo/seeds.sh [SEED ...]   monocular double loop
#
# Spiral: full BA, cDWO and gDWO with the default (marginal) constraint information, then
# cDWO and gDWO with the thesis's coarse one (eq. 6.2). Double loop: BA, cDWO, gDWO.
# Output in $OUT (default out/dwo-seeds/ or out/dl-seeds/). DWSLAM=path/to/dwslam to use a
# built binary (default: build with cargo).
set -euo pipefail
cd "$(dirname "$0")/../.."
SCENARIO=${SCENARIO:-spiral}
case "$SCENARIO" in
    spiral) OUT=${OUT:-out/dwo-seeds} ;;
    double-loop) OUT=${OUT:-out/dl-seeds} ;;
    *) echo "SCENARIO must be spiral or double-loop" >&2; exit 2 ;;
esac
LOCK=${LOCK:-/work/.release-build.lock}
SEEDS=("$@")
[ ${#SEEDS[@]} -eq 0 ] && SEEDS=(1 2 3 4 5 6 7 8 9 10)
if [ -z "${DWSLAM:-}" ]; then
    cargo build --release -p dwslam
    DWSLAM=${CARGO_TARGET_DIR:-target}/release/dwslam
fi
run() {
    if [ -e "$LOCK" ] || touch "$LOCK" 2>/dev/null; then flock "$LOCK" "$DWSLAM" "$@"; else "$DWSLAM" "$@"; fi
}
for s in "${SEEDS[@]}"; do
    if [ "$SCENARIO" = double-loop ]; then
        [ -f "$OUT/seed$s/summary.json" ] && continue
        run experiment dwo --scenario double-loop --seed "$s" --methods ba,cdwo,gdwo --out "$OUT/seed$s"
        continue
    fi
    for info in marginal coarse; do
        dir="$OUT/seed$s-$info"
        [ -f "$dir/summary.json" ] && continue
        methods=ba,cdwo,gdwo
        [ "$info" = coarse ] && methods=cdwo,gdwo   # BA does not depend on the option
        run experiment dwo --scenario spiral --sensor stereo --seed "$s" --methods "$methods" \
            --constraint-information "$info" --out "$dir"
    done
done
python3 bench/dwo/table.py "$OUT"

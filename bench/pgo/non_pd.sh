#!/usr/bin/env bash
# Non-positive-definite information on a real graph: sphere2500 and intel with every 10th edge's
# information made singular (make_non_pd.py), through dwslam, GTSAM and g2o with run.sh.
# dwslam warns about each such edge (line and vertices) and uses the matrix as is; its final cost
# should equal GTSAM's. Usage: bench/pgo/non_pd.sh   (outputs in out/pgo/, like run.sh)
set -euo pipefail
cd "$(dirname "$0")/../.."
DATA="${DWSLAM_DATA:-$PWD/../shared/data}"
mkdir -p out/pgo
python3 bench/pgo/make_non_pd.py "$DATA/pose_graph_g2o/sphere2500.g2o" out/pgo/sphere2500_singular.g2o
python3 bench/pgo/make_non_pd.py "$DATA/pose_graph_g2o/intel.g2o" out/pgo/intel_singular.g2o
bash bench/pgo/run.sh "$PWD/out/pgo/sphere2500_singular.g2o" "$PWD/out/pgo/intel_singular.g2o"
grep -c "not positive definite" out/pgo/sphere2500_singular.dwslam.log out/pgo/intel_singular.dwslam.log || true

#!/usr/bin/env bash
# Micro-benchmark of the lie crate: ns per operation for SE(3)/Sim(3) exp, log, compose,
# inverse, point action and the pose-graph log Jacobians, beside nalgebra's Isometry3 /
# Similarity3 / UnitQuaternion measured in the same run. Single-threaded, release build.
# That none of these allocate is checked by `cargo test -p lie --test no_alloc`.
set -euo pipefail
cd "$(dirname "$0")/../.."
cargo bench -q -p lie --bench ops 2>/dev/null

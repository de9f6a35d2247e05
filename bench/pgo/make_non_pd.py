#!/usr/bin/env python3
"""Writes a copy of a g2o pose graph in which every K-th edge has a singular (positive
semi-definite, not positive definite) information matrix: the diagonal of its information with
the z-translation entry (SE(3)) or the y-translation entry (SE(2)) set to zero, off-diagonal
entries dropped. That is an edge with no information on one translation component, as planar
odometry written into a 3-D graph has.

The matrix is kept exactly diagonal on purpose: GTSAM's noiseModel::Gaussian::Information turns a
diagonal zero precision into sigma = inf (weight 0), which is the correct cost 1/2 d^T L d, while
for a non-diagonal singular matrix it runs Eigen's LLT without checking success and optimises an
unrelated matrix (see crates/data/src/g2o.rs). So on this file GTSAM's cost is the reference.

usage: make_non_pd.py IN.g2o OUT.g2o [--every K]      (stdlib only)
"""
import argparse

ap = argparse.ArgumentParser()
ap.add_argument("src")
ap.add_argument("dst")
ap.add_argument("--every", type=int, default=10)
a = ap.parse_args()

def upper_index(n):
    return [(i, j) for i in range(n) for j in range(i, n)]

count = edges = 0
out = []
for line in open(a.src):
    w = line.split()
    if w and w[0] in ("EDGE_SE3:QUAT", "EDGE_SE2"):
        n, head = (6, 10) if w[0] == "EDGE_SE3:QUAT" else (3, 6)
        if edges % a.every == 0:
            zero = 2 if n == 6 else 1
            vals = []
            for (i, j), v in zip(upper_index(n), w[head:]):
                vals.append("0" if i != j or i == zero else v)
            w = w[:head] + vals
            count += 1
        edges += 1
        out.append(" ".join(w) + "\n")
    else:
        out.append(line)
open(a.dst, "w").writelines(out)
print(f"{a.dst}: {count} of {edges} edges made singular (every {a.every})")

"""Checks, numerically, the GTSAM conventions the benchmark relies on (run in the GTSAM venv).

1. Pose3's chart is the full exponential map: Pose3.localCoordinates(p) == Pose3.Logmap(p)
   and Pose3.retract(x) == Pose3.Expmap(x) for large rotations (GTSAM_POSE3_EXPMAP on); the
   same for Pose2.
2. BetweenFactor<Pose3>'s error on random poses equals 1/2 d^T Lambda_gtsam d with
   d = Log(Z^-1 * Pi^-1 * Pj) computed independently in numpy (pgo_common.se3_log), with
   Lambda_gtsam = P Lambda P^T the (v, omega) -> (omega, v) permutation; the same for Pose2.
3. gtsam.readG2o on a file with full (non-diagonal) 6x6 information: graph.error(initial)
   equals pgo_common.cost on the same file, i.e. readG2o interprets the information exactly as
   dwslam does (file order (x y z qx qy qz) = (v, omega), no quaternion rescaling).
4. The same on every dataset given on the command line (vertex files only).
Prints what it checked and exits non-zero on a mismatch.
"""

import sys

import gtsam
import numpy as np

import pgo_common as pc

rng = np.random.default_rng(7)
ok = True


def check(name, a, b, tol):
    global ok
    err = abs(a - b) / max(1.0, abs(b))
    status = "ok" if err <= tol else "MISMATCH"
    if err > tol:
        ok = False
    print(f"  {status:8s} {name}: {a:.12g} vs {b:.12g} (rel {err:.1e})")


def random_pose3(angle=None):
    axis = rng.normal(size=3)
    axis /= np.linalg.norm(axis)
    theta = rng.uniform(0, 3.0) if angle is None else angle
    t = rng.normal(size=3) * 3
    return gtsam.Pose3(gtsam.Rot3.Rodrigues(axis * theta), t)


import importlib.metadata
print(f"gtsam {importlib.metadata.version('gtsam')}")
print("1. Pose3/Pose2 charts are Expmap/Logmap:")
worst = 0.0
for _ in range(200):
    p = random_pose3()
    worst = max(worst, np.abs(gtsam.Pose3.Logmap(p) - gtsam.Pose3().localCoordinates(p)).max())
    x = rng.normal(size=6) * 1.2
    worst = max(worst, np.abs(gtsam.Pose3().retract(x).matrix() - gtsam.Pose3.Expmap(x).matrix()).max())
check("max |Pose3 localCoordinates - Logmap|, |retract - Expmap|", worst, 0.0, 1e-9)
worst = 0.0
for _ in range(200):
    p = gtsam.Pose2(*(rng.normal(size=2) * 3), rng.uniform(-3, 3))
    worst = max(worst, np.abs(gtsam.Pose2.Logmap(p) - gtsam.Pose2().localCoordinates(p)).max())
check("max |Pose2 localCoordinates - Logmap|", worst, 0.0, 1e-9)
worst = 0.0
for _ in range(200):
    p = random_pose3()
    worst = max(worst, np.abs(pc.se3_log(p.matrix()) - np.concatenate([gtsam.Pose3.Logmap(p)[3:], gtsam.Pose3.Logmap(p)[:3]])).max())
check("max |numpy se3_log (v,w) - GTSAM Logmap permuted|", worst, 0.0, 1e-9)

print("2. BetweenFactor error == 1/2 d^T Lambda d (d computed in numpy):")
worst = 0.0
for _ in range(100):
    pi, pj, z = random_pose3(), random_pose3(), random_pose3()
    a = rng.normal(size=(6, 6))
    info = a @ a.T + 0.5 * np.eye(6)            # dwslam order (v, omega), full
    f = gtsam.BetweenFactorPose3(1, 2, z, gtsam.noiseModel.Gaussian.Information(
        pc.dwslam_to_gtsam_pose3_information(info)))
    v = gtsam.Values()
    v.insert(1, pi)
    v.insert(2, pj)
    d = pc.se3_log(np.linalg.inv(z.matrix()) @ np.linalg.inv(pi.matrix()) @ pj.matrix())
    mine = 0.5 * d @ info @ d
    worst = max(worst, abs(f.error(v) - mine) / max(1.0, mine))
check("max rel |BetweenFactorPose3.error - numpy|", worst, 0.0, 1e-9)
worst = 0.0
for _ in range(100):
    pi, pj, z = (gtsam.Pose2(*(rng.normal(size=2) * 3), rng.uniform(-3, 3)) for _ in range(3))
    a = rng.normal(size=(3, 3))
    info = a @ a.T + 0.5 * np.eye(3)
    f = gtsam.BetweenFactorPose2(1, 2, z, gtsam.noiseModel.Gaussian.Information(info))
    v = gtsam.Values()
    v.insert(1, pi)
    v.insert(2, pj)
    d = pc.residual(2, (z.x(), z.y(), z.theta()), (pi.x(), pi.y(), pi.theta()), (pj.x(), pj.y(), pj.theta()))
    mine = 0.5 * d @ info @ d
    worst = max(worst, abs(f.error(v) - mine) / max(1.0, mine))
check("max rel |BetweenFactorPose2.error - numpy|", worst, 0.0, 1e-9)

print("3. readG2o with a full information matrix:")
import tempfile, os
with tempfile.TemporaryDirectory() as d:
    path = os.path.join(d, "full.g2o")
    with open(path, "w") as f:
        poses = [random_pose3() for _ in range(4)]
        for i, p in enumerate(poses):
            qx, qy, qz, qw = pc.matrix_to_quat(p.rotation().matrix())
            f.write("VERTEX_SE3:QUAT %d %s\n" % (i, " ".join(repr(float(v)) for v in (*p.translation(), qx, qy, qz, qw))))
        for i, j in [(0, 1), (1, 2), (2, 3), (3, 0), (0, 2)]:
            z = random_pose3(angle=0.7)
            qx, qy, qz, qw = pc.matrix_to_quat(z.rotation().matrix())
            a = rng.normal(size=(6, 6))
            info = a @ a.T + 0.5 * np.eye(6)
            upper = [info[r, c] for r in range(6) for c in range(r, 6)]
            f.write("EDGE_SE3:QUAT %d %d %s\n" % (i, j, " ".join(repr(float(v)) for v in (*z.translation(), qx, qy, qz, qw, *upper))))
    graph, initial = gtsam.readG2o(path, True)
    check("readG2o graph.error(initial) vs numpy cost (3D, full information)",
          graph.error(initial), pc.cost(pc.read_g2o(path), pc.read_g2o(path).vertices), 1e-9)

print("4. datasets:")
for path in sys.argv[1:]:
    g = pc.read_g2o(path)
    graph, initial = gtsam.readG2o(path, g.dim == 3)
    check(f"{os.path.basename(path)}: readG2o error vs numpy cost", graph.error(initial), pc.cost(g, g.vertices), 1e-9)

print("all conventions verified" if ok else "MISMATCHES FOUND")
sys.exit(0 if ok else 1)

"""g2o (PyPI g2o-python) peer driver for bench/pgo: optimise one g2o pose graph with g2o's LM.

usage: g2o_pgo.py FILE.g2o --out OUT.g2o [--json OUT.json]

g2o-python's file loader loads nothing, so the graph is built here (pgo_common.read_g2o):
VertexSE2/EdgeSE2 or VertexSE3/EdgeSE3 with the file's measurement and information matrix, as
g2o itself would read the file. g2o's own error is NOT dwslam's/GTSAM's: EdgeSE3's error is
(t, qx, qy, qz) of Z^-1 * Xi^-1 * Xj (quaternion vector part ~ omega/2) and EdgeSE2's is
(t, theta) of it (translation without the V^-1 of the logarithm), so g2o minimises a slightly
different cost. We report g2o's own chi2 (not halved) and, for comparison with GTSAM and dwslam,
the GTSAM/dwslam cost 1/2 sum d^T Lambda d re-evaluated in numpy at g2o's result
(final_cost, pgo_common.cost).
Gauge: the first vertex in the file (or the FIX vertices) is fixed (g2o's set_fixed).
Algorithm: OptimizationAlgorithmLevenberg with its defaults, BlockSolverSE2/SE3 with
LinearSolverEigen (Eigen's sparse Cholesky with AMD); at most 100 iterations, stopped by a
SparseOptimizerTerminateAction when the relative chi2 gain falls below 1e-5 (GTSAM's
relativeErrorTol). The wheel links no OpenMP or TBB. Timing: optimizer.optimize() only.
"""

import argparse
import json
import time

import g2o
import numpy as np

import pgo_common as pc

MAX_ITERATIONS = 100
GAIN_THRESHOLD = 1e-5


def main():
    ap = argparse.ArgumentParser()
    ap.add_argument("file")
    ap.add_argument("--out", required=True)
    ap.add_argument("--json")
    args = ap.parse_args()

    g = pc.read_g2o(args.file)
    opt = g2o.SparseOptimizer()
    if g.dim == 2:
        solver = g2o.BlockSolverSE2(g2o.LinearSolverEigenSE2())
    else:
        solver = g2o.BlockSolverSE3(g2o.LinearSolverEigenSE3())
    opt.set_algorithm(g2o.OptimizationAlgorithmLevenberg(solver))
    gauge = g.fixed if g.fixed else [g.order[0]]
    for i in g.order:
        p = g.vertices[i]
        if g.dim == 2:
            v = g2o.VertexSE2()
            v.set_estimate(g2o.SE2(*p))
        else:
            v = g2o.VertexSE3()
            v.set_estimate(g2o.Isometry3d(p[:3, :3], p[:3, 3]))
        v.set_id(i)
        v.set_fixed(i in gauge)
        opt.add_vertex(v)
    for a, b, z, info in g.edges:
        if g.dim == 2:
            e = g2o.EdgeSE2()
            e.set_measurement(g2o.SE2(*z))
        else:
            e = g2o.EdgeSE3()
            e.set_measurement(g2o.Isometry3d(z[:3, :3], z[:3, 3]))
        e.set_vertex(0, opt.vertex(a))
        e.set_vertex(1, opt.vertex(b))
        e.set_information(info)
        opt.add_edge(e)

    opt.initialize_optimization()
    opt.compute_active_errors()
    initial_chi2 = opt.chi2()
    terminate = g2o.SparseOptimizerTerminateAction()
    terminate.set_gain_threshold(GAIN_THRESHOLD)
    terminate.set_max_iterations(MAX_ITERATIONS)
    opt.add_post_iteration_action(terminate)
    t0 = time.perf_counter()
    iterations = opt.optimize(MAX_ITERATIONS)
    time_s = time.perf_counter() - t0
    opt.compute_active_errors()

    poses = {}
    for i in g.order:
        est = opt.vertex(i).estimate()
        if g.dim == 2:
            x, y, th = est.to_vector()
            poses[i] = (x, y, th)
        else:
            poses[i] = np.array(est.matrix())
    pc.write_g2o(args.out, g, poses)
    summary = dict(
        solver="g2o",
        file=args.file,
        initial_cost=pc.cost(g, g.vertices),
        final_cost=pc.cost(g, poses),
        g2o_initial_chi2=initial_chi2,
        g2o_final_chi2=opt.chi2(),
        iterations=iterations,
        time_s=time_s,
        gauge_vertices=gauge,
    )
    text = json.dumps(summary)
    print(text)
    if args.json:
        with open(args.json, "w") as f:
            f.write(text + "\n")


if __name__ == "__main__":
    main()

"""GTSAM peer driver for bench/pgo: optimise one g2o pose graph with Levenberg-Marquardt.

usage: gtsam_pgo.py FILE.g2o --out OUT.g2o [--json OUT.json]

The graph is built here from the file (pgo_common.read_g2o), with the same interpretation as
dwslam's reader: BetweenFactor<Pose2|Pose3>(from, to, Z) whose error is 1/2 d^T Lambda d with
d = Logmap(Z^-1 * P_from^-1 * P_to) (verify_gtsam_conventions.py checks this numerically), the
file's information matrix permuted into Pose3's (omega, v) order and not rescaled.
Gauge: a PriorFactor on the first vertex in the file (or every FIX vertex) at its initial pose,
with sigmas 1e-6 (that is Lambda = 1e12 I). It is exactly satisfiable, so it adds ~0 to the cost;
the reported costs are those of the between factors alone (graph without the prior), and the
prior's own final error is reported as gauge_prior_cost.
LM parameters: GTSAM's defaults, written out (and asserted equal to the installed defaults).
Timing: optimizer.optimize() only (time_s). Single-threaded: this GTSAM wheel links neither TBB
nor OpenMP (checked with ldd in run.sh); run.sh also pins the process to one CPU.
Prints one JSON object.
"""

import argparse
import json
import time

import gtsam
import numpy as np

import pgo_common as pc

LM_DEFAULTS = dict(
    maxIterations=100,
    relativeErrorTol=1e-5,
    absoluteErrorTol=1e-5,
    errorTol=0.0,
    lambdaInitial=1e-5,
    lambdaFactor=10.0,
    lambdaUpperBound=1e5,
    lambdaLowerBound=0.0,
    diagonalDamping=False,
    useFixedLambdaFactor=True,
)
# Not exposed to Python by gtsam 4.3.0 (no getter or setter), so left at their defaults, as
# LevenbergMarquardtParams.print() shows them: minModelFidelity 1e-3, minDiagonal 1e-6,
# maxDiagonal 1e32; linear solver MULTIFRONTAL_CHOLESKY, ordering COLAMD (set below).


def lm_params():
    p = gtsam.LevenbergMarquardtParams()
    got = dict(
        maxIterations=p.getMaxIterations(),
        relativeErrorTol=p.getRelativeErrorTol(),
        absoluteErrorTol=p.getAbsoluteErrorTol(),
        errorTol=p.getErrorTol(),
        lambdaInitial=p.getlambdaInitial(),
        lambdaFactor=p.getlambdaFactor(),
        lambdaUpperBound=p.getlambdaUpperBound(),
        lambdaLowerBound=p.getlambdaLowerBound(),
        diagonalDamping=p.getDiagonalDamping(),
        useFixedLambdaFactor=p.getUseFixedLambdaFactor(),
    )
    assert got == LM_DEFAULTS, f"GTSAM's LM defaults changed: {got}"
    p.setMaxIterations(LM_DEFAULTS["maxIterations"])
    p.setRelativeErrorTol(LM_DEFAULTS["relativeErrorTol"])
    p.setAbsoluteErrorTol(LM_DEFAULTS["absoluteErrorTol"])
    p.setErrorTol(LM_DEFAULTS["errorTol"])
    p.setlambdaInitial(LM_DEFAULTS["lambdaInitial"])
    p.setlambdaFactor(LM_DEFAULTS["lambdaFactor"])
    p.setlambdaUpperBound(LM_DEFAULTS["lambdaUpperBound"])
    p.setlambdaLowerBound(LM_DEFAULTS["lambdaLowerBound"])
    p.setDiagonalDamping(LM_DEFAULTS["diagonalDamping"])
    p.setUseFixedLambdaFactor(LM_DEFAULTS["useFixedLambdaFactor"])
    p.setLinearSolverType("MULTIFRONTAL_CHOLESKY")
    p.setOrderingType("COLAMD")
    p.setVerbosityLM("SILENT")
    return p


def to_gtsam(dim, pose):
    if dim == 2:
        return gtsam.Pose2(*pose)
    return gtsam.Pose3(pose)


def from_gtsam(dim, pose):
    if dim == 2:
        return (pose.x(), pose.y(), pose.theta())
    return pose.matrix()


def main():
    ap = argparse.ArgumentParser()
    ap.add_argument("file")
    ap.add_argument("--out", required=True)
    ap.add_argument("--json")
    args = ap.parse_args()

    g = pc.read_g2o(args.file)
    graph = gtsam.NonlinearFactorGraph()
    initial = gtsam.Values()
    for i in g.order:
        initial.insert(i, to_gtsam(g.dim, g.vertices[i]))
    for a, b, z, info in g.edges:
        if g.dim == 2:
            model = gtsam.noiseModel.Gaussian.Information(info)
            graph.add(gtsam.BetweenFactorPose2(a, b, gtsam.Pose2(*z), model))
        else:
            model = gtsam.noiseModel.Gaussian.Information(pc.dwslam_to_gtsam_pose3_information(info))
            graph.add(gtsam.BetweenFactorPose3(a, b, gtsam.Pose3(z), model))
    gauge = g.fixed if g.fixed else [g.order[0]]
    priors = gtsam.NonlinearFactorGraph()
    dof = 3 if g.dim == 2 else 6
    prior_model = gtsam.noiseModel.Isotropic.Sigma(dof, 1e-6)
    for i in gauge:
        if g.dim == 2:
            priors.add(gtsam.PriorFactorPose2(i, initial.atPose2(i), prior_model))
        else:
            priors.add(gtsam.PriorFactorPose3(i, initial.atPose3(i), prior_model))
    full = gtsam.NonlinearFactorGraph(graph)
    full.push_back(priors)

    initial_cost = graph.error(initial)
    optimizer = gtsam.LevenbergMarquardtOptimizer(full, initial, lm_params())
    t0 = time.perf_counter()
    result = optimizer.optimize()
    time_s = time.perf_counter() - t0

    poses = {}
    for i in g.order:
        poses[i] = from_gtsam(g.dim, result.atPose2(i) if g.dim == 2 else result.atPose3(i))
    pc.write_g2o(args.out, g, poses)
    summary = dict(
        solver="gtsam",
        file=args.file,
        initial_cost=initial_cost,
        final_cost=graph.error(result),
        final_cost_numpy=pc.cost(g, poses),
        gauge_prior_cost=priors.error(result),
        iterations=optimizer.iterations(),
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

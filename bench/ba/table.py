"""Tables for bench/ba: per run, dwslam vs Ceres final cost and time per iteration; per-iteration
side-by-side for the Ladybug problem; and the growth exponent of time per iteration in the
number of points (synthetic problems, fixed cameras)."""
import json
import math
import sys
from pathlib import Path

out = Path(sys.argv[1])
problems = sys.argv[2:]


def load(p, solver, threads, who):
    f = out / f"{p}.{solver}.t{threads}.{who}.json"
    return json.loads(f.read_text()) if f.exists() else None


print("| problem | solver (dwslam / Ceres) | threads | dwslam final ½Σ‖r‖² | Ceres final ½Σ‖r‖² | rel. diff | dwslam s/iter | Ceres s/iter | ratio | CPU-time ratio |")
print("|---|---|---:|---:|---:|---:|---:|---:|---:|---:|")
growth = {}
for p in problems:
    for solver, ceres_name in [("schur-cholesky", "SPARSE_SCHUR"), ("schur-pcg", "ITERATIVE_SCHUR+SCHUR_JACOBI")]:
        for threads in (1, 2):
            d, c = load(p, solver, threads, "dwslam"), load(p, solver, threads, "ceres")
            if not d or not c:
                continue
            rel = (d["final_cost"] - c["final_cost"]) / c["final_cost"]
            ratio = d["time_per_iteration_s"] / c["time_per_iteration_s"]
            dc, cc = d.get("cpu_time_per_iteration_s"), c.get("cpu_time_per_iteration_s")
            cpu = f"{dc / cc:.2f}" if dc and cc else "n/a"
            print(f"| {p} | {solver} / {ceres_name} | {threads} | {d['final_cost']:.6g} | {c['final_cost']:.6g} | {rel:+.2e} | "
                  f"{d['time_per_iteration_s']:.4f} | {c['time_per_iteration_s']:.4f} | {ratio:.2f} | {cpu} |")
            if p.startswith("synthetic-") and solver == "schur-cholesky" and threads == 1:
                growth[int(p.split("-")[1])] = (d["time_per_iteration_s"], c["time_per_iteration_s"], d["rms_px"])

for p in problems[:1]:
    d, c = load(p, "schur-cholesky", 1, "dwslam"), load(p, "schur-cholesky", 1, "ceres")
    if d and c:
        print(f"\nPer iteration, {p}, 1 thread (dwslam schur-cholesky / Ceres SPARSE_SCHUR; Ceres lists iteration 0, the initial evaluation):\n")
        print("| iteration | dwslam ½Σ‖r‖² | Ceres ½Σ‖r‖² | dwslam elapsed s | Ceres elapsed s |")
        print("|---:|---:|---:|---:|---:|")
        ours = d["per_iteration"]
        theirs = c["per_iteration"][1:]
        for k in range(max(len(ours), len(theirs))):
            a = ours[k] if k < len(ours) else None
            b = theirs[k] if k < len(theirs) else None
            print(f"| {k + 1} | {a['cost'] if a else float('nan'):.6f} | {b['cost'] if b else float('nan'):.6f} | "
                  f"{a['elapsed_s'] if a else float('nan'):.3f} | {b['elapsed_s'] if b else float('nan'):.3f} |")

if len(growth) >= 2:
    ns = sorted(growth)
    print("\nGrowth with the number of points (50 cameras, 1 thread, schur-cholesky; σ = 1 px):\n")
    print("| points | dwslam s/iter | Ceres s/iter | dwslam final RMS px |")
    print("|---:|---:|---:|---:|")
    for n in ns:
        print(f"| {n} | {growth[n][0]:.4f} | {growth[n][1]:.4f} | {growth[n][2]:.3f} |")
    for who, k in (("dwslam", 0), ("Ceres", 1)):
        xs = [math.log(n) for n in ns]
        ys = [math.log(growth[n][k]) for n in ns]
        mx, my = sum(xs) / len(xs), sum(ys) / len(ys)
        slope = sum((x - mx) * (y - my) for x, y in zip(xs, ys)) / sum((x - mx) ** 2 for x in xs)
        print(f"\n{who}: time per iteration ∝ N^{slope:.2f} (least-squares fit over {len(ns)} sizes)")

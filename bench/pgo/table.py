"""Prints the bench/pgo markdown table from out/pgo/*.json (see run.sh)."""

import json
import os
import sys


def load(path):
    try:
        with open(path) as f:
            return json.load(f)
    except (OSError, ValueError):
        return None


def num(v, fmt="{:.6g}"):
    return "n/a" if v is None else fmt.format(v)


out, names = sys.argv[1], sys.argv[2:]
print("| dataset | initial ½χ² | dwslam final ½χ² | GTSAM final ½χ² | g2o final ½χ² (its χ²) "
      "| dwslam time s | GTSAM time s | g2o time s | iterations dwslam/GTSAM/g2o "
      "| ratio dwslam/GTSAM | RMSE vs GT dwslam / GTSAM / g2o (m) |")
print("|---|---:|---:|---:|---:|---:|---:|---:|---:|---:|---:|")
for name in names:
    init = load(os.path.join(out, f"{name}.init.json")) or {}
    ours = load(os.path.join(out, f"{name}.dwslam.json")) or {}
    gt = load(os.path.join(out, f"{name}.gtsam.json")) or {}
    g2 = load(os.path.join(out, f"{name}.g2o.json")) or {}
    ours_t = ours.get("solve_time_s")
    ratio = ours_t / gt["time_s"] if ours_t is not None and gt.get("time_s") else None
    rmse = []
    for who in ("dwslam", "gtsam", "g2o"):
        r = load(os.path.join(out, f"{name}.{who}.rmse.json"))
        rmse.append(num(r["translation_rmse"], "{:.4g}") if r else "n/a")
    g2o_cell = "n/a"
    if g2:
        g2o_cell = f"{g2['final_cost']:.6g} ({g2['g2o_final_chi2']:.6g})"
    iters = "/".join(str(d.get("iterations", "n/a")) if d else "n/a" for d in (ours, gt, g2))
    print(f"| {name} | {num(init.get('initial_cost'))} | {num(ours.get('final_cost'))} "
          f"| {num(gt.get('final_cost'))} | {g2o_cell} | {num(ours_t, '{:.3g}')} "
          f"| {num(gt.get('time_s'), '{:.3g}')} | {num(g2.get('time_s'), '{:.3g}')} | {iters} "
          f"| {num(ratio, '{:.2f}')} | {' / '.join(rmse) if any(x != 'n/a' for x in rmse) else '—'} |")

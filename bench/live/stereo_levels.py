#!/usr/bin/env python3
"""dwslam's stereo sequences at two settings of `stereo.level` (the pyramid level block matching
runs at), deterministic, one after the other on the same core: ATE of the live and the final
trajectory and the time per frame, side by side, as a markdown table (also OUT/table.md).

    bench/live/stereo_levels.py --dwslam target/release/dwslam --out OUT [--levels 0,1]
        [--cpu 1] SEQ [SEQ ...]

Each SEQ is a stereo sequence folder `dwslam run` reads (KITTI, EuRoC or rendered). Several
sequences (and renders of one world with different seeds, `dwslam render --seed`) are needed:
a single run's ATE moves by tens of per cent with any small change of the front end (a
keyframe or a loop closure more or less), so one sequence cannot rank two settings.
"""

import argparse
import json
import os
import subprocess
import sys


def run(dwslam, seq, level, out, cpu):
    """One deterministic run; returns (ATE live cm, ATE final cm, ms per frame)."""
    os.makedirs(out, exist_ok=True)
    config = os.path.join(out, "config.yaml")
    with open(config, "w") as f:
        f.write(f"stereo:\n  level: {level}\n")
    cmd = [dwslam, "run", seq, "--sensor", "stereo", "--deterministic", "--config", config,
           "--out", out]
    if cpu is not None:
        cmd = ["taskset", "-c", str(cpu)] + cmd
    r = subprocess.run(cmd, capture_output=True, text=True)
    if r.returncode != 0:
        sys.exit(f"{' '.join(cmd)} failed:\n{r.stderr[-2000:]}")
    with open(os.path.join(out, "summary.json")) as f:
        s = json.load(f)
    ev = s["evaluation"]
    return (100 * ev["live"]["ate_rmse_m"], 100 * ev["final"]["ate_rmse_m"],
            1000 * s["run"]["seconds"] / s["frames"])


def main():
    p = argparse.ArgumentParser(description=__doc__,
                                formatter_class=argparse.RawDescriptionHelpFormatter)
    p.add_argument("--dwslam", required=True)
    p.add_argument("--out", required=True)
    p.add_argument("--levels", type=lambda s: [int(x) for x in s.split(",")], default=[0, 1],
                   help="comma-separated levels (default 0,1)")
    p.add_argument("--cpu", type=int, default=None, help="pin each run to this core")
    p.add_argument("sequences", nargs="+")
    a = p.parse_args()
    head = "| sequence | " + " | ".join(
        f"level {l}: ATE live / final (cm), ms per frame" for l in a.levels) + " |"
    lines = [head, "|---|" + "---|" * len(a.levels)]
    print(head, flush=True)
    sums = {l: [0.0, 0.0, 0.0] for l in a.levels}
    for seq in a.sequences:
        name = os.path.basename(os.path.normpath(seq))
        cells = []
        for l in a.levels:
            live, final, ms = run(a.dwslam, seq, l, os.path.join(a.out, f"{name}-level{l}"), a.cpu)
            for i, v in enumerate((live, final, ms)):
                sums[l][i] += v
            cells.append(f"{live:.2f} / {final:.2f}, {ms:.1f}")
        line = f"| {name} | " + " | ".join(cells) + " |"
        lines.append(line)
        print(line, flush=True)
    n = len(a.sequences)
    line = "| mean | " + " | ".join(
        f"{sums[l][0] / n:.2f} / {sums[l][1] / n:.2f}, {sums[l][2] / n:.1f}" for l in a.levels) + " |"
    lines.append(line)
    print(line)
    with open(os.path.join(a.out, "table.md"), "w") as f:
        f.write("\n".join(lines) + "\n")


if __name__ == "__main__":
    main()

#!/usr/bin/env python3
"""Per 100 keyframes of one `dwslam experiment dwo` run: median optimisation time, median
window contents and mean inner-window RMSE of BA and cDWO, graph points at the end of each
block (thesis Figure 6.10 (b)).

    bench/dwo/blocks.py DIR        (DIR holds ba.csv and cdwo.csv)"""
import csv
import math
import pathlib
import statistics
import sys


def rows(path):
    with open(path) as f:
        return [{k: float(v) for k, v in r.items()} for r in csv.DictReader(f)]


def main():
    if len(sys.argv) != 2:
        sys.exit(__doc__)
    d = pathlib.Path(sys.argv[1])
    ba, cdwo = rows(d / "ba.csv"), rows(d / "cdwo.csv")
    med = lambda rs, k: statistics.median(r[k] for r in rs)
    mean = lambda rs, k: statistics.mean(r[k] for r in rs if not math.isnan(r[k]))
    print("| keyframes | BA t | BA points / obs. | cDWO t | cDWO points / point-pose / pose-pose "
          "| cDWO inner | BA inner | graph points |")
    print("|---" * 8 + "|")
    for a in range(0, len(ba), 100):
        b, c = ba[a:a + 100], cdwo[a:a + 100]
        print(f"| {a}–{a + len(b) - 1} | {med(b, 'time_optimise_s') * 1e3:.0f} ms "
              f"| {med(b, 'points'):.0f} / {med(b, 'point_constraints') / 1e3:.1f}k "
              f"| {med(c, 'time_optimise_s') * 1e3:.1f} ms "
              f"| {med(c, 'points'):.0f} / {med(c, 'point_constraints') / 1e3:.1f}k / {med(c, 'pose_constraints'):.0f} "
              f"| {mean(c, 'rmse_inner'):.2e} | {mean(b, 'rmse_inner'):.2e} | {c[-1]['graph_points']:.0f} |")


if __name__ == "__main__":
    main()

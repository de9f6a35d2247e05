#!/usr/bin/env python3
"""What the live view costs a run: `dwslam run SEQ --deterministic` (or threaded) without and with
`--view-save FILE.rrd`, alternated `--repeats` times, wall-clock seconds of each process
(the view's logging, its final map and the file's flush included) and of the frame loop
(`summary.json` run.seconds). Prints the medians and their ratio (the issue's bound: ≤ 1.10).

    python3 bench/view/cost.py --dwslam target/release/dwslam \\
        --sequence ../shared/data/seven_scenes_redkitchen_1000 [--repeats 3] [-- EXTRA ARGS]

The binary must be built with `--features view`.
"""

import argparse
import json
import pathlib
import statistics
import subprocess
import sys
import tempfile
import time


def one(dwslam, sequence, extra, view, work):
    out = work / ("view" if view else "plain")
    args = [dwslam, "run", sequence, "--quiet", "--out", out, *extra]
    if view:
        args += ["--view-save", work / "view.rrd"]
    started = time.perf_counter()
    subprocess.run(args, check=True, stdout=subprocess.DEVNULL)
    wall = time.perf_counter() - started
    loop = json.loads((out / "summary.json").read_text())["run"]["seconds"]
    size = (work / "view.rrd").stat().st_size if view else 0
    return wall, loop, size


def main():
    p = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    p.add_argument("--dwslam", required=True)
    p.add_argument("--sequence", required=True)
    p.add_argument("--repeats", type=int, default=3)
    p.add_argument("--threaded", action="store_true",
                   help="the back-end in its threads (default: --deterministic, one thread)")
    p.add_argument("extra", nargs="*", help="further `dwslam run` arguments")
    a = p.parse_args()
    rows = {False: [], True: []}
    extra = a.extra if a.threaded else ["--deterministic", *a.extra]
    with tempfile.TemporaryDirectory() as tmp:
        work = pathlib.Path(tmp)
        for r in range(a.repeats):
            for view in (False, True):
                rows[view].append(one(a.dwslam, a.sequence, extra, view, work))
                wall, loop, size = rows[view][-1]
                print(f"run {r + 1} {'with' if view else 'without'} the view: "
                      f"{wall:.2f} s ({loop:.2f} s frame loop)"
                      + (f", {size / 1e6:.1f} MB .rrd" if view else ""), flush=True)
    med = {v: (statistics.median(x[0] for x in rows[v]),
               statistics.median(x[1] for x in rows[v])) for v in rows}
    print(f"median without: {med[False][0]:.2f} s wall, {med[False][1]:.2f} s frame loop")
    print(f"median with:    {med[True][0]:.2f} s wall, {med[True][1]:.2f} s frame loop")
    ratio_wall = med[True][0] / med[False][0]
    ratio_loop = med[True][1] / med[False][1]
    print(f"ratio with / without: {ratio_wall:.3f} wall, {ratio_loop:.3f} frame loop "
          f"(bound 1.10)")
    return 0


if __name__ == "__main__":
    sys.exit(main())

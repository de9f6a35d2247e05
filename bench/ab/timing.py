#!/usr/bin/env python3
"""Time two builds of dwslam against each other on the same core.

    bench/ab/timing.py BIN_A BIN_B [--threaded N] [--deterministic M] [--only a,b] [--cpu C]

For each case the two binaries are alternated (A B, then B A, ...) on one pinned core: N threaded
runs each (the live and final ATE's range, the median tracking and frame time, the tracking
thread's lock waits of the last run) and M deterministic runs each (median tracking and frame
time, ms). A ratio on one machine at one time, not an absolute figure.
"""
import argparse, json, os, statistics, subprocess, sys

HERE = os.path.dirname(os.path.abspath(__file__))
D = os.environ.get("DWSLAM_DATA", os.path.normpath(os.path.join(HERE, "../../../shared/data")))
R = os.environ.get("RENDERED", "/work/renders")
CASES = [("7s-rgbd500", [f"{D}/seven_scenes_redkitchen_1000", "--depth-frames-only"]),
         ("kitti1-stereo", [f"{D}/kitti_odometry_snippets/KITTI_sequence_1"]),
         ("euroc", [f"{D}/euroc_v1_01_easy_micro"]),
         ("7s-mono", [f"{D}/seven_scenes_redkitchen_1000", "--sensor", "mono"]),
         ("kitti04-mono", [f"{D}/kitti_odometry_snippets/KITTI_04_0_270", "--sensor", "mono"]),
         ("room-rgbd", [f"{R}/room-rgbd"]),
         ("courtyard-stereo", [f"{R}/courtyard-stereo"])]


def run(binary, args, deterministic, cpu):
    out = "/tmp/dwslam-ab-timing"
    cmd = ["taskset", "-c", cpu, binary, "run", *args, "--quiet", "--out", out]
    p = subprocess.run(cmd + (["--deterministic"] if deterministic else []), capture_output=True, text=True)
    if p.returncode != 0:
        sys.exit(f"{' '.join(cmd)} failed ({p.returncode}): {p.stderr[-600:]}")
    s = json.load(open(f"{out}/summary.json"))
    t = {x["stage"]: x for x in s["timings"]}
    ev = s.get("evaluation", {})
    ate = lambda k: ev.get(k, {}).get("ate_rmse_m", float("nan")) * 100
    return dict(live=ate("live"), final=ate("final"), track=t["track: total"]["mean_ms"],
                frame=t["frame: total"]["mean_ms"], waits=s.get("tracking_lock_waits", {}))


def alternated(a, b, n, f):
    res = {a: [], b: []}
    for i in range(n):
        for x in ((a, b) if i % 2 == 0 else (b, a)):
            res[x].append(f(x))
    return res


def main():
    ap = argparse.ArgumentParser()
    ap.add_argument("a")
    ap.add_argument("b")
    ap.add_argument("--threaded", type=int, default=3)
    ap.add_argument("--deterministic", type=int, default=1)
    ap.add_argument("--only")
    ap.add_argument("--cpu", default="1")
    o = ap.parse_args()
    cases = [c for c in CASES if os.path.exists(c[1][0])]
    if o.only:
        cases = [c for c in cases if any(x in c[0] for x in o.only.split(","))]
    med = lambda rs, k: statistics.median(r[k] for r in rs)
    for name, args in cases:
        th = alternated(o.a, o.b, o.threaded, lambda x: run(x, args, False, o.cpu))
        det = alternated(o.a, o.b, o.deterministic, lambda x: run(x, args, True, o.cpu))
        for x in (o.a, o.b):
            line = f"{name:18s} {os.path.basename(x):14s}"
            if th[x]:
                lv, fi = [r["live"] for r in th[x]], [r["final"] for r in th[x]]
                line += (f" threaded: live {min(lv):.2f}-{max(lv):.2f} final {min(fi):.2f}-{max(fi):.2f} cm,"
                         f" track {med(th[x], 'track'):.2f} frame {med(th[x], 'frame'):.2f} ms, waits {th[x][-1]['waits']} |")
            if det[x]:
                line += (f" deterministic: live {det[x][0]['live']:.2f} final {det[x][0]['final']:.2f} cm,"
                         f" track {med(det[x], 'track'):.2f} frame {med(det[x], 'frame'):.2f} ms"
                         " (frames " + ", ".join(f"{r['frame']:.2f}" for r in det[x]) + ")")
            print(line, flush=True)


main()

#!/usr/bin/env python3
"""Capture deterministic dwslam runs of one build, to compare two builds' outputs file by file.

    bench/ab/capture.py BINARY TAG [--set quick|full|rendered] [--only a,b] [--cpu N] [--threaded]

Writes $AB_OUT/TAG/NAME/ (a run's outputs; AB_OUT defaults to /tmp/dwslam-ab) and prints a line
per run: the SHA-1 of its live and final trajectories, keyframes and map, and its counts.
`bench/ab/compare.py TAG_A TAG_B` then prints, per run, the largest position difference between
the two builds' trajectories. The cases: the shared sequences (../shared/data, or $DWSLAM_DATA),
cuts of them that force a relocalisation or a new map (made under $AB_OUT/sequences from
symbolic links), and with `--set full` or `rendered` the renders in $RENDERED (default
/work/renders; `dwslam render`, see bench/live/run.sh) where they exist.
"""
import argparse, hashlib, json, os, subprocess, sys, time, glob

sys.path.insert(0, os.path.join(os.path.dirname(os.path.abspath(__file__)), "..", "live"))
import cuts  # noqa: E402

HERE = os.path.dirname(os.path.abspath(__file__))
DATA = os.environ.get("DWSLAM_DATA", os.path.normpath(os.path.join(HERE, "../../../shared/data")))
R = os.environ.get("RENDERED", "/work/renders")
ROOT = os.environ.get("AB_OUT", "/tmp/dwslam-ab")
CUTS = os.path.join(ROOT, "sequences")
SEVEN = os.path.join(DATA, "seven_scenes_redkitchen_1000")


def seven_cut(name, first, last):
    return cuts.seven_scenes_cut(os.path.join(CUTS, name), SEVEN, first, last)


def kitti_cut(name, source, first, last):
    return cuts.kitti_cut(os.path.join(CUTS, name), source, first, last)


def new_map_now():
    p = os.path.join(CUTS, "new_map_after_0.yaml")
    os.makedirs(CUTS, exist_ok=True)
    with open(p, "w") as f:
        f.write("tracker:\n  new_map_after: 0\n")
    return p


def runs():
    k1 = os.path.join(DATA, "kitti_odometry_snippets/KITTI_sequence_1")
    k4 = os.path.join(DATA, "kitti_odometry_snippets/KITTI_04_0_270")
    quick = [
        ("7s-rgbd500", [SEVEN, "--depth-frames-only"]),
        ("kitti1-stereo", [k1]),
        ("euroc", [os.path.join(DATA, "euroc_v1_01_easy_micro")]),
        ("kitti1-mono", [k1, "--sensor", "mono"]),
        ("7s-mono", [SEVEN, "--sensor", "mono"]),
        ("7s-rgbd-cut301-619", [seven_cut("c1", 301, 619), "--depth-frames-only"]),
        ("7s-mono-cut301-399-newmap", [seven_cut("c2", 301, 399), "--sensor", "mono", "--config", new_map_now()]),
        ("7s-mono-cut301-619", [seven_cut("c1", 301, 619), "--sensor", "mono"]),
    ]
    full = quick + [
        ("7s-rgbd1000", [SEVEN]),
        ("7s-rgbd-cut301-399", [seven_cut("c2", 301, 399), "--depth-frames-only"]),
        ("7s-mono-cut301-399", [seven_cut("c2", 301, 399), "--sensor", "mono"]),
        ("kitti04-mono", [k4, "--sensor", "mono"]),
        ("tum-fr1", [os.path.join(DATA, "tum_rgbd_fr1_xyz_fragment")]),
    ]
    rendered = [
        ("room-rgbd", [f"{R}/room-rgbd"]),
        ("room-stereo", [f"{R}/room-stereo"]),
        ("courtyard-stereo", [f"{R}/courtyard-stereo"]),
        ("building-stereo", [f"{R}/building-stereo"]),
        ("room-mono", [f"{R}/room-mono"]),
        ("courtyard-mono", [f"{R}/courtyard-mono"]),
        ("building-mono", [f"{R}/building-mono"]),
    ]
    if os.path.isdir(f"{R}/courtyard-stereo"):
        rendered.append(("courtyard-stereo-cut1500-2199",
                         [kitti_cut("courtyard-cut", f"{R}/courtyard-stereo", 1500, 2199)]))
        rendered.append(("courtyard-mono-cut300-699",
                         [kitti_cut("courtyard-cut2", f"{R}/courtyard-stereo", 300, 699), "--sensor", "mono"]))
    rendered = [r for r in rendered if os.path.exists(r[1][0])]
    return {"quick": quick, "full": full + rendered, "rendered": rendered}


def sha(path):
    if not os.path.exists(path):
        return "-"
    return hashlib.sha1(open(path, "rb").read()).hexdigest()[:10]


def main():
    ap = argparse.ArgumentParser()
    ap.add_argument("binary")
    ap.add_argument("tag")
    ap.add_argument("--set", default="quick")
    ap.add_argument("--only")
    ap.add_argument("--cpu", default="1")
    ap.add_argument("--threaded", action="store_true")
    a = ap.parse_args()
    if not os.path.isdir(DATA):
        sys.exit(f"no shared data at {DATA}: set DWSLAM_DATA")
    todo = runs()[a.set]
    if a.only:
        todo = [r for r in todo if any(o in r[0] for o in a.only.split(","))]
    for name, args in todo:
        out = os.path.join(ROOT, a.tag, name)
        cmd = ["taskset", "-c", a.cpu, a.binary, "run", *args, "--quiet", "--out", out]
        if not a.threaded:
            cmd.append("--deterministic")
        t = time.time()
        p = subprocess.run(cmd, capture_output=True, text=True)
        dt = time.time() - t
        if p.returncode != 0:
            print(f"{name:34s} FAILED rc={p.returncode}: {p.stderr[-600:]}", flush=True)
            continue
        s = json.load(open(os.path.join(out, "summary.json")))
        finals = sorted(glob.glob(os.path.join(out, "trajectory_final*.tum")))
        fin = " ".join(f"{os.path.basename(f)[17:-4] or 'final'}={sha(f)}" for f in finals)
        ate = s.get("ate", {})
        print(f"{name:34s} live={sha(os.path.join(out, 'trajectory.tum'))} {fin} kf={sha(os.path.join(out, 'keyframes.tum'))} "
              f"map={sha(os.path.join(out, 'map.ply'))} frames={s.get('frames')} keyframes={s.get('keyframes')} "
              f"points={s.get('points')} ate={json.dumps(ate, separators=(',', ':'))[:120]} {dt:.0f}s", flush=True)


main()

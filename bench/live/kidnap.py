#!/usr/bin/env python3
"""Kidnapped cameras: dwslam (relocalisation) beside ORB-SLAM3 on sequences with a stretch of
frames cut out, so that the camera jumps and no motion model bridges the gap.

    bench/live/kidnap.py --dwslam target/release/dwslam --out OUT [--data DIR] [--peers DIR]
        [--venv DIR] [--rendered DIR] [--orb-runs 2] [--cpu 1]

The cut sequences are folders of symbolic links into the shared data (and the rendered
courtyard) under OUT/sequences:

- 7-Scenes, frames 301-619 cut: the camera jumps 1.5 m to the place it saw around frame 200
  (PROVENANCE.md: frames 136-205 are revisited at 616-680) - a jump into the map;
- 7-Scenes, frames 301-399 cut: a jump to the far side of the table, which the map has not seen;
  it comes back into view around frame 480;
- the rendered courtyard (stereo, `dwslam render courtyard --sensor stereo --layout kitti`),
  frames 1500-2199 cut: half a lap skipped;
- the courtyard, frames 300-699 cut: a 21 m jump in the first lap, to the part of the courtyard
  the map has not seen; the camera comes back to the mapped part about 20 s later (monocular:
  a new map starts after 3 s, and is joined to the first when it sees the first's places).

7-Scenes runs on its frames with depth (dwslam `--depth-frames-only`, ORB-SLAM3 RGB-D on
associations.txt), and monocular on all its colour frames with the same cuts (dwslam `--sensor
mono`, ORB-SLAM3 mono), as do the courtyard's cuts on its left images; the 301-399 cut once more
with `tracker.new_map_after: 0` (dwslam only), so that the monocular camera starts a new map at
once and the two maps are joined by place recognition. dwslam runs deterministic, ORB-SLAM3 `--orb-runs` times (it is not
deterministic), each pinned to one core. ATE by evo_ape -a (SE(3); monocular -a -s, Sim(3), one
alignment for all the frames) over the frames each system gave a pose, live and after the run, beside the fraction of frames tracked (dwslam: good or weak,
including frames tracked in a new map not joined to the first yet, which have no pose in the
world) and dwslam's frames with a pose in each trajectory. Prints a markdown table (also
OUT/table.md).
"""
import argparse
import json
import os
import re
import subprocess
import sys

sys.path.insert(0, os.path.dirname(os.path.abspath(__file__)))
import cuts  # noqa: E402

HERE = os.path.dirname(os.path.abspath(__file__))
ROOT = os.path.abspath(os.path.join(HERE, "../.."))
ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
ap.add_argument("--dwslam", required=True)
ap.add_argument("--out", required=True)
ap.add_argument("--data", default=os.environ.get("DWSLAM_DATA", os.path.join(ROOT, "../shared/data")))
ap.add_argument("--peers", default=os.path.join(ROOT, "../shared/peers/live"))
ap.add_argument("--venv", default=os.environ.get("LIVE_PEERS_VENV", os.path.expanduser("~/.cache/dwslam-live-peers")))
ap.add_argument("--rendered", help="folder holding courtyard-stereo (rendered there when missing); omit to skip it")
ap.add_argument("--orb-runs", type=int, default=2)
ap.add_argument("--cpu", type=int, default=1)
ap.add_argument("--only", help="run only the cases whose title contains this text (e.g. mono)")
a = ap.parse_args()
a.out = os.path.abspath(a.out)
evo = os.path.join(a.venv, "bin", "evo_ape")
SEVEN = os.path.join(a.data, "seven_scenes_redkitchen_1000")


def seven_scenes_cut(name, first, last):
    """7-Scenes without frames first..=last: a dwslam folder and run_peer.py's data root."""
    root = os.path.join(a.out, "sequences", name)
    return cuts.seven_scenes_cut(root, SEVEN, first, last), root


def kitti_cut(name, source, first, last):
    """A KITTI-layout folder without frames first..=last (renumbered links)."""
    return cuts.kitti_cut(os.path.join(a.out, "sequences", name), source, first, last)


def ate(gt, est, mono=False):
    scale = ["-s"] if mono else []
    p = subprocess.run([evo, "tum", gt, est, "-a", *scale, "--t_max_diff", "0.02"], capture_output=True, text=True)
    m = re.search(r"rmse\s+([0-9.eE+-]+)", p.stdout)
    return float(m.group(1)) if m else None


def count_poses(path):
    return sum(1 for l in open(path) if l.strip() and not l.startswith("#"))


def dwslam(name, seq, extra):
    out = os.path.join(a.out, "dwslam-" + name)
    cmd = ["taskset", "-c", str(a.cpu), a.dwslam, "run", seq, *extra, "--deterministic", "--quiet", "--out", out]
    p = subprocess.run(cmd, capture_output=True, text=True)
    if p.returncode != 0:
        sys.exit(f"{' '.join(cmd)} failed:\n{p.stderr[-2000:]}")
    s = json.load(open(os.path.join(out, "summary.json")))
    gt = os.path.join(out, "ground_truth.tum")
    mono = s.get("sensor") == "mono"
    final = os.path.join(out, "trajectory_final.tum")
    if not os.path.exists(final):
        # A monocular run with loops writes each correction's trajectory; Sim(3) is the default.
        final = os.path.join(out, "trajectory_final_sim3.tum")
    return {
        "ate_live": ate(gt, os.path.join(out, "trajectory.tum"), mono),
        "ate_final": ate(gt, final, mono),
        "tracked": (s["tracking"]["good"] + s["tracking"]["weak"]) / s["frames"],
        "with_pose": [count_poses(os.path.join(out, f)) / s["frames"] for f in ("trajectory.tum", final)],
        "relocalisations": [(r["frame"], r["keyframe_frame"]) for r in s.get("relocalisations", [])],
        "new_maps": [(m["frame"], m["joined"]) for m in s.get("new_maps", [])],
    }


def orbslam3(name, peer_seq, extra, run):
    out = os.path.join(a.out, f"orbslam3-{name}-{run}")
    cmd = ["taskset", "-c", str(a.cpu), os.path.join(a.venv, "bin", "python"),
           os.path.join(a.peers, "run_peer.py"), "orbslam3", peer_seq, out, *extra]
    env = {**os.environ, "PATH": os.path.join(a.venv, "bin") + ":" + os.environ["PATH"], "OMP_NUM_THREADS": "1"}
    p = subprocess.run(cmd, capture_output=True, text=True, env=env)
    lines = [l for l in p.stdout.splitlines() if l.startswith("{")]
    if not lines:
        return {"error": (p.stdout + p.stderr)[-500:]}
    r = json.loads(lines[-1])
    return {"ate_live": r.get("ate_rmse_online_m"), "ate_final": r.get("ate_rmse_m"),
            "tracked": r.get("tracked_frac"), "lost": r.get("lost_frames")}


cases = []
seq, root = seven_scenes_cut("7scenes-jump-into-map", 301, 619)
cases.append(("7-Scenes RGB-D, frames 301-619 cut (a jump into the map)", "7scenes-jump-into-map",
              seq, ["--depth-frames-only"], "7scenes", ["--data", root]))
seq, root = seven_scenes_cut("7scenes-jump-off-map", 301, 399)
cases.append(("7-Scenes RGB-D, frames 301-399 cut (a jump off the map)", "7scenes-jump-off-map",
              seq, ["--depth-frames-only"], "7scenes", ["--data", root]))
seq, root = seven_scenes_cut("7scenes-jump-into-map", 301, 619)
cases.append(("7-Scenes mono, frames 301-619 cut (a jump into the map)", "7scenes-mono-jump-into-map",
              seq, ["--sensor", "mono"], "7scenes-mono", ["--data", root]))
seq, root = seven_scenes_cut("7scenes-jump-off-map", 301, 399)
cases.append(("7-Scenes mono, frames 301-399 cut (a jump off the map)", "7scenes-mono-jump-off-map",
              seq, ["--sensor", "mono"], "7scenes-mono", ["--data", root]))
# The same cut with a new map at once instead of relocalisation: the two maps joined by place
# recognition (ORB-SLAM3 is not run again: its rows are the case above).
new_map_at_once = os.path.join(a.out, "new-map-at-once.yaml")
with open(new_map_at_once, "w") as f:
    f.write("tracker:\n  new_map_after: 0\n")
cases.append(("7-Scenes mono, frames 301-399 cut, `tracker.new_map_after: 0` (a new map at once, joined later)",
              "7scenes-mono-jump-off-map-new-map", seq, ["--sensor", "mono", "--config", new_map_at_once], None, []))
if a.rendered:
    courtyard = os.path.join(a.rendered, "courtyard-stereo")
    if not os.path.isdir(courtyard):
        subprocess.run([a.dwslam, "render", "courtyard", "--sensor", "stereo", "--layout", "kitti",
                        "--out", courtyard], check=True)
    seq = kitti_cut("courtyard-stereo-cut", courtyard, 1500, 2199)
    cases.append(("rendered courtyard stereo, frames 1500-2199 cut", "courtyard-cut", seq, ["--sensor", "stereo"],
                  "kitti-dir-stereo", ["--dir", seq]))
    cases.append(("rendered courtyard mono, frames 1500-2199 cut", "courtyard-mono-cut", seq, ["--sensor", "mono"],
                  "kitti-dir", ["--dir", seq]))
    seq = kitti_cut("courtyard-stereo-cut-first-lap", courtyard, 300, 699)
    cases.append(("rendered courtyard stereo, frames 300-699 cut (a jump off the map in the first lap)",
                  "courtyard-cut-first-lap", seq, ["--sensor", "stereo"], "kitti-dir-stereo", ["--dir", seq]))
    cases.append(("rendered courtyard mono, frames 300-699 cut (a jump off the map in the first lap)",
                  "courtyard-mono-cut-first-lap", seq, ["--sensor", "mono"], "kitti-dir", ["--dir", seq]))

if a.only:
    cases = [c for c in cases if a.only in c[0]]

cm = lambda x: "—" if x is None else f"{100 * x:.2f} cm"
rng = lambda xs: "—" if not xs else (cm(min(xs)) if min(xs) == max(xs) else f"{100 * min(xs):.2f}–{cm(max(xs))}")
table = ["| sequence | system | ATE live | ATE after the run | tracked | with a pose, live / after the run | relocalised (frame ← keyframe's frame, positions in the cut sequence) | new maps (frame: joined to the first?) |",
         "|---|---|---|---|---|---|---|---|"]
print("\n".join(table), flush=True)
results = {}
for title, name, seq, extra, peer_seq, peer_extra in cases:
    d = dwslam(name, seq, extra)
    o = [orbslam3(name, peer_seq, peer_extra, i) for i in range(a.orb_runs)] if peer_seq else []
    results[name] = {"dwslam": d, "orbslam3": o}
    ok = [r for r in o if "error" not in r]
    rows = [f"| {title} | dwslam (deterministic) | {cm(d['ate_live'])} | {cm(d['ate_final'])} | "
            f"{100 * d['tracked']:.1f} % | {100 * d['with_pose'][0]:.1f} % / {100 * d['with_pose'][1]:.1f} % | "
            f"{', '.join(f'{f} ← {k}' for f, k in d['relocalisations']) or '—'} | "
            f"{', '.join(f'{f}: ' + ('yes' if j else 'no') for f, j in d['new_maps']) or '—'} |"]
    if peer_seq:
        rows.append(
            f"| | ORB-SLAM3 ({len(ok)} runs) | {rng([r['ate_live'] for r in ok if r['ate_live'] is not None])} | "
            f"{rng([r['ate_final'] for r in ok if r['ate_final'] is not None])} | "
            f"{', '.join('%.1f %%' % (100 * r['tracked']) for r in ok if r['tracked'] is not None)} | | | |")
    print("\n".join(rows), flush=True)
    table += rows
with open(os.path.join(a.out, "table.md"), "w") as f:
    f.write("\n".join(table) + "\n")
with open(os.path.join(a.out, "results.json"), "w") as f:
    json.dump(results, f, indent=1)

#!/usr/bin/env python3
"""Maps that last (issue 43), on 7-Scenes Red Kitchen: a map saved from the first half of the
frames, loaded by a second run that only localises the second half in it — against one session
over all the frames (on the same second half) and against ORB-SLAM3's localisation mode
(`orb_localise.py`: it maps the first half and is switched to localisation for the second, in one
process, `--orb-runs` times: it is multi-threaded and not deterministic).

  maps.py --dwslam BIN --data DATA --venv VENV --out OUT [--orb-runs 3]

Rows: RGB-D (the 500 frames with a depth image: 250 mapped, 250 localised — frames 0–499 and
500–999 of the sequence) and mono (the 1000 colour frames: 500 and 500). dwslam runs
`--deterministic`, pinned to core 0; ORB-SLAM3 pinned to core 1. ATE RMSE by evo_ape -a (-s for
mono: Sim(3)) of the live poses of the localised frames. Also: the map's size against its
keyframes' features, save and load times, keyframes added while localising. Prints a Markdown
table and writes OUT/maps.json."""
import argparse, json, os, re, statistics, subprocess, time

ap = argparse.ArgumentParser()
ap.add_argument("--dwslam", required=True)
ap.add_argument("--data", required=True)
ap.add_argument("--venv", required=True)
ap.add_argument("--out", required=True)
ap.add_argument("--orb-runs", type=int, default=3)
a = ap.parse_args()
os.makedirs(a.out, exist_ok=True)
evo = os.path.join(a.venv, "bin", "evo_ape")
py = os.path.join(a.venv, "bin", "python")
here = os.path.dirname(os.path.abspath(__file__))
seq = os.path.join(a.data, "seven_scenes_redkitchen_1000")

CASES = [
    # name, sensor arguments, frames, split, Sim(3)
    ("7-Scenes RGB-D (500 frames with depth: 250 + 250)", ["--depth-frames-only"], 500, 250, False),
    ("7-Scenes mono (1000 colour frames: 500 + 500)", ["--sensor", "mono"], 1000, 500, True),
]


def ate(gt, est, sim3):
    p = subprocess.run([evo, "tum", gt, est, "-a", "--t_max_diff", "0.02"] + (["-s"] if sim3 else []),
                       capture_output=True, text=True)
    m = re.search(r"rmse\s+([0-9.eE+-]+)", p.stdout)
    return float(m.group(1)) if m else None


def tum_rows(path):
    return [l for l in open(path) if l.strip() and not l.startswith("#")]


def cut(src, dst, first_t):
    """The poses of `src` from time `first_t` on, into `dst`."""
    with open(dst, "w") as f:
        f.writelines(l for l in tum_rows(src) if float(l.split()[0]) >= first_t - 1e-6)
    return dst


def dwslam(args, out):
    cmd = ["taskset", "-c", "0", a.dwslam, "run", seq, *args, "--out", out, "--quiet", "--deterministic"]
    t0 = time.perf_counter()
    p = subprocess.run(cmd, capture_output=True, text=True)
    if p.returncode != 0:
        raise SystemExit(f"{' '.join(cmd)} failed:\n{p.stdout[-2000:]}{p.stderr[-2000:]}")
    return p.stdout, time.perf_counter() - t0


results = []
for name, sensor, frames, split, sim3 in CASES:
    tag = re.sub(r"\W+", "_", name.split("(")[0]).strip("_")
    base = os.path.join(a.out, tag)
    mapfile = base + ".map"
    r = {"name": name}
    # The mapping session, saved.
    dwslam(sensor + ["--max-frames", str(split), "--save-map", mapfile], base + "-map")
    s = json.load(open(os.path.join(base + "-map", "summary.json")))
    sm = s["saved_map"]
    r["map"] = {"bytes": sm["bytes"], "save_s": sm["seconds"], "keyframes": sm["holds"]["keyframes"],
                "points": sm["holds"]["points"], "bytes_by_part": sm["holds"]["bytes"]}
    # The localisation session.
    out, _ = dwslam(sensor + ["--start-frame", str(split), "--load-map", mapfile, "--localise"], base + "-loc")
    m = re.search(r"loaded map .* in ([0-9.]+) s", out)
    r["map"]["load_s"] = float(m.group(1)) if m else None
    s = json.load(open(os.path.join(base + "-loc", "summary.json")))
    gt = os.path.join(base + "-loc", "ground_truth.tum")
    loc = os.path.join(base + "-loc", "trajectory.tum")
    first_t = float(tum_rows(loc)[0].split()[0])
    rows = list(open(os.path.join(base + "-loc", "frames.csv")))[1:]
    tracked = sum(1 for l in rows if l.split(",")[1] in ("good", "weak"))
    r["dwslam_localised"] = {"ate": ate(gt, loc, sim3), "tracked": tracked / len(rows),
                             "keyframes_made": s["keyframes_made"],
                             "ms_tracking_median": statistics.median(float(l.split(",")[8]) for l in rows)}
    # One session over every frame, on the same second half.
    dwslam(sensor + ["--max-frames", str(frames)], base + "-one")
    one = cut(os.path.join(base + "-one", "trajectory.tum"), base + "-one-second-half.tum", first_t)
    r["dwslam_one_session"] = {"ate": ate(os.path.join(base + "-one", "ground_truth.tum"), one, sim3)}
    # ORB-SLAM3: mapping, then its localisation mode.
    orbs = []
    for run in range(a.orb_runs):
        o = f"{base}-orbslam3-{run}"
        p = subprocess.run(["taskset", "-c", "1", py, os.path.join(here, "orb_localise.py"),
                            "mono" if sim3 else "rgbd", a.data, o, "--split", str(split)],
                           capture_output=True, text=True)
        lines = [l for l in p.stdout.splitlines() if l.startswith("{")]
        if not lines:
            orbs.append({"error": (p.stdout + p.stderr)[-500:]})
            continue
        q = json.loads(lines[-1])
        q["ate"] = ate(gt, os.path.join(o, "localised.tum"), sim3) if tum_rows(os.path.join(o, "localised.tum")) else None
        orbs.append(q)
    r["orbslam3_localised"] = orbs
    results.append(r)
    json.dump(results, open(os.path.join(a.out, "maps.json"), "w"), indent=1)

cm = lambda x: "—" if x is None else f"{100 * x:.2f} cm"
print("| sequence | dwslam localised: ATE, tracked, keyframes added | one session, same frames | ORB-SLAM3 localisation mode: ATE best / median, tracked | map: MB (× features), save / load s |")
print("|---|---|---|---|---|")
for r in results:
    d, o = r["dwslam_localised"], [q for q in r["orbslam3_localised"] if q.get("ate") is not None]
    at = sorted(q["ate"] for q in o)
    orb = (f"{cm(at[0])} / {cm(statistics.median(at))}, "
           f"{min(q['tracked_localised'] for q in o):.0%}–{max(q['tracked_localised'] for q in o):.0%}") if o else "—"
    m = r["map"]
    print(f"| {r['name']} | {cm(d['ate'])}, {d['tracked']:.1%}, {d['keyframes_made']} | {cm(r['dwslam_one_session']['ate'])} "
          f"| {orb} | {m['bytes'] / 1e6:.1f} ({m['bytes'] / m['bytes_by_part']['features']:.2f}×), "
          f"{m['save_s']:.2f} / {m['load_s']} |")

#!/usr/bin/env python3
"""Bounded memory on revisits (issue 43, lifelong mapping): the rendered room browsed hand-held
for a long time (`dwslam demo --frames N`: the room rendered on the fly, RGB-D, exact ground
truth), with keyframe culling (the default), new points only beside the map's
(`keyframes.reuse_map_points: true`) and the points tracking no longer finds removed
(`keyframes.cull_points: true`); `--without`: also the defaults alone and no culling at all.

  lifelong.py --dwslam BIN --out OUT [--frames 30000] [--without] [--revisit-jitter 1]

The run is cut in four quarters of frames. Per quarter: keyframes and points in the map and the
process's resident memory at its end (summary.json `over_time`, sampled every 100 frames), the
mean time per frame (frames.csv `frame_ms`, the tracking thread's whole frame), the mean time of
a keyframe's pipeline in the tracking thread (`frame_ms` of the frames that became keyframes) and
of the double window optimisations that ran in it (optimisations.csv `total_ms`, in the order
they ran, attributed to quarters by their share of the run). The acceptance is last / first
quarter ≤ 1.1 for keyframes, memory and time per keyframe. Rendering shares the machine (it runs
a few frames ahead on its own thread), so only the system's own times are compared. Prints a
Markdown table and writes OUT/lifelong.json."""
import argparse, csv, json, os, subprocess, time

ap = argparse.ArgumentParser()
ap.add_argument("--dwslam", required=True)
ap.add_argument("--out", required=True)
ap.add_argument("--frames", type=int, default=30000)
ap.add_argument("--revisit-jitter", type=float, default=1.0)
ap.add_argument("--without", action="store_true", help="also run without culling")
a = ap.parse_args()
os.makedirs(a.out, exist_ok=True)


def run(name, config_text):
    out = os.path.join(a.out, name)
    cmd = [a.dwslam, "demo", "--frames", str(a.frames), "--quiet", "--out", out,
           "--revisit-jitter", str(a.revisit_jitter)]
    if config_text:
        path = os.path.join(a.out, name + ".yaml")
        with open(path, "w") as f:
            f.write(config_text)
        cmd += ["--config", path]
    t = time.time()
    p = subprocess.run(cmd, capture_output=True, text=True)
    if p.returncode != 0:
        raise SystemExit(f"{' '.join(cmd)} failed:\n{p.stdout}\n{p.stderr}")
    seconds = time.time() - t
    summary = json.load(open(os.path.join(out, "summary.json")))
    frames = list(csv.DictReader(open(os.path.join(out, "frames.csv"))))
    opts = list(csv.DictReader(open(os.path.join(out, "optimisations.csv"))))
    n = len(frames)
    quarters = []
    for q in range(4):
        lo, hi = q * n // 4, (q + 1) * n // 4
        rows = frames[lo:hi]
        kf = [float(r["frame_ms"]) for r in rows if r["keyframe"]]
        # Optimisations in the order they ran, spread over the run like the keyframes that
        # woke them: the quarter's share of them.
        o = opts[q * len(opts) // 4:(q + 1) * len(opts) // 4]
        sample = [s for s in summary["over_time"] if s["frames"] <= hi][-1]
        quarters.append({
            "frames": [lo, hi],
            "keyframes": sample["keyframes"],
            "points": sample["points"],
            "resident_mb": sample["resident_mb"],
            "keyframes_made": len(kf),
            "ms_per_frame": sum(float(r["frame_ms"]) for r in rows) / max(len(rows), 1),
            "ms_per_keyframe": sum(kf) / max(len(kf), 1),
            "dwo_ms": sum(float(r["total_ms"]) for r in o) / max(len(o), 1),
        })
    ate = summary.get("ate") or {}
    return {
        "name": name,
        "seconds": seconds,
        "keyframes_culled": summary.get("keyframes_culled"),
        "keyframes_made": summary.get("keyframes_made"),
        "summary_ate": {k: ate.get(k) for k in ("live", "final")} if isinstance(ate, dict) else ate,
        "quarters": quarters,
    }


runs = [run("lifelong", "keyframes:\n  reuse_map_points: true\n  cull_points: true\n")]
if a.without:
    runs.append(run("cull (defaults)", ""))
    runs.append(run("neither", "keyframes:\n  cull: false\n"))

ratio = lambda r, key: r["quarters"][3][key] / max(r["quarters"][0][key], 1e-9)
print(f"Rendered room, RGB-D, {a.frames} frames (revisit jitter {a.revisit_jitter}):\n")
print("| run | quarter | keyframes | points | resident MB | ms per frame | ms per keyframe (pipeline) | ms per DWO |")
print("|---|---|---|---|---|---|---|---|")
for r in runs:
    for i, q in enumerate(r["quarters"]):
        print(f"| {r['name']} | {i + 1} (frames {q['frames'][0]}–{q['frames'][1]}) | {q['keyframes']} | {q['points']} | "
              f"{q['resident_mb']:.0f} | {q['ms_per_frame']:.2f} | {q['ms_per_keyframe']:.1f} | {q['dwo_ms']:.1f} |")
print()
print("| run | culled | keyframes last/first | memory last/first | ms per keyframe last/first | ms per DWO last/first | ms per frame last/first |")
print("|---|---|---|---|---|---|---|")
for r in runs:
    r["ratios"] = {k: ratio(r, k) for k in ("keyframes", "resident_mb", "ms_per_keyframe", "dwo_ms", "ms_per_frame")}
    x = r["ratios"]
    print(f"| {r['name']} | {r['keyframes_culled']} of {r['keyframes_made']} | {x['keyframes']:.2f} | {x['resident_mb']:.2f} | "
          f"{x['ms_per_keyframe']:.2f} | {x['dwo_ms']:.2f} | {x['ms_per_frame']:.2f} |")
json.dump(runs, open(os.path.join(a.out, "lifelong.json"), "w"), indent=1)

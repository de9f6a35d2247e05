#!/usr/bin/env python3
"""Sessions of one place (issue 43): the rendered room browsed along three paths (`dwslam render
room --path-seed N`, the same world and textures), each session loading the last one's map and
saving its own (`dwslam run --load-map PREV --save-map NEXT --deterministic`, pinned to one core).
Reports per session: keyframes in the map at its end, keyframes made and culled, points, the
ATE live / after the run, whether it was relocalised in the loaded map, and how far the keyframes
it made are from the nearest keyframe of the map it loaded (camera centres in metres, viewing
directions in degrees, after the run): the keyframe criterion adds a keyframe 10 % of the scene
depth or 10° from every keyframe near the camera, so this says whether a path revisits the
loaded map's views or only its place. The issue's bar:
the third session's ATE no worse than the first's, keyframes growing by at most 10 % after the
first.

  sessions.py --dwslam BIN --out OUT [--frames 1500] [--sensor rgbd] [--jitter F] [--core 0]
              [--config CONFIG.yaml]

Renders go to OUT/room-<sensor>-path<N> and are reused when present."""
import argparse, csv, json, math, os, statistics, subprocess

ap = argparse.ArgumentParser()
ap.add_argument("--dwslam", required=True)
ap.add_argument("--out", required=True)
ap.add_argument("--frames", type=int, default=1500)
ap.add_argument("--sensor", default="rgbd", choices=["rgbd", "stereo", "mono"])
ap.add_argument("--jitter", type=float, help="--revisit-jitter of the renders (default: the browse's)")
ap.add_argument("--core", type=int, default=0)
ap.add_argument("--config", help="a dwslam config file for every session")
ap.add_argument("--paths", type=int, default=3)
a = ap.parse_args()
os.makedirs(a.out, exist_ok=True)


def tum(path):
    """`timestamp x y z qx qy qz qw` rows: (centre, unit quaternion)."""
    out = []
    for line in open(path):
        if line.startswith("#") or not line.strip():
            continue
        v = [float(x) for x in line.split()]
        out.append((v[1:4], v[4:8]))
    return out


def nearest(new, old):
    """For each pose of `new`, the distance to the nearest centre of `old` and the smallest
    rotation to an `old` pose (degrees; each on its own)."""
    dist, rot = [], []
    for c, q in new:
        dist.append(min(math.dist(c, c2) for c2, _ in old))
        rot.append(min(math.degrees(2 * math.acos(min(1.0, abs(sum(a * b for a, b in zip(q, q2))))))
                       for _, q2 in old))
    return dist, rot


def quartiles(xs):
    return statistics.quantiles(xs, n=4) if len(xs) >= 2 else [xs[0]] * 3 if xs else [float("nan")] * 3


def sh(cmd, log):
    with open(log, "w") as f:
        p = subprocess.run(cmd, stdout=f, stderr=subprocess.STDOUT)
    if p.returncode != 0:
        raise SystemExit(f"{' '.join(cmd)} failed: see {log}")


rows, previous, previous_out = [], None, None
for n in range(1, a.paths + 1):
    tag = f"room-{a.sensor}-path{n}" + (f"-jitter{a.jitter}" if a.jitter is not None else "")
    seq = os.path.join(a.out, tag)
    if not os.path.exists(os.path.join(seq, "done")):
        sh([a.dwslam, "render", "room", "--sensor", a.sensor, "--frames", str(a.frames), "--path-seed", str(n),
            *(["--revisit-jitter", str(a.jitter)] if a.jitter is not None else []), "--out", seq], seq + ".log")
        open(os.path.join(seq, "done"), "w").close()
    out = os.path.join(a.out, f"session{n}")
    mapfile = out + ".map"
    cmd = ["taskset", "-c", str(a.core), a.dwslam, "run", seq, "--sensor", a.sensor, "--deterministic", "--quiet",
           "--out", out, "--save-map", mapfile, *(["--load-map", previous] if previous else []),
           *(["--config", a.config] if a.config else [])]
    sh(cmd, out + ".log")
    s = json.load(open(os.path.join(out, "summary.json")))
    e = s["evaluation"]
    rows.append({
        "session": n,
        "keyframes": s["keyframes"],
        "keyframes_made": s.get("keyframes_made"),
        "keyframes_culled": s.get("keyframes_culled"),
        "points": s.get("points"),
        "ate_live_cm": e["live"]["ate_rmse_m"] * 100,
        "ate_final_cm": e["final"]["ate_rmse_m"] * 100,
        "relocalisations": len(s.get("relocalisations", [])),
        "frames_with_pose": s["frames_with_pose"],
        "frames": s["frames"],
    })
    if previous:
        frames = [int(r["frame"]) for r in csv.DictReader(open(os.path.join(out, "frames.csv"))) if r["keyframe"]]
        poses = tum(os.path.join(out, "trajectory_final.tum"))
        made = [poses[f] for f in frames if f < len(poses)]
        dist, rot = nearest(made, tum(os.path.join(previous_out, "keyframes.tum")))
        rows[-1]["new_keyframes_to_loaded_m"] = quartiles(dist)
        rows[-1]["new_keyframes_to_loaded_deg"] = quartiles(rot)
    previous, previous_out = mapfile, out
json.dump(rows, open(os.path.join(a.out, "sessions.json"), "w"), indent=1)
print("| session | keyframes in the map (made / culled) | points | ATE live / after | frames posed | relocalisations |")
print("|---|---|---|---|---|---|")
for r in rows:
    print(f"| {r['session']} | {r['keyframes']} ({r['keyframes_made']} / {r['keyframes_culled']}) | {r['points']} | "
          f"{r['ate_live_cm']:.2f} / {r['ate_final_cm']:.2f} cm | {r['frames_with_pose']} / {r['frames']} | "
          f"{r['relocalisations']} |")
if len(rows) > 1:
    print("\n| session | its keyframes to the nearest loaded keyframe: centre, m (quartiles) | rotation, ° (quartiles) |")
    print("|---|---|---|")
    for r in rows[1:]:
        m, d = r["new_keyframes_to_loaded_m"], r["new_keyframes_to_loaded_deg"]
        print(f"| {r['session']} | {m[0]:.3f} / {m[1]:.3f} / {m[2]:.3f} | {d[0]:.1f} / {d[1]:.1f} / {d[2]:.1f} |")
first, last = rows[0], rows[-1]
print(f"\nkeyframes after the first session: {first['keyframes']} -> {last['keyframes']} "
      f"({100 * (last['keyframes'] / first['keyframes'] - 1):+.1f} %); ATE after the run, last / first: "
      f"{last['ate_final_cm'] / first['ate_final_cm']:.2f}")

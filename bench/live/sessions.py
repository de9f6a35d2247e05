#!/usr/bin/env python3
"""Sessions of one place (issue 43): the rendered room browsed along three paths (`dwslam render
room --path-seed N`, the same world and textures), each session loading the last one's map and
saving its own (`dwslam run --load-map PREV --save-map NEXT --deterministic`, pinned to one core).
Reports per session: keyframes in the map at its end, keyframes made and culled, points, the
ATE live / after the run, and whether it was relocalised in the loaded map. The issue's bar:
the third session's ATE no worse than the first's, keyframes growing by at most 10 % after the
first.

  sessions.py --dwslam BIN --out OUT [--frames 1500] [--sensor rgbd] [--jitter F] [--core 0]
              [--config CONFIG.yaml]

Renders go to OUT/room-<sensor>-path<N> and are reused when present."""
import argparse, json, os, subprocess

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


def sh(cmd, log):
    with open(log, "w") as f:
        p = subprocess.run(cmd, stdout=f, stderr=subprocess.STDOUT)
    if p.returncode != 0:
        raise SystemExit(f"{' '.join(cmd)} failed: see {log}")


rows, previous = [], None
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
    previous = mapfile
json.dump(rows, open(os.path.join(a.out, "sessions.json"), "w"), indent=1)
print("| session | keyframes in the map (made / culled) | points | ATE live / after | frames posed | relocalisations |")
print("|---|---|---|---|---|---|")
for r in rows:
    print(f"| {r['session']} | {r['keyframes']} ({r['keyframes_made']} / {r['keyframes_culled']}) | {r['points']} | "
          f"{r['ate_live_cm']:.2f} / {r['ate_final_cm']:.2f} cm | {r['frames_with_pose']} / {r['frames']} | "
          f"{r['relocalisations']} |")
first, last = rows[0], rows[-1]
print(f"\nkeyframes after the first session: {first['keyframes']} -> {last['keyframes']} "
      f"({100 * (last['keyframes'] / first['keyframes'] - 1):+.1f} %); ATE after the run, last / first: "
      f"{last['ate_final_cm'] / first['ate_final_cm']:.2f}")

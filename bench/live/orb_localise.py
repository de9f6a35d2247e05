#!/usr/bin/env python3
"""ORB-SLAM3 (pyorbslam3) mapping the first frames of 7-Scenes Red Kitchen, then in its
localisation mode (`activate_localization_mode`: tracking only, no keyframe, no map point) for
the rest — the peer of `dwslam run --load-map MAP --localise` (bench/live/maps.py).

  orb_localise.py rgbd|mono DATA OUT --split N [--vocab FILE]

rgbd: the 500 frames with a depth image (associations.txt), mono: the 1000 colour frames
(rgb.txt). Writes OUT/localised.tum (the poses it returned for frames N.. while localising),
OUT/mapped.tum (those of frames ..N) and prints one JSON line: frames localised, tracked
fraction, ms per frame (median) in each phase, the keyframes of its map at the switch and at the
end (ORB-SLAM3's keyframe trajectory)."""
import argparse, json, os, statistics, sys, time
import numpy as np
import cv2
from scipy.spatial.transform import Rotation

ap = argparse.ArgumentParser()
ap.add_argument("mode", choices=["rgbd", "mono"])
ap.add_argument("data")
ap.add_argument("out")
ap.add_argument("--split", type=int, required=True)
ap.add_argument("--vocab", default=os.environ.get("ORB_VOCAB", os.path.expanduser(
    os.path.join(os.environ.get("LIVE_PEERS_VENV", "~/.cache/dwslam-live-peers"), "vocab/voc_k10L6.txt"))))
a = ap.parse_args()
os.makedirs(a.out, exist_ok=True)
seq = os.path.join(a.data, "seven_scenes_redkitchen_1000")
frames = []
if a.mode == "rgbd":
    for ln in open(os.path.join(seq, "associations.txt")):
        if ln.strip() and not ln.startswith("#"):
            t, rgb, _, dep = ln.split()
            frames.append((float(t), os.path.join(seq, rgb), os.path.join(seq, dep)))
else:
    for ln in open(os.path.join(seq, "rgb.txt")):
        if ln.strip() and not ln.startswith("#"):
            t, rgb = ln.split()[:2]
            frames.append((float(t), os.path.join(seq, rgb), None))

cfg = os.path.join(a.out, "orbslam3.yaml")
with open(cfg, "w") as y:
    y.write('%YAML:1.0\nCamera.type: "PinHole"\n')
    fps = 15.0 if a.mode == "rgbd" else 30.0
    for k, v in dict(fx=585.0, fy=585.0, cx=320.0, cy=240.0, k1=0.0, k2=0.0, p1=0.0, p2=0.0, fps=fps).items():
        y.write(f"Camera.{k}: {v:.6f}\n")
    y.write("Camera.width: 640\nCamera.height: 480\nCamera.RGB: 0\n")
    if a.mode == "rgbd":
        y.write("Camera.bf: 40.0\nThDepth: 40.0\nDepthMapFactor: 1000.0\n")
    y.write("ORBextractor.nFeatures: 1000\nORBextractor.scaleFactor: 1.2\nORBextractor.nLevels: 8\n"
            "ORBextractor.iniThFAST: 20\nORBextractor.minThFAST: 7\n")
    for k, v in dict(KeyFrameSize=0.05, KeyFrameLineWidth=1.0, GraphLineWidth=0.9, PointSize=2.0, CameraSize=0.08,
                     CameraLineWidth=3.0, ViewpointX=0.0, ViewpointY=-0.7, ViewpointZ=-1.8, ViewpointF=500.0).items():
        y.write(f"Viewer.{k}: {v}\n")


def write_tum(path, rows):
    with open(path, "w") as f:
        for t, T in rows:
            q = Rotation.from_matrix(T[:3, :3]).as_quat()
            f.write(f"{t:.6f} {T[0,3]:.7f} {T[1,3]:.7f} {T[2,3]:.7f} {q[0]:.7f} {q[1]:.7f} {q[2]:.7f} {q[3]:.7f}\n")


def keyframes(slam, name):
    path = os.path.join(a.out, name)
    try:
        slam.save_keyframe_trajectory_tum(path)
        return sum(1 for l in open(path) if l.strip())
    except Exception:
        return None


log = os.open(os.path.join(a.out, "orbslam3.log"), os.O_WRONLY | os.O_CREAT | os.O_TRUNC)
saved = os.dup(1)
os.dup2(log, 1)  # ORB-SLAM3's prints go to the log
import pyorbslam3 as pos
slam = pos.Slam(a.vocab, cfg, pos.Sensor.RGBD if a.mode == "rgbd" else pos.Sensor.MONOCULAR)
phases = {"mapped": [], "localised": []}
ms = {"mapped": [], "localised": []}
ok = {"mapped": [], "localised": []}
kf_at_switch = None
for i, (t, rgb, dep) in enumerate(frames):
    if i == a.split:
        kf_at_switch = keyframes(slam, "keyframes_at_switch.tum")
        slam.activate_localization_mode()
    phase = "mapped" if i < a.split else "localised"
    im = cv2.imread(rgb, cv2.IMREAD_UNCHANGED)
    t0 = time.perf_counter()
    if a.mode == "rgbd":
        d = cv2.imread(dep, cv2.IMREAD_UNCHANGED).astype(np.float32)
        d[d >= 65535] = 0
        r = slam.track_rgbd(im, d, t)
    else:
        r = slam.track_monocular(im, t)
    ms[phase].append(1e3 * (time.perf_counter() - t0))
    ok[phase].append(bool(r.ok))
    if r.ok:
        phases[phase].append((t, np.array(r.pose_wc)))
kf_end = keyframes(slam, "keyframes_end.tum")
slam.shutdown()
sys.stdout.flush()
os.dup2(saved, 1)
for phase, rows in phases.items():
    write_tum(os.path.join(a.out, f"{phase}.tum"), rows)
print(json.dumps({
    "frames_localised": len(ok["localised"]),
    "tracked_localised": sum(ok["localised"]) / max(len(ok["localised"]), 1),
    "tracked_mapped": sum(ok["mapped"]) / max(len(ok["mapped"]), 1),
    "ms_median_mapped": statistics.median(ms["mapped"]),
    "ms_median_localised": statistics.median(ms["localised"]),
    "keyframes_at_switch": kf_at_switch, "keyframes_end": kf_end,
}))

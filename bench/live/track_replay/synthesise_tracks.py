"""Replaces each corner track's measurements by the reprojection of its point triangulated from
the ground-truth poses: the same tracks, frames and lifetimes, positions exactly consistent
with the true motion (see README.md here).

Usage: synthesise_tracks.py DUMP OUT SEQUENCE_DIR
  DUMP: "frame track u v" per line (the DWSLAM_DUMP hook of scratch_hooks.patch)
  SEQUENCE_DIR: a KITTI odometry folder (calib.txt with P0, poses.txt of the left camera)
Tracks seen once, or whose point cannot be triangulated in front of every camera, keep their
measurements.
"""
import sys
import numpy as np
from replay_common import load_sequence, read_dump, triangulate

dump, out_path, seq = sys.argv[1:4]
(f, cx, cy), Tcw = load_sequence(seq)
out = open(out_path, 'w'); kept = repl = 0; rms = []
for t, obs in read_dump(dump).items():
    solved = triangulate(obs, (f, cx, cy), Tcw, 5) if len(obs) >= 2 else None
    zs = None
    if solved is not None:
        X, zs = solved[0], []
        for fr, u, v in obs:
            x = Tcw[fr][:3, :3] @ X + Tcw[fr][:3, 3]
            if x[2] <= 0.5: zs = None; break
            zs.append((fr, f * x[0] / x[2] + cx, f * x[1] / x[2] + cy))
    if zs is None:
        for fr, u, v in obs: out.write(f'{fr} {t} {u:.5f} {v:.5f}\n')
        kept += 1
    else:
        r = [np.hypot(a[1] - b[1], a[2] - b[2]) for a, b in zip(zs, obs)]; rms.append(np.sqrt(np.mean(np.square(r))))
        for fr, u, v in zs: out.write(f'{fr} {t} {u:.5f} {v:.5f}\n')
        repl += 1
print('tracks replaced', repl, 'kept', kept, 'median rms of the change px', np.median(rms))

"""Replaces each corner track's measurements by the reprojection of its point triangulated from
the ground-truth poses: the same tracks, frames and lifetimes, positions exactly consistent
with the true motion (see README.md here).

Usage: synthesise_tracks.py DUMP OUT SEQUENCE_DIR
  DUMP: "frame track u v" per line (the DWSLAM_DUMP hook of scratch_hooks.patch)
  SEQUENCE_DIR: a KITTI odometry folder (calib.txt with P0, poses.txt of the left camera)
Tracks seen once, or whose point cannot be triangulated in front of every camera, keep their
measurements.
"""
import numpy as np, collections, sys
dump, out_path, seq = sys.argv[1:4]
p0 = [l.split() for l in open(seq + '/calib.txt') if l.strip()][0]
p0 = [float(x) for x in (p0[1:] if p0[0].endswith(':') else p0)]
f, cx, cy = p0[0], p0[2], p0[6]
P = np.loadtxt(seq + '/poses.txt').reshape(-1, 3, 4)
Tcw = [np.linalg.inv(np.vstack([p, [0, 0, 0, 1]])) for p in P]
K = np.array([[f, 0, cx], [0, f, cy], [0, 0, 1]])
tr = collections.defaultdict(list)
for l in open(dump):
    fr, t, u, v = l.split(); tr[int(t)].append((int(fr), float(u), float(v)))
out = open(out_path, 'w'); kept = repl = 0; rms = []
for t, obs in tr.items():
    X = None
    if len(obs) >= 2:
        A = []
        for fr, u, v in obs:
            Pm = K @ Tcw[fr][:3]
            A.append(u * Pm[2] - Pm[0]); A.append(v * Pm[2] - Pm[1])
        _, _, Vt = np.linalg.svd(np.array(A))
        if abs(Vt[-1][3]) > 1e-12:
            X = Vt[-1][:3] / Vt[-1][3]
            # Gauss-Newton refinement of the point (pixel error)
            for _ in range(5):
                H = np.zeros((3, 3)); g = np.zeros(3)
                for fr, u, v in obs:
                    R, tt = Tcw[fr][:3, :3], Tcw[fr][:3, 3]; x = R @ X + tt
                    if x[2] <= 0: X = None; break
                    e = np.array([f * x[0] / x[2] + cx - u, f * x[1] / x[2] + cy - v])
                    J = np.array([[f / x[2], 0, -f * x[0] / x[2] ** 2], [0, f / x[2], -f * x[1] / x[2] ** 2]]) @ R
                    H += J.T @ J; g += J.T @ e
                if X is None: break
                X = X - np.linalg.solve(H + 1e-9 * np.eye(3), g)
    zs = []
    if X is not None:
        for fr, u, v in obs:
            x = Tcw[fr][:3, :3] @ X + Tcw[fr][:3, 3]
            if x[2] <= 0.5: zs = None; break
            zs.append((fr, f * x[0] / x[2] + cx, f * x[1] / x[2] + cy))
    if X is None or zs is None:
        for fr, u, v in obs: out.write(f'{fr} {t} {u:.5f} {v:.5f}\n')
        kept += 1
    else:
        r = [np.hypot(a[1] - b[1], a[2] - b[2]) for a, b in zip(zs, obs)]; rms.append(np.sqrt(np.mean(np.square(r))))
        for fr, u, v in zs: out.write(f'{fr} {t} {u:.5f} {v:.5f}\n')
        repl += 1
print('tracks replaced', repl, 'kept', kept, 'median rms of the change px', np.median(rms))

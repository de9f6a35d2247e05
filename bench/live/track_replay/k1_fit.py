"""With the ground-truth poses fixed, which radial term k1 of the measurements best explains a
dump of corner tracks (see README.md here)? For each k1: the measurements moved by 1 + k1·r²
(r in normalised coordinates about the principal point), each track of five frames or more
triangulated (linear, then Gauss-Newton), its squared reprojection errors capped at 9 px²;
prints their mean and median over the tracks. The ground truth fixes the scale, so depth and
a radial term are no longer confounded as in the estimate.

Usage: SEQ=SEQUENCE_DIR k1_fit.py DUMP K1 [K1 ...]
"""
import numpy as np, collections, sys
import os
seq = os.environ['SEQ']
p0 = [l.split() for l in open(seq + '/calib.txt') if l.strip()][0]
p0 = [float(x) for x in (p0[1:] if p0[0].endswith(':') else p0)]
f, cx, cy = p0[0], p0[2], p0[6]
P = np.loadtxt(seq + '/poses.txt').reshape(-1, 3, 4)
Tcw = [np.linalg.inv(np.vstack([p, [0, 0, 0, 1]])) for p in P]
K = np.array([[f, 0, cx], [0, f, cy], [0, 0, 1]])
Pm = [K @ T[:3] for T in Tcw]
tr = collections.defaultdict(list)
for l in open(sys.argv[1]):
    fr, t, u, v = l.split(); tr[int(t)].append((int(fr), float(u), float(v)))
tracks = [np.array(o) for o in tr.values() if len(o) >= 5]
print('tracks', len(tracks))
for k1 in [float(x) for x in sys.argv[2:]]:
    cost = []; 
    for o in tracks:
        fr = o[:, 0].astype(int); u = o[:, 1]; v = o[:, 2]
        x, y = (u - cx) / f, (v - cy) / f; g = 1 + k1 * (x * x + y * y)
        u2, v2 = cx + (u - cx) * g, cy + (v - cy) * g
        A = np.concatenate([u2[:, None] * np.array([Pm[i][2] for i in fr]) - np.array([Pm[i][0] for i in fr]),
                            v2[:, None] * np.array([Pm[i][2] for i in fr]) - np.array([Pm[i][1] for i in fr])])
        _, _, Vt = np.linalg.svd(A); X = Vt[-1]
        if abs(X[3]) < 1e-12: continue
        X = X[:3] / X[3]
        for _ in range(3):  # GN on pixel error
            H = np.zeros((3, 3)); gr = np.zeros(3); ok = True; rs = []
            for i, a, b in zip(fr, u2, v2):
                R, t = Tcw[i][:3, :3], Tcw[i][:3, 3]; q = R @ X + t
                if q[2] <= 0: ok = False; break
                e = np.array([f * q[0] / q[2] + cx - a, f * q[1] / q[2] + cy - b])
                J = np.array([[f / q[2], 0, -f * q[0] / q[2] ** 2], [0, f / q[2], -f * q[1] / q[2] ** 2]]) @ R
                H += J.T @ J; gr += J.T @ e; rs.append(e)
            if not ok: break
            X = X - np.linalg.solve(H + 1e-9 * np.eye(3), gr)
        if not ok: continue
        rs = np.array(rs); cost.append(np.minimum((rs ** 2).sum(1), 9.0).mean())
    print(f'k1 {k1:+.3f}: tracks {len(cost)} mean capped squared error {np.mean(cost):.4f} px^2, median {np.median(cost):.4f}')

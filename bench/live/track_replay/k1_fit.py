"""With the ground-truth poses fixed, which radial term k1 of the measurements best explains a
dump of corner tracks (see README.md here)? For each k1: the measurements moved by 1 + k1·r²
(r in normalised coordinates about the principal point), each track of five frames or more
triangulated (linear, then Gauss-Newton), its squared reprojection errors capped at 9 px²;
prints their mean and median over the tracks. The ground truth fixes the scale, so depth and
a radial term are no longer confounded as in the estimate.

Usage: SEQ=SEQUENCE_DIR k1_fit.py DUMP K1 [K1 ...]
"""
import os, sys
import numpy as np
from replay_common import load_sequence, read_dump, triangulate

(f, cx, cy), Tcw = load_sequence(os.environ['SEQ'])
tracks = [np.array(o) for o in read_dump(sys.argv[1]).values() if len(o) >= 5]
print('tracks', len(tracks))
for k1 in [float(x) for x in sys.argv[2:]]:
    cost = []
    for o in tracks:
        fr = o[:, 0].astype(int); u = o[:, 1]; v = o[:, 2]
        x, y = (u - cx) / f, (v - cy) / f; g = 1 + k1 * (x * x + y * y)
        solved = triangulate(list(zip(fr, cx + (u - cx) * g, cy + (v - cy) * g)), (f, cx, cy), Tcw, 3)
        if solved is None: continue
        rs = solved[1]; cost.append(np.minimum((rs ** 2).sum(1), 9.0).mean())
    print(f'k1 {k1:+.3f}: tracks {len(cost)} mean capped squared error {np.mean(cost):.4f} px^2, median {np.median(cost):.4f}')

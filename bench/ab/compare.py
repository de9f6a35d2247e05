#!/usr/bin/env python3
"""bench/ab/compare.py TAG_A TAG_B [names...]: for each run captured by capture.py under both tags,
the largest position difference between the two builds' live and final trajectories (m; and the
pose counts when they differ), their keyframe and point counts and their ATE."""
import sys, os, json, glob, math
A, B = sys.argv[1], sys.argv[2]
root = os.environ.get("AB_OUT", "/tmp/dwslam-ab")
names = sys.argv[3:] or sorted(os.listdir(os.path.join(root, A)))
def tum(p):
    if not os.path.exists(p): return None
    d = {}
    for l in open(p):
        if l.startswith('#') or not l.strip(): continue
        v = l.split(); d[round(float(v[0]), 6)] = tuple(map(float, v[1:8]))
    return d
def diff(a, b):
    if a is None or b is None: return "missing" if (a is None) != (b is None) else "-"
    common = set(a) & set(b)
    m = max((math.dist(a[t][:3], b[t][:3]) for t in common), default=0.0)
    s = f"{m:.2e}"
    if len(a) != len(b) or len(common) != len(a): s += f" n={len(a)}/{len(b)}"
    return s
for n in names:
    pa, pb = os.path.join(root, A, n), os.path.join(root, B, n)
    if not os.path.isdir(pb) or not os.path.isdir(pa):
        print(f"{n:34s} missing"); continue
    sa, sb = json.load(open(os.path.join(pa, "summary.json"))), json.load(open(os.path.join(pb, "summary.json")))
    live = diff(tum(os.path.join(pa, "trajectory.tum")), tum(os.path.join(pb, "trajectory.tum")))
    fin = diff(tum(os.path.join(pa, "trajectory_final.tum")), tum(os.path.join(pb, "trajectory_final.tum")))
    alts = []
    for f in sorted(glob.glob(os.path.join(pa, "trajectory_final_*.tum"))):
        alts.append(os.path.basename(f)[17:-4] + "=" + diff(tum(f), tum(os.path.join(pb, os.path.basename(f)))))
    kf = f"{sa.get('keyframes')}/{sb.get('keyframes')}"
    pts = f"{sa.get('points')}/{sb.get('points')}"
    ev = lambda s, k: s.get('evaluation', {}).get(k, {}).get('ate_rmse_m')
    ate = " ".join(f"{k}:{(ev(sa,k) or 0)*100:.3f}/{(ev(sb,k) or 0)*100:.3f}cm" for k in ("live", "final") if ev(sa,k) is not None or ev(sb,k) is not None)
    print(f"{n:34s} live {live:12s} final {fin:12s} {' '.join(alts)} kf {kf} pts {pts} {ate}")

#!/usr/bin/env python3
"""Side-by-side comparison of dwslam's `vision` crate with OpenCV on the same images, both
single-threaded (cv2.setNumThreads(1); our driver is single-threaded, RAYON_NUM_THREADS=1).

Called by run.sh. Speed is reported as ratio ours/OpenCV measured in the same run; accuracy as
the same metric computed for both. Writes a Markdown section to --out.
"""
import argparse, glob, json, os, subprocess, sys, tempfile, time

import cv2
import numpy as np

cv2.setNumThreads(1)

ap = argparse.ArgumentParser()
ap.add_argument("--bin", required=True)
ap.add_argument("--data", required=True)
ap.add_argument("--out", required=True)
ap.add_argument("--rust-log", default=None, help="output of the ignored real-data tests")
args = ap.parse_args()
BIN, DATA = args.bin, args.data
TMP = tempfile.mkdtemp(prefix="vision-bench-")


def ours(*a):
    out = subprocess.check_output([BIN, *map(str, a)], env={**os.environ, "RAYON_NUM_THREADS": "1"})
    return json.loads(out)


def timed(f, min_reps=5, budget=1.0):
    """Mean CPU time (thread clock) per call in ms over >= min_reps calls and >= budget s of CPU
    time (as our driver measures), robust to other processes competing for the cores."""
    c0, reps, r = time.thread_time(), 0, None
    while True:
        r = f()
        reps += 1
        spent = time.thread_time() - c0
        if reps >= min_reps and (min_reps <= 1 or spent >= budget or reps >= 500):
            return spent * 1e3 / reps, r


lines = []
def out(s=""):
    print(s)
    lines.append(s)

euroc = sorted(glob.glob(f"{DATA}/euroc_v1_01_easy_micro/mav0/cam0/data/*.png"))
if not euroc:
    sys.exit(f"no EuRoC frames under {DATA}")
frames = euroc[20:30]

out("## vision vs OpenCV " + cv2.__version__ + " (single-threaded, same run)")
out()
out(f"Machine: {os.cpu_count()} cores; frames: EuRoC V1_01 cam0 752×480, frames 20–29 (median of per-frame medians).")
out()

# --- FAST agreement and pyramid+FAST speed -------------------------------------------------
out("### FAST-9 corners (level 0, non-max suppression)")
out()
out("| threshold | OpenCV corners | ours | identical (of OpenCV's) | identical (of ours) |")
out("|---|---|---|---|---|")
for t in (10, 20, 40):
    n_o = n_u = n_c = 0
    fast = cv2.FastFeatureDetector_create(t, True, cv2.FAST_FEATURE_DETECTOR_TYPE_9_16)
    for f in frames:
        img = cv2.imread(f, 0)
        o = {(int(k.pt[0]), int(k.pt[1])) for k in fast.detect(img)}
        u = {(int(x), int(y)) for x, y in ours("fast", f, t)["corners"]}
        n_o += len(o); n_u += len(u); n_c += len(o & u)
    out(f"| {t} | {n_o} | {n_u} | {100*n_c/max(n_o,1):.2f} % | {100*n_c/max(n_u,1):.2f} % |")
out()

speed = []
fast20 = cv2.FastFeatureDetector_create(20, True, cv2.FAST_FEATURE_DETECTOR_TYPE_9_16)
def ocv_pyrfast(img):
    p = img
    n = []
    for _ in range(4):
        n.append(len(fast20.detect(p)))
        p = cv2.pyrDown(p)
    return n
t_o, t_u = [], []
for f in frames:
    img = cv2.imread(f, 0)
    t_o.append(timed(lambda: ocv_pyrfast(img))[0])
    t_u.append(ours("pyrfast", f, 20, 4)["ms"])
speed.append(("pyramid (4 levels) + FAST-9 t=20 + NMS", np.median(t_u), np.median(t_o),
              "OpenCV: cv2.pyrDown (5×5 Gaussian) + FastFeatureDetector; ours: 2×2 half-sampling + fast9"))

orb = cv2.ORB_create(500)
t_o, t_u = [], []
for f in frames:
    img = cv2.imread(f, 0)
    t_o.append(timed(lambda: orb.detectAndCompute(img, None))[0])
    t_u.append(ours("orb", f, 500)["ms"])
speed.append(("ORB, 500 features, 8 levels × 1.2", np.median(t_u), np.median(t_o), "detect + describe"))

# --- LK ------------------------------------------------------------------------------------
def lk_compare(pairs, label, timing):
    diffs, t_o, t_u, n_o, n_u, n_both = [], [], [], 0, 0, 0
    for a, b in pairs:
        ia, ib = cv2.imread(a, 0), cv2.imread(b, 0)
        pts = cv2.goodFeaturesToTrack(ia, 500, 0.01, 10)
        pf = os.path.join(TMP, "pts.txt")
        np.savetxt(pf, pts.reshape(-1, 2))
        f = lambda: cv2.calcOpticalFlowPyrLK(ia, ib, pts, None, winSize=(21, 21), maxLevel=3)
        ms, (nxt, st, _) = timed(f)
        r = ours("lk", a, b, pf, 4)
        t_o.append(ms); t_u.append(r["ms"])
        for i, tr in enumerate(r["tracks"]):
            ok_o = st[i, 0] == 1
            n_o += ok_o; n_u += tr is not None
            if ok_o and tr is not None:
                n_both += 1
                diffs.append(np.hypot(tr[0] - nxt[i, 0, 0], tr[1] - nxt[i, 0, 1]))
    d = np.array(diffs)
    if timing:
        speed.append(("pyramidal LK, 21×21, 4 levels, ~500 points (incl. both pyramids)", np.median(t_u), np.median(t_o), "inverse compositional vs OpenCV's"))
    return (label, len(pairs), n_o, n_u, n_both, np.median(d), np.percentile(d, 90), np.mean(d < 0.1) * 100)

lk_rows = [lk_compare(list(zip(euroc[20:29], euroc[21:30])), "EuRoC V1_01 cam0 frames 20–29 (static MAV)", True)]
kitti = sorted(glob.glob(f"{DATA}/kitti_odometry_snippets/KITTI_sequence_1/image_l/*.png"))
if len(kitti) > 10:
    lk_rows.append(lk_compare(list(zip(kitti[0:9], kitti[1:10])), "KITTI snippet frames 0–9 (driving)", False))
ss = sorted(glob.glob(f"{DATA}/seven_scenes_redkitchen_1000/rgb/*.jpg"))
if len(ss) > 110:
    lk_rows.append(lk_compare(list(zip(ss[100:109], ss[101:110])), "7-Scenes frames 100–109 (hand-held)", False))

out("### Speed (CPU ms per call, mean over ≥ 1 s of CPU time, median over frames; ratio = ours / OpenCV)")
out()
out("| operation | ours | OpenCV | ratio | note |")
out("|---|---|---|---|---|")
for name, u, o, note in speed:
    out(f"| {name} | {u:.2f} | {o:.2f} | **{u/o:.2f}** | {note} |")
out()

out("### Pyramidal LK agreement (same input points from cv2.goodFeaturesToTrack)")
out()
out("| sequence | pairs | OpenCV tracked | ours tracked | both | median ‖ours − OpenCV‖ px | 90th pct | < 0.1 px |")
out("|---|---|---|---|---|---|---|---|")
for r in lk_rows:
    out(f"| {r[0]} | {r[1]} | {r[2]} | {r[3]} | {r[4]} | {r[5]:.4f} | {r[6]:.4f} | {r[7]:.1f} % |")
out()

# --- Stereo --------------------------------------------------------------------------------
def read_gt(path, scale):
    g = cv2.imread(path, cv2.IMREAD_UNCHANGED)
    if g.ndim == 3:
        g = g[:, :, 0]
    return g.astype(np.float32) / scale

def nonocc(gt):
    h, w = gt.shape
    mask = np.zeros_like(gt, dtype=bool)
    for y in range(h):
        z = np.full(w, -np.inf, np.float32)
        xs = np.arange(w)
        d = gt[y]
        xr = np.round(xs - d).astype(int)
        ok = (d > 0) & (xr >= 0)
        for x in xs[ok]:
            z[xr[x]] = max(z[xr[x]], d[x])
        mask[y, ok] = d[ok] >= z[xr[ok]] - 1.0
    return mask

def bad_rate(disp, gt, mask):
    valid = np.isfinite(disp)
    err = np.abs(np.where(valid, disp, 0) - gt)
    bad = (~valid | (err > 1.0)) & mask
    return bad.sum() / mask.sum(), (valid & mask).sum() / mask.sum(), ((err > 1.0) & valid & mask).sum() / max((valid & mask).sum(), 1)

out("### Stereo block matching on Middlebury (bad pixels: |d − gt| > 1 px over non-occluded pixels)")
out()
out("The Middlebury copy has no nonocc masks: a pixel counts as non-occluded if its left ground truth is known,")
out("it maps inside the right image, and no other pixel of its row maps to the same right pixel with a disparity")
out("larger by more than 1 px (forward-warping visibility test). Invalid (unmatched) pixels count as bad;")
out("the error among valid pixels and the density are listed too. Matched settings: same disparity range")
out("(OpenCV numDisparities = ours max+1), same 9×9 block; other OpenCV parameters at their defaults.")
out()
out("| scene | method | bad (invalid = bad) | density | bad among valid | ms |")
out("|---|---|---|---|---|---|")
for name, l, r, g, scale, nd in [("tsukuba", "im3.png", "im4.png", "disp3.pgm", 16, 16),
                                   ("venus", "im2.png", "im6.png", "disp2.pgm", 8, 32),
                                   ("teddy", "im2.png", "im6.png", "disp2.png", 4, 64)]:
    d = f"{DATA}/middlebury_stereo/{name}"
    L, R = cv2.imread(f"{d}/{l}", 0), cv2.imread(f"{d}/{r}", 0)
    gt = read_gt(f"{d}/{g}", scale)
    mask = nonocc(gt)
    bm = cv2.StereoBM_create(numDisparities=nd, blockSize=9)
    ms_bm, dbm = timed(lambda: bm.compute(L, R))
    dbm = dbm.astype(np.float32) / 16.0
    dbm[dbm < 0] = np.nan
    sg = cv2.StereoSGBM_create(0, nd, 9, P1=8 * 81, P2=32 * 81, uniquenessRatio=10)
    ms_sg, dsg = timed(lambda: sg.compute(L, R), min_reps=3)
    dsg = dsg.astype(np.float32) / 16.0
    dsg[dsg < 0] = np.nan
    of = os.path.join(TMP, f"{name}.f32")
    r_ = ours("stereo", f"{d}/{l}", f"{d}/{r}", nd - 1, 9, of)
    du = np.fromfile(of, np.float32).reshape(r_["height"], r_["width"])
    for meth, disp, ms in [("ours (census 7×7, SAD of Hamming 9×9, LR check)", du, r_["ms"]),
                           ("OpenCV StereoBM", dbm, ms_bm), ("OpenCV StereoSGBM (reference)", dsg, ms_sg)]:
        b, dens, bv = bad_rate(disp, gt, mask)
        out(f"| {name} | {meth} | {100*b:.1f} % | {100*dens:.1f} % | {100*bv:.1f} % | {ms:.1f} |")
out()

# --- Flow ----------------------------------------------------------------------------------
out("### Dense flow: our TV-L1 (Chambolle-Pock) vs OpenCV Farnebäck")
out()
out("opencv-python-headless has no DualTVL1 (contrib); Farnebäck is the peer. Accuracy on a synthetic warp of a")
out("real 640×480 frame (7-Scenes frame 100 remapped by a known smooth flow: 1.5° rotation about the centre plus")
out("(2.0, −1.2) px), endpoint error over pixels whose source lies inside the image.")
out()
img = cv2.imread(ss[100], 0) if ss else cv2.imread(euroc[20], 0)
h, w = img.shape
yy, xx = np.mgrid[0:h, 0:w].astype(np.float32)
a = np.deg2rad(1.5)
cx, cy = (w - 1) / 2, (h - 1) / 2
# flow of pixel x of image 0: x1 = R (x − c) + c + t
fx = np.cos(a) * (xx - cx) - np.sin(a) * (yy - cy) + cx + 2.0 - xx
fy = np.sin(a) * (xx - cx) + np.cos(a) * (yy - cy) + cy - 1.2 - yy
# image 1 samples image 0 at the inverse map: I1(x1) = I0(x)
ia_ = -a
ix = np.cos(ia_) * (xx - cx - 2.0) - np.sin(ia_) * (yy - cy + 1.2) + cx
iy = np.sin(ia_) * (xx - cx - 2.0) + np.cos(ia_) * (yy - cy + 1.2) + cy
img1 = cv2.remap(img, ix.astype(np.float32), iy.astype(np.float32), cv2.INTER_LINEAR, borderMode=cv2.BORDER_REPLICATE)
p0, p1 = os.path.join(TMP, "f0.png"), os.path.join(TMP, "f1.png")
cv2.imwrite(p0, img); cv2.imwrite(p1, img1)
inside = (xx + fx >= 2) & (xx + fx <= w - 3) & (yy + fy >= 2) & (yy + fy <= h - 3)
ms_fb, ff = timed(lambda: cv2.calcOpticalFlowFarneback(img, img1, None, 0.5, 5, 15, 3, 5, 1.2, 0), min_reps=3)
r_ = ours("tvl1", p0, p1, os.path.join(TMP, "flow"))
du = np.fromfile(os.path.join(TMP, "flow.du"), np.float32).reshape(h, w)
dv = np.fromfile(os.path.join(TMP, "flow.dv"), np.float32).reshape(h, w)
epe_u = np.hypot(du - fx, dv - fy)[inside]
epe_f = np.hypot(ff[..., 0] - fx, ff[..., 1] - fy)[inside]
out("| method | mean EPE px | median EPE px | ms (640×480) |")
out("|---|---|---|---|")
out(f"| ours TV-L1 (λ 0.15, 5 levels, 5 warps × 50 iterations) | {epe_u.mean():.3f} | {np.median(epe_u):.3f} | {r_['ms']:.0f} |")
out(f"| OpenCV Farnebäck (0.5, 5 levels, win 15) | {epe_f.mean():.3f} | {np.median(epe_f):.3f} | {ms_fb:.0f} |")
out()

if args.rust_log and os.path.exists(args.rust_log):
    out("### Dense alignment and place recognition (Rust real-data tests, `--ignored`)")
    out()
    out("```")
    for l in open(args.rust_log):
        if l.startswith(("pair ", "EuRoC left", "7-Scenes", "vocabulary", "tsukuba", "venus", "teddy", "test ")):
            out(l.rstrip())
    out("```")
    out()

with open(args.out, "w") as f:
    f.write("\n".join(lines) + "\n")
print(f"wrote {args.out}")

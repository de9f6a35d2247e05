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
ap.add_argument("--budget", type=float, default=1.0,
                help="CPU seconds per timed measurement (both sides; 1.0 for recorded runs)")
ap.add_argument("--ref-bin", default=None,
                help="a vision_bench built from the code before a change: FAST, LK and stereo are compared to it")
ap.add_argument("--only", default="", help="comma-separated subset of: fast,speed,lk,stereo,flow")
args = ap.parse_args()
ONLY = set(filter(None, args.only.split(",")))
def want(part):
    return not ONLY or part in ONLY
BIN, DATA = args.bin, args.data
TMP = tempfile.mkdtemp(prefix="vision-bench-")


def ours(*a):
    env = {**os.environ, "RAYON_NUM_THREADS": "1", "VISION_BENCH_BUDGET": str(args.budget)}
    out = subprocess.check_output([BIN, *map(str, a)], env=env)
    return json.loads(out)


REF = args.ref_bin


def ours_ref(*a):
    env = {**os.environ, "RAYON_NUM_THREADS": "1", "VISION_BENCH_BUDGET": "0"}
    return json.loads(subprocess.check_output([REF, *map(str, a)], env=env))


def timed(f, min_reps=5, budget=None):
    """Mean CPU time (thread clock) per call in ms over >= min_reps calls and >= budget s of CPU
    time (as our driver measures), robust to other processes competing for the cores."""
    budget = args.budget if budget is None else budget
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
kitti = sorted(glob.glob(f"{DATA}/kitti_odometry_snippets/KITTI_sequence_1/image_l/*.png"))
ss = sorted(glob.glob(f"{DATA}/seven_scenes_redkitchen_1000/rgb/*.jpg"))
if not euroc or len(kitti) < 10 or len(ss) < 110:
    sys.exit(f"EuRoC, KITTI or 7-Scenes frames missing under {DATA}")


def grey_copies(paths, tag):
    """Both sides read the same 8-bit grey pixels: OpenCV's grey conversion written as PNG (our
    JPEG decoder and colour conversion differ from OpenCV's by a grey level here and there)."""
    outp = []
    for i, p in enumerate(paths):
        q = os.path.join(TMP, f"{tag}_{i:02d}.png")
        cv2.imwrite(q, cv2.imread(p, 0))
        outp.append(q)
    return outp


DATASETS = [("EuRoC V1_01 cam0 752×480, frames 20–29 (static MAV)", "EuRoC", grey_copies(euroc[20:30], "euroc")),
            ("KITTI snippet 1226×370, frames 0–9 (driving)", "KITTI", grey_copies(kitti[0:10], "kitti")),
            ("7-Scenes redkitchen 640×480, frames 100–109 (hand-held)", "7-Scenes", grey_copies(ss[100:110], "7scenes"))]

out("## vision vs OpenCV " + cv2.__version__ + " (single-threaded, same run)")
out()
out(f"Machine: {os.cpu_count()} cores; frames: " + "; ".join(d[0] for d in DATASETS) + ".")
if REF:
    out(f"`before` = the reference driver `{os.path.basename(REF)}` (the code before this change), run on the same frames.")
out()

# --- FAST agreement ------------------------------------------------------------------------
if want("fast"):
    out("### FAST-9 corners (level 0, non-max suppression)")
    out()
    out("| frames | threshold | OpenCV corners | ours | identical (of OpenCV's) | identical (of ours) |"
        + (" identical to before |" if REF else ""))
    out("|---|---|---|---|---|---|" + ("---|" if REF else ""))
    for _, short, frames in DATASETS:
        for t in (10, 20, 40):
            n_o = n_u = n_c = 0
            same_ref = True
            fast = cv2.FastFeatureDetector_create(t, True, cv2.FAST_FEATURE_DETECTOR_TYPE_9_16)
            for f in frames:
                img = cv2.imread(f, 0)
                o = {(int(k.pt[0]), int(k.pt[1])) for k in fast.detect(img)}
                cu = ours("fast", f, t)["corners"]
                u = {(int(x), int(y)) for x, y in cu}
                if REF:
                    same_ref &= cu == ours_ref("fast", f, t)["corners"]
                n_o += len(o); n_u += len(u); n_c += len(o & u)
            out(f"| {short} | {t} | {n_o} | {n_u} | {100*n_c/max(n_o,1):.2f} % | {100*n_c/max(n_u,1):.2f} % |"
                + ((" yes |" if same_ref else " **no** |") if REF else ""))
    out()

# --- speed: pyramid + FAST, ORB, LK on each data set ----------------------------------------
fast20 = cv2.FastFeatureDetector_create(20, True, cv2.FAST_FEATURE_DETECTOR_TYPE_9_16)
def ocv_pyrfast(img):
    p = img
    n = []
    for _ in range(4):
        n.append(len(fast20.detect(p)))
        p = cv2.pyrDown(p)
    return n
orb = cv2.ORB_create(500)

speed = []
lk_rows = []
def lk_compare(pairs, label, short):
    diffs, ref_diffs, t_o, t_u, n_o, n_u, n_both = [], [], [], [], 0, 0, 0
    for a, b in pairs:
        ia, ib = cv2.imread(a, 0), cv2.imread(b, 0)
        pts = cv2.goodFeaturesToTrack(ia, 500, 0.01, 10)
        pf = os.path.join(TMP, "pts.txt")
        np.savetxt(pf, pts.reshape(-1, 2))
        f = lambda: cv2.calcOpticalFlowPyrLK(ia, ib, pts, None, winSize=(21, 21), maxLevel=3)
        ms, (nxt, st, _) = timed(f)
        r = ours("lk", a, b, pf, 4)
        if REF:
            rr = ours_ref("lk", a, b, pf, 4)
            for tr, tq in zip(r["tracks"], rr["tracks"]):
                if (tr is None) != (tq is None):
                    ref_diffs.append(np.inf)
                elif tr is not None:
                    ref_diffs.append(np.hypot(tr[0] - tq[0], tr[1] - tq[1]))
        t_o.append(ms); t_u.append(r["ms"])
        for i, tr in enumerate(r["tracks"]):
            ok_o = st[i, 0] == 1
            n_o += ok_o; n_u += tr is not None
            if ok_o and tr is not None:
                n_both += 1
                diffs.append(np.hypot(tr[0] - nxt[i, 0, 0], tr[1] - nxt[i, 0, 1]))
    d = np.array(diffs)
    speed.append(("pyramidal LK, 21×21, 4 levels, ~500 points (incl. both pyramids)", short,
                  np.median(t_u), np.median(t_o), "inverse compositional vs OpenCV's"))
    rd = np.array(ref_diffs) if REF else None
    lk_rows.append((label, len(pairs), n_o, n_u, n_both, np.median(d), np.percentile(d, 90),
                    np.mean(d < 0.1) * 100, rd))

if want("speed") or want("lk"):
    for label, short, frames in DATASETS:
        if want("speed"):
            t_o, t_u = [], []
            for f in frames:
                img = cv2.imread(f, 0)
                t_o.append(timed(lambda: ocv_pyrfast(img))[0])
                t_u.append(ours("pyrfast", f, 20, 4)["ms"])
            speed.append(("pyramid (4 levels) + FAST-9 t=20 + NMS", short, np.median(t_u), np.median(t_o),
                          "OpenCV: cv2.pyrDown (5×5 Gaussian) + FastFeatureDetector; ours: 2×2 half-sampling + fast9"))
            t_o, t_u, same = [], [], True
            for f in frames:
                img = cv2.imread(f, 0)
                t_o.append(timed(lambda: orb.detectAndCompute(img, None))[0])
                r = ours("orb", f, 500)
                t_u.append(r["ms"])
                if REF:
                    same &= r["digest"] == ours_ref("orb", f, 500)["digest"]
            speed.append(("ORB, 500 features, 8 levels × 1.2", short, np.median(t_u), np.median(t_o),
                          "detect + describe" + ((", keypoints and descriptors identical to before" if same
                                                  else ", **results differ from before**") if REF else "")))
        lk_compare(list(zip(frames[0:9], frames[1:10])), label, short)

    out("### Speed (CPU ms per call, mean over ≥ budget s of CPU time per frame, median over frames; ratio = ours / OpenCV)")
    out()
    out(f"Budget {args.budget} s of CPU time per frame and side.")
    out()
    out("| operation | frames | ours | OpenCV | ratio | note |")
    out("|---|---|---|---|---|---|")
    for name, short, u, o, note in sorted(speed, key=lambda r: r[0]):
        out(f"| {name} | {short} | {u:.2f} | {o:.2f} | **{u/o:.2f}** | {note} |")
    out()

    out("### Pyramidal LK agreement (same input points from cv2.goodFeaturesToTrack)")
    out()
    out("| sequence | pairs | OpenCV tracked | ours tracked | both | median ‖ours − OpenCV‖ px | 90th pct | < 0.1 px |"
        + (" max ‖ours − before‖ px (tracked by both) | track set changed |" if REF else ""))
    out("|---|---|---|---|---|---|---|---|" + ("---|---|" if REF else ""))
    for r in lk_rows:
        extra = ""
        if REF:
            rd = r[8]
            fin = rd[np.isfinite(rd)]
            extra = f" {fin.max() if len(fin) else 0:.5f} | {int((~np.isfinite(rd)).sum())} |"
        out(f"| {r[0]} | {r[1]} | {r[2]} | {r[3]} | {r[4]} | {r[5]:.4f} | {r[6]:.4f} | {r[7]:.1f} % |" + extra)
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

if want("stereo"):
    out("### Stereo block matching on Middlebury (bad pixels: |d − gt| > 1 px over non-occluded pixels)")
    out()
    out("The Middlebury copy has no nonocc masks: a pixel counts as non-occluded if its left ground truth is known,")
    out("it maps inside the right image, and no other pixel of its row maps to the same right pixel with a disparity")
    out("larger by more than 1 px (forward-warping visibility test). Invalid (unmatched) pixels count as bad;")
    out("the error among valid pixels and the density are listed too. Matched settings: same disparity range")
    out("(OpenCV numDisparities = ours max+1), same 9×9 block; other OpenCV parameters at their defaults.")
    out("Ratio = ours / StereoBM's time in this run.")
    out()
    out("| scene | method | bad (invalid = bad) | density | bad among valid | ms | ratio to StereoBM |")
    out("|---|---|---|---|---|---|---|")
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
        lg, rg = os.path.join(TMP, f"{name}_l.png"), os.path.join(TMP, f"{name}_r.png")
        cv2.imwrite(lg, L); cv2.imwrite(rg, R)
        rows = []
        for tag, fn in [("ours", ours)] + ([("before", ours_ref)] if REF else []):
            of = os.path.join(TMP, f"{name}_{tag}.f32")
            r_ = fn("stereo", lg, rg, nd - 1, 9, of)
            du = np.fromfile(of, np.float32).reshape(r_["height"], r_["width"])
            rows.append((f"{tag} (census 7×7, SAD of Hamming 9×9, LR check)", du, r_["ms"]))
        rows += [("OpenCV StereoBM", dbm, ms_bm), ("OpenCV StereoSGBM (reference)", dsg, ms_sg)]
        for meth, disp, ms in rows:
            b, dens, bv = bad_rate(disp, gt, mask)
            out(f"| {name} | {meth} | {100*b:.1f} % | {100*dens:.1f} % | {100*bv:.1f} % | {ms:.1f} | {ms/ms_bm:.2f} |")
    out()

# --- Flow ----------------------------------------------------------------------------------
if want("flow"):
    out("### Dense flow: our TV-L1 (Chambolle-Pock) vs OpenCV DualTVL1 (contrib) and Farnebäck")
    out()
    out("Accuracy on a synthetic warp of a real 640×480 frame (7-Scenes frame 100 remapped by a known smooth flow:")
    out("1.5° rotation about the centre plus (2.0, −1.2) px), endpoint error over pixels whose source lies inside")
    out("the image. DualTVL1 'matched' uses our settings (λ 0.15, 5 scales of step 0.5, 5 warps, 50 iterations")
    out("per warp in one outer loop, 3×3 median); 'defaults' is OpenCV's own configuration (5 scales of step 0.8,")
    out("5 warps, up to 10 × 30 iterations with ε = 0.01, 5×5 median). Ratio = ours / DualTVL1 matched.")
    out()
    img = cv2.imread(ss[100], 0)
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
    def epe(u, v):
        e = np.hypot(u - fx, v - fy)[inside]
        return e.mean(), np.median(e)
    rows = []
    for tag, fn in [("ours", ours)] + ([("before", ours_ref)] if REF else []):
        r_ = fn("tvl1", p0, p1, os.path.join(TMP, f"flow_{tag}"))
        du = np.fromfile(os.path.join(TMP, f"flow_{tag}.du"), np.float32).reshape(h, w)
        dv = np.fromfile(os.path.join(TMP, f"flow_{tag}.dv"), np.float32).reshape(h, w)
        rows.append((f"{tag}: TV-L1 (λ 0.15, 5 levels, 5 warps × 50 iterations)", *epe(du, dv), r_["ms"]))
    tv = cv2.optflow.DualTVL1OpticalFlow_create(tau=0.25, lambda_=0.15, theta=0.3, nscales=5, warps=5,
                                               epsilon=0.01, innnerIterations=50, outerIterations=1,
                                               scaleStep=0.5, gamma=0.0, medianFiltering=3)
    ms_tv, ft = timed(lambda: tv.calc(img, img1, None), min_reps=1)
    rows.append(("OpenCV DualTVL1, matched settings", *epe(ft[..., 0], ft[..., 1]), ms_tv))
    tvd = cv2.optflow.DualTVL1OpticalFlow_create()
    ms_tvd, ftd = timed(lambda: tvd.calc(img, img1, None), min_reps=1)
    rows.append(("OpenCV DualTVL1, OpenCV defaults", *epe(ftd[..., 0], ftd[..., 1]), ms_tvd))
    ms_fb, ff = timed(lambda: cv2.calcOpticalFlowFarneback(img, img1, None, 0.5, 5, 15, 3, 5, 1.2, 0), min_reps=3)
    rows.append(("OpenCV Farnebäck (0.5, 5 levels, win 15)", *epe(ff[..., 0], ff[..., 1]), ms_fb))
    out("| method | mean EPE px | median EPE px | ms (640×480) | ratio to DualTVL1 matched |")
    out("|---|---|---|---|---|")
    for name, m, med, ms in rows:
        out(f"| {name} | {m:.3f} | {med:.3f} | {ms:.0f} | {ms/ms_tv:.2f} |")
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

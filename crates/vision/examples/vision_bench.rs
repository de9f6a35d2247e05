//! Timing and output driver for `bench/vision/run.sh`: runs one `vision` operation on given
//! images, single-threaded, and prints JSON (median time over repetitions, plus results).
//!
//! Usage:
//!   vision_bench pyrfast IMG THRESH LEVELS
//!   vision_bench fast IMG THRESH                 (corners of level 0, NMS)
//!   vision_bench orb IMG NFEATURES
//!   vision_bench lk IMG0 IMG1 POINTS.txt LEVELS  (points: "u v" per line; prints tracks)
//!   vision_bench stereo LEFT RIGHT MAXDISP BLOCK OUT.f32   (one StereoMatcher kept over the
//!                                           repetitions)
//!   vision_bench tvl1 IMG0 IMG1 OUT [ITERATIONS [WARPS]]
//!                                           (writes OUT.du, OUT.dv as raw f32; default params
//!                                           unless ITERATIONS / WARPS per warp are given)
//!   vision_bench patch IMG0 IMG1               (guided-search kernels on FAST corners of IMG0:
//!                                           ns per call of each, and per whole search)
//!   vision_bench dense REF REF_DEPTH CUR FX FY CX CY LEVELS FINEST ITERATIONS
//!                                           (REF_DEPTH: 16-bit PNG in millimetres, 0 and 65535
//!                                           invalid; pyramids built outside the timing, as in the
//!                                           live tracker; prints cur_from_ref as a 4×4 matrix,
//!                                           the time of prepare + align, of each alone, and
//!                                           with both pyramids built)
//!   vision_bench lkroad IMGS STEP F CX HORIZON HEIGHT RADIUS [AFFINE_LEVELS]
//!                                           (LK's error on a road: each image of the
//!                                           comma-separated IMGS warped by the homography of a
//!                                           flat road HEIGHT metres below a camera of focal F,
//!                                           principal column CX and horizon row HORIZON that
//!                                           moves STEP metres forward; the FAST corners below
//!                                           the horizon tracked as the monocular front-end
//!                                           does (forward-backward, 4 levels, window radius
//!                                           RADIUS, the finest AFFINE_LEVELS affine, 0 unless
//!                                           given); prints the corners, the tracks kept and
//!                                           their error along and across each corner's true
//!                                           flow, by flow length)
//!   vision_bench lksurv PAIRS CX RADIUS AFFINE_LEVELS
//!                                           (the share of FAST corners that the monocular
//!                                           front-end's forward-backward LK keeps between the
//!                                           images of each pair of the comma-separated
//!                                           `A:B` PAIRS, at the centre (within 300 px of
//!                                           column CX) and at the sides)

use std::time::Instant;
use vision::fast::fast9_pyramid;
use vision::image::load_gray_u8;
use vision::pyramid::Pyramid;

/// CPU time of this thread in nanoseconds (`/proc/thread-self/schedstat`), so that timings are
/// not inflated by other processes competing for the cores; `None` where unavailable.
fn thread_cpu_ns() -> Option<u64> {
    std::fs::read_to_string("/proc/thread-self/schedstat")
        .ok()?
        .split_whitespace()
        .next()?
        .parse()
        .ok()
}

/// Runs `f` repeatedly (at least `min_reps` times, and for at least `VISION_BENCH_BUDGET`
/// seconds of CPU time, default 1, when `min_reps > 1`) and returns the mean CPU milliseconds
/// per call (wall clock if no CPU clock).
fn time_ms<T>(min_reps: usize, mut f: impl FnMut() -> T) -> (f64, T) {
    let budget: f64 = std::env::var("VISION_BENCH_BUDGET")
        .ok()
        .and_then(|s| s.parse().ok())
        .unwrap_or(1.0);
    let wall = Instant::now();
    let cpu0 = thread_cpu_ns();
    let mut reps = 0usize;
    loop {
        let out = f();
        reps += 1;
        let spent = match (cpu0, thread_cpu_ns()) {
            (Some(a), Some(b)) => (b - a) as f64 * 1e-9,
            _ => wall.elapsed().as_secs_f64(),
        };
        if reps >= min_reps && (min_reps <= 1 || spent >= budget || reps >= 500) {
            return (spent * 1e3 / reps as f64, out);
        }
    }
}

fn write_f32(path: &str, img: &vision::Image<f32>) {
    let mut bytes = Vec::with_capacity(img.width() * img.height() * 4);
    for v in 0..img.height() {
        for &x in img.row(v) {
            bytes.extend_from_slice(&x.to_le_bytes());
        }
    }
    std::fs::write(path, bytes).expect("write output");
}

fn main() {
    let a: Vec<String> = std::env::args().collect();
    let arg = |i: usize| {
        a.get(i)
            .unwrap_or_else(|| panic!("missing argument {i}; see the source for usage"))
            .clone()
    };
    match arg(1).as_str() {
        "pyrfast" => {
            let img = load_gray_u8(arg(2)).expect("image");
            let t: u8 = arg(3).parse().expect("threshold");
            let levels: usize = arg(4).parse().expect("levels");
            let (ms, n) = time_ms(5, || {
                let p = Pyramid::new(&img, levels, 8).expect("pyramid");
                fast9_pyramid(&p, t, true)
                    .iter()
                    .map(|c| c.len())
                    .collect::<Vec<_>>()
            });
            println!("{}", serde_json::json!({"ms": ms, "corners_per_level": n}));
        }
        "fast" => {
            let img = load_gray_u8(arg(2)).expect("image");
            let t: u8 = arg(3).parse().expect("threshold");
            let (ms, c) = time_ms(5, || vision::fast::fast9(&img, t, true));
            let pts: Vec<[f32; 2]> = c.iter().map(|c| [c.u, c.v]).collect();
            println!("{}", serde_json::json!({"ms": ms, "corners": pts}));
        }
        "orb" => {
            let img = load_gray_u8(arg(2)).expect("image");
            let n: usize = arg(3).parse().expect("nfeatures");
            let params = vision::orb::OrbParams {
                num_features: n,
                ..Default::default()
            };
            let (ms, (k, d)) = time_ms(5, || {
                vision::orb::detect_and_describe(&img, &params).expect("orb")
            });
            // A digest of the keypoints and descriptors, to compare two builds' results.
            let mut digest = 0xcbf2_9ce4_8422_2325u64;
            let mut mix = |x: u64| digest = (digest ^ x).wrapping_mul(0x0100_0000_01b3);
            for (kp, desc) in k.iter().zip(&d) {
                mix(kp.u.to_bits() as u64);
                mix(kp.v.to_bits() as u64);
                mix(kp.angle.to_bits() as u64);
                mix(kp.response.to_bits() as u64);
                desc.iter().for_each(|&w| mix(w));
            }
            println!(
                "{}",
                serde_json::json!({"ms": ms, "keypoints": k.len(), "digest": format!("{digest:016x}")})
            );
        }
        "lk" => {
            let i0 = load_gray_u8(arg(2)).expect("image 0");
            let i1 = load_gray_u8(arg(3)).expect("image 1");
            let pts: Vec<[f32; 2]> = std::fs::read_to_string(arg(4))
                .expect("points")
                .lines()
                .filter_map(|l| {
                    let mut it = l.split_whitespace().map(|x| x.parse::<f32>());
                    Some([it.next()?.ok()?, it.next()?.ok()?])
                })
                .collect();
            let levels: usize = arg(5).parse().expect("levels");
            let params = vision::lk::LkParams {
                levels,
                ..Default::default()
            };
            let (ms, tracks) = time_ms(5, || {
                let p0 = Pyramid::new(&i0, levels, 8).expect("pyramid");
                let p1 = Pyramid::new(&i1, levels, 8).expect("pyramid");
                vision::lk::track(&p0, &p1, &pts, None, &params)
            });
            let out: Vec<Option<[f32; 2]>> = tracks;
            println!("{}", serde_json::json!({"ms": ms, "tracks": out}));
        }
        "stereo" => {
            let l = load_gray_u8(arg(2)).expect("left");
            let r = load_gray_u8(arg(3)).expect("right");
            let params = vision::stereo::StereoParams {
                max_disparity: arg(4).parse().expect("maxdisp"),
                block_radius: arg(5).parse::<usize>().expect("block") / 2,
                ..Default::default()
            };
            // One matcher for all repetitions, as a caller matching a stream of pairs keeps
            // one (its buffers are made by the first call; each call allocates its output).
            let mut matcher = vision::stereo::StereoMatcher::new(params);
            let (ms, d) = time_ms(3, || matcher.compute(&l, &r).expect("stereo"));
            write_f32(&arg(6), &d);
            println!(
                "{}",
                serde_json::json!({"ms": ms, "width": d.width(), "height": d.height()})
            );
        }
        "sparse" => {
            // Sparse stereo at the FAST corners of the left image: time per point, and how many
            // get a disparity (also with the point's own patch refinement, as the live system).
            let l = load_gray_u8(arg(2)).expect("left");
            let r = load_gray_u8(arg(3)).expect("right");
            let params = vision::stereo::SparseParams {
                max_disparity: arg(4).parse().expect("maxdisp"),
                ..Default::default()
            };
            let corners = vision::fast::fast9(&l, 20, true);
            let (ms, found) = time_ms(3, || {
                corners
                    .iter()
                    .filter_map(|c| {
                        let (x, y) = ((c.u + 0.5) as usize, (c.v + 0.5) as usize);
                        vision::stereo::point_block_disparity(&l, &r, x, y, &params)
                    })
                    .count()
            });
            let (ms_refined, refined) = time_ms(3, || {
                corners
                    .iter()
                    .filter_map(|c| {
                        let (x, y) = ((c.u + 0.5) as usize, (c.v + 0.5) as usize);
                        let d = vision::stereo::point_block_disparity(&l, &r, x, y, &params)?;
                        vision::stereo::point_disparity(&l, &r, c.u, c.v, d, 1.0)
                    })
                    .count()
            });
            println!(
                "{}",
                serde_json::json!({"ms": ms, "points": corners.len(), "measured": found,
                    "us_per_point": 1e3 * ms / corners.len() as f64,
                    "ms_refined": ms_refined, "refined": refined})
            );
        }
        "tvl1" => {
            let i0 = load_gray_u8(arg(2)).expect("image 0");
            let i1 = load_gray_u8(arg(3)).expect("image 1");
            let mut params = vision::tvl1::Tvl1Params::default();
            if let Some(it) = a.get(5) {
                params.iterations = it.parse().expect("iterations");
            }
            if let Some(wp) = a.get(6) {
                params.warps = wp.parse().expect("warps");
            }
            let (ms, f) = time_ms(1, || {
                vision::tvl1::tvl1_flow(&i0, &i1, &params).expect("flow")
            });
            write_f32(&format!("{}.du", arg(4)), &f.du);
            write_f32(&format!("{}.dv", arg(4)), &f.dv);
            println!(
                "{}",
                serde_json::json!({"ms": ms, "width": f.du.width(), "height": f.du.height()})
            );
        }
        "patch" => {
            use vision::patch::{Patch, nssd, refine_subpixel, template_with_gradient, zmssd};
            let i0 = load_gray_u8(arg(2)).expect("image 0");
            let i1 = load_gray_u8(arg(3)).expect("image 1");
            let corners: Vec<(f32, f32)> = vision::fast::fast9(&i0, 12, true)
                .iter()
                .filter(|c| {
                    c.u > 20.0
                        && c.v > 20.0
                        && c.u < i0.width() as f32 - 20.0
                        && c.v < i0.height() as f32 - 20.0
                })
                .step_by(3)
                .take(300)
                .map(|c| (c.u, c.v))
                .collect();
            // A mild affine warp (5° rotation, 1.05 scale), as the tracker predicts from a pose.
            let (sn, cs) = (0.0872f64.sin() * 1.05, 0.0872f64.cos() * 1.05);
            let warp = nalgebra::Matrix2::new(cs, -sn, sn, cs);
            let templates: Vec<Patch> = corners
                .iter()
                .filter_map(|&(u, v)| Patch::extract_warped(&i0, u, v, &warp))
                .collect();
            let offsets: Vec<(f32, f32)> = (-1..=1)
                .flat_map(|dy| (-1..=1).map(move |dx| (dx as f32 * 2.0, dy as f32 * 2.0)))
                .collect();
            // Each timed call runs its kernel REPS times over all corners (the driver's clock
            // has scheduler-tick resolution and stops at 500 calls).
            const REPS: usize = 40;
            let n = (corners.len() * REPS) as f64;
            let per = |ms: f64, calls: f64| ms * 1e6 / calls;
            let (ms, _) = time_ms(5, || {
                (0..REPS)
                    .flat_map(|_| corners.iter())
                    .filter_map(|&(u, v)| Patch::extract(&i1, u + 0.3, v - 0.2))
                    .count()
            });
            let extract_ns = per(ms, n);
            let (ms, _) = time_ms(5, || {
                (0..REPS)
                    .flat_map(|_| corners.iter())
                    .filter_map(|&(u, v)| Patch::extract_warped(&i0, u, v, &warp))
                    .count()
            });
            let warped_ns = per(ms, n);
            let cands: Vec<Patch> = corners
                .iter()
                .filter_map(|&(u, v)| Patch::extract(&i1, u, v))
                .collect();
            let pairs = (templates.len().min(cands.len()) * REPS) as f64;
            let (ms, _) = time_ms(5, || {
                (0..REPS)
                    .flat_map(|_| templates.iter().zip(&cands))
                    .map(|(a, b)| nssd(a, b))
                    .sum::<f32>()
            });
            let nssd_ns = per(ms, pairs);
            let (ms, _) = time_ms(5, || {
                (0..REPS)
                    .flat_map(|_| templates.iter().zip(&cands))
                    .map(|(a, b)| zmssd(a, b))
                    .sum::<f32>()
            });
            let zmssd_ns = per(ms, pairs);
            let (ms, _) = time_ms(5, || {
                (0..REPS)
                    .flat_map(|_| corners.iter())
                    .filter_map(|&(u, v)| template_with_gradient(&i0, u, v, &warp))
                    .count()
            });
            let tg_ns = per(ms, n);
            let tgs: Vec<_> = corners
                .iter()
                .filter_map(|&(u, v)| template_with_gradient(&i0, u, v, &warp).map(|t| (t, u, v)))
                .collect();
            let refine_all = || {
                tgs.iter()
                    .map(|(t, u, v)| refine_subpixel(t, &i1, [*u + 0.7, *v - 0.6], 10))
                    .collect::<Vec<_>>()
            };
            let (ms, _) = time_ms(5, || (0..REPS).map(|_| refine_all().len()).sum::<usize>());
            let refined = refine_all();
            let refine_ns = per(ms, (tgs.len() * REPS) as f64);
            // The tracker's search: template, 9 candidates by NSSD, refinement of the best,
            // NSSD at the refined position.
            let search = || {
                corners
                    .iter()
                    .filter_map(|&(u, v)| {
                        let t = Patch::extract_warped(&i0, u, v, &warp)?;
                        let mut best: Option<(f32, f32, f32)> = None;
                        for &(dx, dy) in &offsets {
                            let Some(p) = Patch::extract(&i1, u + dx, v + dy) else {
                                continue;
                            };
                            let s = nssd(&t, &p);
                            if best.is_none_or(|b| s < b.2) {
                                best = Some((u + dx, v + dy, s));
                            }
                        }
                        let (bu, bv, _) = best?;
                        let r = template_with_gradient(&i0, u, v, &warp)
                            .and_then(|tg| refine_subpixel(&tg, &i1, [bu, bv], 10))
                            .unwrap_or([bu, bv]);
                        let p = Patch::extract(&i1, r[0], r[1])?;
                        Some((r, nssd(&t, &p)))
                    })
                    .collect::<Vec<_>>()
            };
            let (ms, _) = time_ms(5, || (0..REPS).map(|_| search().len()).sum::<usize>());
            let found = search();
            let search_ns = per(ms, n);
            let mut digest = 0xcbf2_9ce4_8422_2325u64;
            let mut mix = |x: u32| digest = (digest ^ x as u64).wrapping_mul(0x0100_0000_01b3);
            for t in &templates {
                t.data.iter().for_each(|x| mix(x.to_bits()));
            }
            for (r, s) in &found {
                mix(r[0].to_bits());
                mix(r[1].to_bits());
                mix(s.to_bits());
            }
            for r in refined.iter().flatten() {
                mix(r[0].to_bits());
                mix(r[1].to_bits());
            }
            println!(
                "{}",
                serde_json::json!({"corners": corners.len(), "extract_ns": extract_ns,
                    "extract_warped_ns": warped_ns, "nssd_ns": nssd_ns, "zmssd_ns": zmssd_ns,
                    "template_with_gradient_ns": tg_ns, "refine_subpixel_ns": refine_ns,
                    "search_ns": search_ns, "found": found.len(),
                    "digest": format!("{digest:016x}")})
            );
        }
        "dense" => {
            use lie::LieGroup;
            let iref = load_gray_u8(arg(2)).expect("reference image");
            let raw = vision::image::load_u16(arg(3)).expect("reference depth");
            let depth = raw.map(|d| {
                if d == 0 || d == u16::MAX {
                    f32::NAN
                } else {
                    d as f32 * 1e-3
                }
            });
            let icur = load_gray_u8(arg(4)).expect("current image");
            let f = |i: usize| arg(i).parse::<f64>().expect("intrinsics");
            let camera = geom::PinholeCamera::new(f(5), f(6), f(7), f(8));
            let params = vision::dense::DenseParams {
                levels: arg(9).parse().expect("levels"),
                finest_level: arg(10).parse().expect("finest level"),
                max_iterations: arg(11).parse().expect("iterations"),
                ..Default::default()
            };
            let pr = Pyramid::new(&iref, params.levels, 16).expect("pyramid");
            let pc = Pyramid::new(&icur, params.levels, 16).expect("pyramid");
            // The live tracker's per-frame work: prepare the reference, align the next frame
            // against it (buffers kept across frames).
            let mut scratch = vision::dense::DenseScratch::default();
            let (ms, r) = time_ms(5, || {
                vision::dense::DenseReference::new(&pr, &depth, &camera, &params)
                    .expect("dense reference")
                    .align(&pc, &lie::Se3::identity(), &mut scratch)
                    .expect("dense alignment")
            });
            let reference = vision::dense::DenseReference::new(&pr, &depth, &camera, &params)
                .expect("reference");
            let (ms_prepare, _) = time_ms(5, || {
                vision::dense::DenseReference::new(&pr, &depth, &camera, &params)
                    .expect("dense reference")
            });
            let (ms_align, _) = time_ms(5, || {
                reference
                    .align(&pc, &lie::Se3::identity(), &mut scratch)
                    .expect("dense alignment")
            });
            // Including both image pyramids (which the tracker has already), as the OpenCV
            // peer builds them inside its frame preparation.
            let (ms_with_pyramids, _) = time_ms(5, || {
                let pr = Pyramid::new(&iref, params.levels, 16).expect("pyramid");
                let pc = Pyramid::new(&icur, params.levels, 16).expect("pyramid");
                vision::dense::DenseReference::new(&pr, &depth, &camera, &params)
                    .expect("dense reference")
                    .align(&pc, &lie::Se3::identity(), &mut scratch)
                    .expect("dense alignment")
            });
            let scalar = vision::simd::scalar_only(|| {
                reference
                    .align(&pc, &lie::Se3::identity(), &mut scratch)
                    .expect("dense alignment")
            });
            let same_as_scalar = scalar.cur_from_ref.matrix() == r.cur_from_ref.matrix()
                && scalar.final_cost.to_bits() == r.final_cost.to_bits()
                && scalar.iterations == r.iterations;
            let m = r.cur_from_ref.matrix();
            let rows: Vec<Vec<f64>> = (0..4)
                .map(|i| (0..4).map(|j| m[(i, j)]).collect())
                .collect();
            println!(
                "{}",
                serde_json::json!({"ms": ms, "ms_prepare": ms_prepare, "ms_align": ms_align,
                                   "ms_with_pyramids": ms_with_pyramids,
                                   "cur_from_ref": rows, "iterations": r.iterations,
                                   "residuals": r.num_residuals, "cost": r.final_cost,
                                   "same_as_scalar": same_as_scalar})
            );
        }
        "lkroad" => {
            let step: f32 = arg(3).parse().expect("step");
            let (f, cx, horizon, height): (f32, f32, f32, f32) = (
                arg(4).parse().expect("focal"),
                arg(5).parse().expect("cx"),
                arg(6).parse().expect("horizon row"),
                arg(7).parse().expect("camera height"),
            );
            let radius: usize = arg(8).parse().expect("window radius");
            let affine_levels: usize = std::env::args()
                .nth(9)
                .map_or(0, |a| a.parse().expect("affine levels"));
            // The road point seen at row offset y = v − horizon lies at depth Z = f·h/y; after a
            // step b forward it is seen at (c + (x − c)·k, horizon + y·k), k = Z/(Z − b)
            // = 1/(1 − b·y/(f·h)). The warp samples the source at the inverse map.
            let fh = f * height;
            let forward = |u: f32, v: f32| {
                let k = 1.0 / (1.0 - step * (v - horizon) / fh);
                (cx + (u - cx) * k, horizon + (v - horizon) * k)
            };
            let backward = |u: f32, v: f32| {
                let y2 = v - horizon;
                if y2 <= 0.0 {
                    return (u, v);
                }
                let y = y2 / (1.0 + step * y2 / fh);
                (cx + (u - cx) * (1.0 - step * y / fh), horizon + y)
            };
            // Bins of 5 px of true flow: (along, across) errors of the tracked position.
            let mut bins: Vec<Vec<(f32, f32)>> = vec![Vec::new(); 7];
            let mut corners_in = [0usize; 7];
            for path in arg(2).split(',') {
                let img = load_gray_u8(path).expect("image");
                let (w, h) = (img.width() as f32, img.height() as f32);
                let warped =
                    vision::image::GrayImage::from_fn(img.width(), img.height(), |u, v| {
                        let (x, y) = backward(u as f32, v as f32);
                        let x = x.clamp(0.0, w - 1.0);
                        let y = y.clamp(0.0, h - 1.0);
                        vision::interp::bilinear(&img, x, y)
                            .unwrap_or(0.0)
                            .round()
                            .clamp(0.0, 255.0) as u8
                    });
                let corners: Vec<[f32; 2]> = vision::fast::fast9(&img, 20, true)
                    .iter()
                    .filter(|c| c.v > horizon + 30.0 && c.v < h - 40.0)
                    .filter(|c| c.u > 40.0 && c.u < w - 40.0)
                    .map(|c| [c.u, c.v])
                    .collect();
                let p0 = Pyramid::new(&img, 4, 16).expect("pyramid");
                let p1 = Pyramid::new(&warped, 4, 16).expect("pyramid");
                let params = vision::lk::LkParams {
                    levels: 4,
                    window_radius: radius,
                    affine_levels,
                    ..Default::default()
                };
                let tracked = vision::lk::track_forward_backward(&p0, &p1, &corners, &params, 1.0);
                for (p, q) in corners.iter().zip(&tracked) {
                    let (tu, tv) = forward(p[0], p[1]);
                    if tu < 0.0 || tu > w - 1.0 || tv > h - 1.0 {
                        continue;
                    }
                    let d = [tu - p[0], tv - p[1]];
                    let n = d[0].hypot(d[1]);
                    corners_in[((n / 5.0) as usize).min(6)] += 1;
                    let Some(q) = q else { continue };
                    let e = [q[0] - tu, q[1] - tv];
                    let along = (e[0] * d[0] + e[1] * d[1]) / n;
                    let across = (e[1] * d[0] - e[0] * d[1]) / n;
                    bins[((n / 5.0) as usize).min(6)].push((along, across));
                }
            }
            let median = |mut x: Vec<f32>| {
                x.sort_by(f32::total_cmp);
                x.get(x.len() / 2).copied().unwrap_or(f32::NAN)
            };
            let rows: Vec<serde_json::Value> = bins
                .into_iter()
                .enumerate()
                .filter(|(_, b)| !b.is_empty())
                .map(|(i, b)| {
                    // Within 2 px: the mean of the tracks that followed their point; the
                    // median of all.
                    let near: Vec<f32> = b.iter().map(|e| e.0).filter(|e| e.abs() < 2.0).collect();
                    serde_json::json!({
                        "flow_px": [5 * i, if i == 6 { None } else { Some(5 * i + 5) }],
                        "corners": corners_in[i],
                        "tracks": b.len(),
                        "within_2px": near.len(),
                        "along_median": median(b.iter().map(|e| e.0).collect()),
                        "along_mean_within_2px": near.iter().sum::<f32>() / near.len().max(1) as f32,
                        "across_median": median(b.iter().map(|e| e.1).collect()),
                    })
                })
                .collect();
            println!(
                "{}",
                serde_json::json!({"window_radius": radius, "affine_levels": affine_levels, "bins": rows})
            );
        }
        "lksurv" => {
            let cx: f32 = arg(3).parse().expect("principal column");
            let radius: usize = arg(4).parse().expect("window radius");
            let affine_levels: usize = arg(5).parse().expect("affine levels");
            let params = vision::lk::LkParams {
                levels: 4,
                window_radius: radius,
                affine_levels,
                ..Default::default()
            };
            // [centre, sides]: corners, kept.
            let (mut corners, mut kept) = ([0usize; 2], [0usize; 2]);
            let t0 = Instant::now();
            for pair in arg(2).split(',') {
                let (a, b) = pair.split_once(':').expect("PAIRS of A:B");
                let (ia, ib) = (
                    load_gray_u8(a).expect("image"),
                    load_gray_u8(b).expect("image"),
                );
                let pa = Pyramid::new(&ia, 4, 16).expect("pyramid");
                let pb = Pyramid::new(&ib, 4, 16).expect("pyramid");
                let pts: Vec<[f32; 2]> = vision::fast::fast9(&ia, 20, true)
                    .iter()
                    .map(|c| [c.u, c.v])
                    .collect();
                let out = vision::lk::track_forward_backward(&pa, &pb, &pts, &params, 1.0);
                for (p, q) in pts.iter().zip(&out) {
                    let side = usize::from((p[0] - cx).abs() > 300.0);
                    corners[side] += 1;
                    kept[side] += usize::from(q.is_some());
                }
            }
            println!(
                "{}",
                serde_json::json!({
                    "window_radius": radius,
                    "affine_levels": affine_levels,
                    "centre": {"corners": corners[0], "kept": kept[0] as f64 / corners[0].max(1) as f64},
                    "sides": {"corners": corners[1], "kept": kept[1] as f64 / corners[1].max(1) as f64},
                    "seconds": t0.elapsed().as_secs_f64(),
                })
            );
        }
        other => panic!("unknown command {other}"),
    }
}

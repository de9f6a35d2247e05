//! Timing and output driver for `bench/vision/run.sh`: runs one `vision` operation on given
//! images, single-threaded, and prints JSON (median time over repetitions, plus results).
//!
//! Usage:
//!   vision_bench pyrfast IMG THRESH LEVELS
//!   vision_bench fast IMG THRESH                 (corners of level 0, NMS)
//!   vision_bench orb IMG NFEATURES
//!   vision_bench lk IMG0 IMG1 POINTS.txt LEVELS  (points: "u v" per line; prints tracks)
//!   vision_bench stereo LEFT RIGHT MAXDISP BLOCK OUT.f32
//!   vision_bench tvl1 IMG0 IMG1 OUT [ITERATIONS [WARPS]]
//!                                           (writes OUT.du, OUT.dv as raw f32; default params
//!                                           unless ITERATIONS / WARPS per warp are given)

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
            let (ms, d) = time_ms(3, || {
                vision::stereo::block_match(&l, &r, &params).expect("stereo")
            });
            write_f32(&arg(6), &d);
            println!(
                "{}",
                serde_json::json!({"ms": ms, "width": d.width(), "height": d.height()})
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
        other => panic!("unknown command {other}"),
    }
}

//! `dwslam inspect …`: pictures of what the visual front-end sees (issue 8, item 9).

use crate::args;
use anyhow::{Context, Result, bail};
use clap::Subcommand;
use std::path::{Path, PathBuf};
use vision::fast::{fast9_pyramid, with_shi_tomasi};
use vision::image::{GrayImage, Image, load_gray_u8};
use vision::pyramid::Pyramid;
use vision::quadtree::{QuadPoint, QuadTree};

/// Inspection commands.
#[derive(Subcommand, Debug)]
pub enum InspectCommand {
    /// FAST corners per pyramid level (colour per level) and the quadtree selection (thesis
    /// Alg. 2, white squares).
    Features {
        /// Input image (PNG, JPEG; colour is converted to grey).
        image: PathBuf,
        /// Output PNG.
        #[arg(long)]
        out: PathBuf,
        /// FAST threshold.
        #[arg(long, default_value_t = 20)]
        threshold: u8,
        /// Pyramid levels.
        #[arg(long, default_value_t = 4)]
        levels: usize,
        /// Number of features picked by the equi-distributed quadtree traversal.
        #[arg(long, default_value_t = 200)]
        select: usize,
    },
    /// Stereo block matching on a rectified pair: disparity as PFM (Middlebury convention,
    /// invalid = inf) and optionally a colour-mapped PNG.
    Stereo {
        /// Left image.
        left: PathBuf,
        /// Right image.
        right: PathBuf,
        /// Largest disparity searched.
        #[arg(long, default_value_t = 64)]
        max_disparity: usize,
        /// Block size (odd).
        #[arg(long, default_value_t = 9)]
        block: usize,
        /// Output PFM.
        #[arg(long)]
        out: PathBuf,
        /// Optional colour-mapped PNG (near = warm, invalid = black).
        #[arg(long)]
        png: Option<PathBuf>,
    },
    /// Dense TV-L1 optical flow from A to B, colour-coded (hue = direction, saturation =
    /// magnitude).
    Flow {
        /// First image.
        a: PathBuf,
        /// Second image.
        b: PathBuf,
        /// Output PNG.
        #[arg(long)]
        out: PathBuf,
        /// Primal-dual iterations per warp.
        #[arg(long, default_value_t = 50)]
        iterations: usize,
    },
    /// Lucas-Kanade tracks over the images of a directory (sorted by name), drawn on each frame.
    Track {
        /// Directory of images.
        dir: PathBuf,
        /// Output directory (created).
        #[arg(long)]
        out: PathBuf,
        /// Process at most this many frames.
        #[arg(long, default_value_t = 100)]
        max_frames: usize,
        /// Number of tracked features.
        #[arg(long, default_value_t = 300)]
        features: usize,
    },
    /// ORB matches between two images (ratio test 0.8, cross-checked), side by side.
    Match {
        /// First image.
        a: PathBuf,
        /// Second image.
        b: PathBuf,
        /// Output PNG.
        #[arg(long)]
        out: PathBuf,
        /// ORB features per image.
        #[arg(long, default_value_t = 1000)]
        features: usize,
    },
}

/// Checks an inspect command's arguments before any work: the inputs exist, the outputs can
/// be written, the counts are positive.
fn validate(cmd: &InspectCommand) -> Result<()> {
    let positive = |n: usize, what: &str| {
        anyhow::ensure!(n > 0, "{what} must be at least 1");
        Ok(())
    };
    match cmd {
        InspectCommand::Features {
            image,
            out,
            levels,
            select,
            ..
        } => {
            args::input_file(image, "IMAGE")?;
            args::output_file(out, "--out")?;
            positive(*levels, "--levels")?;
            positive(*select, "--select")
        }
        InspectCommand::Stereo {
            left,
            right,
            max_disparity,
            block,
            out,
            png,
        } => {
            args::input_file(left, "LEFT")?;
            args::input_file(right, "RIGHT")?;
            args::output_file(out, "--out")?;
            if let Some(p) = png {
                args::output_file(p, "--png")?;
            }
            positive(*max_disparity, "--max-disparity")?;
            anyhow::ensure!(
                *block >= 3 && block % 2 == 1,
                "--block must be odd and at least 3, got {block}"
            );
            Ok(())
        }
        InspectCommand::Flow {
            a,
            b,
            out,
            iterations,
        } => {
            args::input_file(a, "A")?;
            args::input_file(b, "B")?;
            args::output_file(out, "--out")?;
            positive(*iterations, "--iterations")
        }
        InspectCommand::Track {
            dir,
            out,
            max_frames,
            features,
        } => {
            args::input_dir(dir, "DIR")?;
            args::output_dir(out, "--out")?;
            anyhow::ensure!(
                *max_frames >= 2,
                "--max-frames must be at least 2 (tracks join frames)"
            );
            positive(*features, "--features")
        }
        InspectCommand::Match {
            a,
            b,
            out,
            features,
        } => {
            args::input_file(a, "A")?;
            args::input_file(b, "B")?;
            args::output_file(out, "--out")?;
            positive(*features, "--features")
        }
    }
}

/// Runs an inspect command.
pub fn run(cmd: InspectCommand) -> Result<()> {
    validate(&cmd)?;
    match cmd {
        InspectCommand::Features {
            image,
            out,
            threshold,
            levels,
            select,
        } => features(&image, &out, threshold, levels, select),
        InspectCommand::Stereo {
            left,
            right,
            max_disparity,
            block,
            out,
            png,
        } => stereo(&left, &right, max_disparity, block, &out, png.as_deref()),
        InspectCommand::Flow {
            a,
            b,
            out,
            iterations,
        } => flow(&a, &b, &out, iterations),
        InspectCommand::Track {
            dir,
            out,
            max_frames,
            features,
        } => track(&dir, &out, max_frames, features),
        InspectCommand::Match {
            a,
            b,
            out,
            features,
        } => orb_match(&a, &b, &out, features),
    }
}

fn load(path: &Path) -> Result<GrayImage> {
    Ok(load_gray_u8(path)?)
}

/// An RGB canvas with simple drawing.
struct Canvas {
    w: usize,
    h: usize,
    px: Vec<[u8; 3]>,
}

impl Canvas {
    fn from_gray(g: &GrayImage) -> Self {
        let px = (0..g.height())
            .flat_map(|v| g.row(v).iter().map(|&p| [p, p, p]).collect::<Vec<_>>())
            .collect();
        Self {
            w: g.width(),
            h: g.height(),
            px,
        }
    }
    fn new(w: usize, h: usize) -> Self {
        Self {
            w,
            h,
            px: vec![[0, 0, 0]; w * h],
        }
    }
    fn set(&mut self, x: i64, y: i64, c: [u8; 3]) {
        if x >= 0 && y >= 0 && (x as usize) < self.w && (y as usize) < self.h {
            self.px[y as usize * self.w + x as usize] = c;
        }
    }
    fn line(&mut self, x0: f32, y0: f32, x1: f32, y1: f32, c: [u8; 3]) {
        let n = ((x1 - x0).abs().max((y1 - y0).abs()).ceil() as usize).max(1);
        for i in 0..=n {
            let t = i as f32 / n as f32;
            self.set(
                (x0 + t * (x1 - x0)).round() as i64,
                (y0 + t * (y1 - y0)).round() as i64,
                c,
            );
        }
    }
    fn circle(&mut self, x: f32, y: f32, r: f32, c: [u8; 3]) {
        let n = ((2.0 * std::f32::consts::PI * r).ceil() as usize).max(8);
        for i in 0..n {
            let a = i as f32 / n as f32 * 2.0 * std::f32::consts::PI;
            self.set(
                (x + r * a.cos()).round() as i64,
                (y + r * a.sin()).round() as i64,
                c,
            );
        }
    }
    fn square(&mut self, x: f32, y: f32, r: f32, c: [u8; 3]) {
        self.line(x - r, y - r, x + r, y - r, c);
        self.line(x + r, y - r, x + r, y + r, c);
        self.line(x + r, y + r, x - r, y + r, c);
        self.line(x - r, y + r, x - r, y - r, c);
    }
    fn blit(&mut self, other: &Canvas, ox: usize) {
        for y in 0..other.h.min(self.h) {
            for x in 0..other.w {
                if x + ox < self.w {
                    self.px[y * self.w + x + ox] = other.px[y * other.w + x];
                }
            }
        }
    }
    fn save(&self, path: &Path) -> Result<()> {
        let raw: Vec<u8> = self.px.iter().flatten().copied().collect();
        let file =
            std::fs::File::create(path).with_context(|| format!("creating {}", path.display()))?;
        let enc = image::codecs::png::PngEncoder::new(std::io::BufWriter::new(file));
        image::ImageEncoder::write_image(
            enc,
            &raw,
            self.w as u32,
            self.h as u32,
            image::ExtendedColorType::Rgb8,
        )
        .with_context(|| format!("writing PNG {}", path.display()))
    }
}

const LEVEL_COLOURS: [[u8; 3]; 6] = [
    [255, 60, 60],
    [60, 220, 60],
    [80, 140, 255],
    [255, 220, 40],
    [255, 60, 255],
    [40, 230, 230],
];

/// Turbo-like colour map of `t ∈ [0, 1]` (blue → green → red).
fn colour_map(t: f32) -> [u8; 3] {
    let t = t.clamp(0.0, 1.0);
    let r = (1.5 - (4.0 * t - 3.0).abs()).clamp(0.0, 1.0);
    let g = (1.5 - (4.0 * t - 2.0).abs()).clamp(0.0, 1.0);
    let b = (1.5 - (4.0 * t - 1.0).abs()).clamp(0.0, 1.0);
    [(r * 255.0) as u8, (g * 255.0) as u8, (b * 255.0) as u8]
}

fn features(path: &Path, out: &Path, threshold: u8, levels: usize, select: usize) -> Result<()> {
    let img = load(path)?;
    let pyr = Pyramid::new(&img, levels.max(1), 8)
        .with_context(|| format!("building pyramid of {}", path.display()))?;
    let corners = fast9_pyramid(&pyr, threshold, true);
    let mut canvas = Canvas::from_gray(&img);
    let mut quad_points = Vec::new();
    for (l, cs) in corners.iter().enumerate() {
        let scored = with_shi_tomasi(&pyr.levels[l], cs, 3);
        let s = (1u32 << l) as f32;
        for c in &scored {
            let (u, v) = (
                Pyramid::from_level(c.u as f64, l) as f32,
                Pyramid::from_level(c.v as f64, l) as f32,
            );
            canvas.circle(u, v, 2.0 * s, LEVEL_COLOURS[l % LEVEL_COLOURS.len()]);
            if l == 0 {
                quad_points.push(QuadPoint {
                    u,
                    v,
                    score: c.score,
                    index: quad_points.len(),
                });
            }
        }
        println!(
            "level {l}: {} FAST corners ({} with a Shi-Tomasi score)",
            cs.len(),
            scored.len()
        );
    }
    let tree = QuadTree::from_points(img.width() as f32, img.height() as f32, 8.0, &quad_points);
    let chosen = tree.select(select, 0);
    for q in &chosen {
        canvas.square(q.u, q.v, 4.0, [255, 255, 255]);
    }
    println!(
        "quadtree: {} of {} level-0 corners selected (min cell 8 px)",
        chosen.len(),
        tree.len()
    );
    canvas.save(out)?;
    println!("wrote {}", out.display());
    Ok(())
}

/// Writes a PFM (Middlebury: `Pf`, width height, `-1` = little endian, rows bottom to top,
/// invalid = +inf).
fn write_pfm(path: &Path, img: &Image<f32>) -> Result<()> {
    let mut bytes = format!("Pf\n{} {}\n-1\n", img.width(), img.height()).into_bytes();
    for v in (0..img.height()).rev() {
        for &d in img.row(v) {
            let d = if d.is_finite() { d } else { f32::INFINITY };
            bytes.extend_from_slice(&d.to_le_bytes());
        }
    }
    std::fs::write(path, bytes).with_context(|| format!("writing PFM {}", path.display()))
}

fn stereo(
    left: &Path,
    right: &Path,
    max_disparity: usize,
    block: usize,
    out: &Path,
    png: Option<&Path>,
) -> Result<()> {
    if block.is_multiple_of(2) || block < 3 {
        bail!("--block must be odd and at least 3, got {block}");
    }
    let l = load(left)?;
    let r = load(right)?;
    let params = vision::stereo::StereoParams {
        max_disparity,
        block_radius: block / 2,
        ..Default::default()
    };
    let t = std::time::Instant::now();
    let disp = vision::stereo::block_match(&l, &r, &params)
        .with_context(|| format!("matching {} against {}", left.display(), right.display()))?;
    let valid = disp.data().iter().filter(|d| d.is_finite()).count();
    println!(
        "disparity {}×{} in {:.1} ms, {:.1} % valid",
        disp.width(),
        disp.height(),
        t.elapsed().as_secs_f64() * 1e3,
        100.0 * valid as f64 / (disp.width() * disp.height()) as f64
    );
    write_pfm(out, &disp)?;
    println!("wrote {}", out.display());
    if let Some(png) = png {
        let mut c = Canvas::new(disp.width(), disp.height());
        for v in 0..disp.height() {
            for u in 0..disp.width() {
                let d = disp.get(u, v);
                if d.is_finite() {
                    c.set(
                        u as i64,
                        v as i64,
                        colour_map(d / max_disparity.max(1) as f32),
                    );
                }
            }
        }
        c.save(png)?;
        println!("wrote {}", png.display());
    }
    Ok(())
}

fn flow(a: &Path, b: &Path, out: &Path, iterations: usize) -> Result<()> {
    let ia = load(a)?;
    let ib = load(b)?;
    let params = vision::tvl1::Tvl1Params {
        iterations,
        ..Default::default()
    };
    let t = std::time::Instant::now();
    let f = vision::tvl1::tvl1_flow(&ia, &ib, &params)
        .with_context(|| format!("flow from {} to {}", a.display(), b.display()))?;
    // Saturation scaled by the 99th percentile of the magnitude (robust to a few outliers).
    let mut mags: Vec<f32> =
        f.du.data()
            .iter()
            .zip(f.dv.data())
            .map(|(x, y)| x.hypot(*y))
            .collect();
    mags.sort_by(|a, b| a.total_cmp(b));
    let max = mags[(mags.len() * 99 / 100).min(mags.len() - 1)].max(1e-3);
    println!(
        "TV-L1 flow {}×{} in {:.2} s, 99th-percentile magnitude {max:.2} px",
        ia.width(),
        ia.height(),
        t.elapsed().as_secs_f64()
    );
    let mut c = Canvas::new(ia.width(), ia.height());
    for v in 0..ia.height() {
        for u in 0..ia.width() {
            let (x, y) = (f.du.get(u, v), f.dv.get(u, v));
            let hue = (y.atan2(x) / (2.0 * std::f32::consts::PI) + 1.0) % 1.0;
            let sat = (x.hypot(y) / max).clamp(0.0, 1.0);
            c.set(u as i64, v as i64, hsv(hue, sat, 1.0));
        }
    }
    c.save(out)?;
    println!("wrote {}", out.display());
    Ok(())
}

fn hsv(h: f32, s: f32, v: f32) -> [u8; 3] {
    let i = (h * 6.0).floor();
    let f = h * 6.0 - i;
    let (p, q, t) = (v * (1.0 - s), v * (1.0 - f * s), v * (1.0 - (1.0 - f) * s));
    let (r, g, b) = match i as i32 % 6 {
        0 => (v, t, p),
        1 => (q, v, p),
        2 => (p, v, t),
        3 => (p, q, v),
        4 => (t, p, v),
        _ => (v, p, q),
    };
    [(r * 255.0) as u8, (g * 255.0) as u8, (b * 255.0) as u8]
}

fn detect_spread(img: &GrayImage, n: usize) -> Vec<[f32; 2]> {
    vision::quadtree::select_corners(img, 20, n, 8.0)
        .1
        .iter()
        .map(|q| [q.u, q.v])
        .collect()
}

fn track(dir: &Path, out: &Path, max_frames: usize, n: usize) -> Result<()> {
    let mut files: Vec<PathBuf> = std::fs::read_dir(dir)
        .with_context(|| format!("listing {}", dir.display()))?
        .filter_map(|e| e.ok().map(|e| e.path()))
        .filter(|p| {
            p.extension().and_then(|e| e.to_str()).is_some_and(|e| {
                matches!(
                    e.to_ascii_lowercase().as_str(),
                    "png" | "jpg" | "jpeg" | "pgm"
                )
            })
        })
        .collect();
    files.sort();
    files.truncate(max_frames);
    if files.is_empty() {
        bail!("no images (png, jpg, pgm) in {}", dir.display());
    }
    std::fs::create_dir_all(out).with_context(|| format!("creating {}", out.display()))?;
    let params = vision::lk::LkParams::default();
    let mut prev_img = load(&files[0])?;
    let mut prev = Pyramid::new(&prev_img, params.levels, 8).context("pyramid")?;
    // Each track: its history of positions.
    let mut tracks: Vec<Vec<[f32; 2]>> = detect_spread(&prev_img, n)
        .into_iter()
        .map(|p| vec![p])
        .collect();
    let draw = |img: &GrayImage, tracks: &[Vec<[f32; 2]>], path: &Path| -> Result<()> {
        let mut c = Canvas::from_gray(img);
        for t in tracks {
            for w in t.windows(2).rev().take(10) {
                c.line(w[0][0], w[0][1], w[1][0], w[1][1], [60, 220, 60]);
            }
            let p = t.last().expect("non-empty");
            c.circle(p[0], p[1], 2.0, [255, 60, 60]);
        }
        c.save(path)
    };
    draw(&prev_img, &tracks, &out.join("000000.png"))?;
    for (k, f) in files.iter().enumerate().skip(1) {
        let img = load(f)?;
        if (img.width(), img.height()) != (prev_img.width(), prev_img.height()) {
            bail!(
                "{} is {}×{}, the sequence is {}×{}",
                f.display(),
                img.width(),
                img.height(),
                prev_img.width(),
                prev_img.height()
            );
        }
        let next = Pyramid::new(&img, params.levels, 8).context("pyramid")?;
        let last: Vec<[f32; 2]> = tracks
            .iter()
            .map(|t| *t.last().expect("non-empty"))
            .collect();
        let res = vision::lk::track_forward_backward(&prev, &next, &last, &params, 1.0);
        let mut kept: Vec<Vec<[f32; 2]>> = tracks
            .into_iter()
            .zip(res)
            .filter_map(|(mut t, r)| {
                r.map(|p| {
                    t.push(p);
                    t
                })
            })
            .collect();
        let survived = kept.len();
        if kept.len() < n / 2 {
            for p in detect_spread(&img, n - kept.len()) {
                kept.push(vec![p]);
            }
        }
        println!(
            "{}: {survived} tracks kept, {} after re-detection",
            f.display(),
            kept.len()
        );
        draw(&img, &kept, &out.join(format!("{k:06}.png")))?;
        tracks = kept;
        prev = next;
        prev_img = img;
    }
    println!("wrote {} frames to {}", files.len(), out.display());
    Ok(())
}

fn orb_match(a: &Path, b: &Path, out: &Path, features: usize) -> Result<()> {
    let ia = load(a)?;
    let ib = load(b)?;
    let params = vision::orb::OrbParams {
        num_features: features,
        ..Default::default()
    };
    let (ka, da) = vision::orb::detect_and_describe(&ia, &params)
        .with_context(|| format!("ORB on {}", a.display()))?;
    let (kb, db) = vision::orb::detect_and_describe(&ib, &params)
        .with_context(|| format!("ORB on {}", b.display()))?;
    let m = vision::orb::match_descriptors(&da, &db, 80, 0.8, true);
    println!(
        "{} / {} keypoints, {} matches (ratio 0.8, cross-checked)",
        ka.len(),
        kb.len(),
        m.len()
    );
    let (ca, cb) = (Canvas::from_gray(&ia), Canvas::from_gray(&ib));
    let mut c = Canvas::new(ca.w + cb.w, ca.h.max(cb.h));
    c.blit(&ca, 0);
    c.blit(&cb, ca.w);
    for (i, mm) in m.iter().enumerate() {
        let (p, q) = (&ka[mm.query], &kb[mm.train]);
        let col = colour_map((i * 37 % 100) as f32 / 100.0);
        c.circle(p.u, p.v, 3.0 * p.scale, col);
        c.circle(q.u + ca.w as f32, q.v, 3.0 * q.scale, col);
        c.line(p.u, p.v, q.u + ca.w as f32, q.v, col);
    }
    c.save(out)?;
    println!("wrote {}", out.display());
    Ok(())
}

#[cfg(test)]
mod tests {
    use super::*;

    /// Writes a smooth textured grey PNG, shifted by `dx` pixels.
    fn write_png(path: &Path, w: usize, h: usize, dx: f32) {
        let g = GrayImage::from_fn(w, h, |u, v| {
            let x = u as f32 - dx;
            let y = v as f32;
            (128.0
                + 60.0 * (x * 0.3).sin() * (y * 0.23).cos()
                + 40.0 * ((x + 2.0 * y) * 0.11).sin())
            .clamp(0.0, 255.0) as u8
        });
        let mut c = Canvas::from_gray(&g);
        // Add a few corners.
        for k in 0..8 {
            c.square(
                10.0 + 12.0 * k as f32,
                20.0 + 5.0 * k as f32,
                3.0,
                [255, 255, 255],
            );
        }
        c.save(path).unwrap();
    }

    #[test]
    fn every_inspect_command_writes_its_output() {
        let dir = std::env::temp_dir().join(format!("dwslam-inspect-{}", std::process::id()));
        let frames = dir.join("frames");
        std::fs::create_dir_all(&frames).unwrap();
        let (a, b) = (dir.join("a.png"), dir.join("b.png"));
        write_png(&a, 121, 83, 0.0);
        write_png(&b, 121, 83, 3.0);
        for k in 0..3 {
            write_png(&frames.join(format!("{k:03}.png")), 121, 83, k as f32);
        }
        features(&a, &dir.join("f.png"), 20, 3, 50).unwrap();
        let pfm = dir.join("d.pfm");
        stereo(&b, &a, 16, 9, &pfm, Some(&dir.join("d.png"))).unwrap();
        let bytes = std::fs::read(&pfm).unwrap();
        let header = b"Pf\n121 83\n-1\n";
        assert_eq!(&bytes[..header.len()], header);
        assert_eq!(bytes.len(), header.len() + 121 * 83 * 4);
        flow(&a, &b, &dir.join("flow.png"), 10).unwrap();
        track(&frames, &dir.join("tracks"), 10, 50).unwrap();
        assert_eq!(std::fs::read_dir(dir.join("tracks")).unwrap().count(), 3);
        orb_match(&a, &b, &dir.join("m.png"), 100).unwrap();
        // Bad input is an error naming the file, not a panic.
        let missing = dir.join("missing.png");
        let e = features(&missing, &dir.join("x.png"), 20, 3, 10).unwrap_err();
        assert!(format!("{e:#}").contains("missing.png"));
        assert!(stereo(&a, &b, 16, 8, &pfm, None).is_err());
        assert!(
            track(
                &dir.join("empty-dir-that-does-not-exist"),
                &dir.join("t2"),
                3,
                10
            )
            .is_err()
        );
        std::fs::remove_dir_all(&dir).ok();
    }
}

//! Helpers for the real-data tests: locating `shared/data`, EuRoC calibration and ground truth,
//! stereo rectification of EuRoC pairs, Middlebury evaluation, place-recognition scoring.
#![allow(dead_code)]

use geom::{DistortedCamera, PinholeCamera, RadTan};
use lie::{LieGroup, Se3, So3};
use nalgebra::{Matrix3, Matrix4, Vector2, Vector3};
use std::path::{Path, PathBuf};
use vision::image::{GrayImage, Image, load_gray_u8};
use vision::undistort::{StereoRectification, UndistortMap, rectify_stereo};

/// `$DWSLAM_DATA` (if set and non-empty), else `<workspace root>/../shared/data`, joined with
/// `sub`; `None` (after printing that the test skips) if absent — unless
/// `DWSLAM_REQUIRE_DATA=1` (set by `.ci/run`), which turns a missing dataset into a failure, as
/// the `data` crate's `paths::require` does.
pub fn data_dir(sub: &str) -> Option<PathBuf> {
    let root = match std::env::var_os("DWSLAM_DATA") {
        Some(d) if !d.is_empty() => PathBuf::from(d),
        _ => Path::new(env!("CARGO_MANIFEST_DIR")).join("../../../shared/data"),
    };
    let p = root.join(sub);
    if p.exists() {
        return Some(p);
    }
    let test = std::thread::current().name().unwrap_or("test").to_string();
    if std::env::var("DWSLAM_REQUIRE_DATA").is_ok_and(|v| v.trim() == "1") {
        panic!(
            "{test}: {} not found and DWSLAM_REQUIRE_DATA=1 forbids skipping",
            p.display()
        );
    }
    eprintln!(
        "skipping {test}: {} not found (set DWSLAM_DATA)",
        p.display()
    );
    None
}

#[derive(serde::Deserialize)]
struct MatrixYaml {
    data: Vec<f64>,
}

#[derive(serde::Deserialize)]
struct SensorYaml {
    #[serde(rename = "T_BS")]
    t_bs: MatrixYaml,
    intrinsics: Vec<f64>,
    distortion_coefficients: Vec<f64>,
}

/// One EuRoC camera: distorted model and `body_from_sensor`.
pub struct EurocCamera {
    pub camera: DistortedCamera<RadTan>,
    pub body_from_camera: Se3,
}

pub fn se3_from_matrix(m: &Matrix4<f64>) -> Se3 {
    let r: Matrix3<f64> = m.fixed_view::<3, 3>(0, 0).into();
    // Re-orthonormalise (the files carry ~1e-9 non-orthogonality).
    let svd = r.svd(true, true);
    let r = svd.u.unwrap() * svd.v_t.unwrap();
    let q = nalgebra::UnitQuaternion::from_matrix(&r);
    Se3::new(
        So3::from_unit_quaternion(q),
        m.fixed_view::<3, 1>(0, 3).into(),
    )
}

pub fn load_euroc_camera(path: &Path) -> EurocCamera {
    let text = std::fs::read_to_string(path).expect("sensor.yaml");
    let body = text.strip_prefix("%YAML:1.0").unwrap_or(&text);
    let s: SensorYaml = serde_saphyr::from_str(body).expect("parse sensor.yaml");
    let m = Matrix4::from_row_slice(&s.t_bs.data);
    let i = &s.intrinsics;
    let d = &s.distortion_coefficients;
    EurocCamera {
        camera: DistortedCamera::new(
            PinholeCamera::new(i[0], i[1], i[2], i[3]),
            RadTan::new(d[0], d[1], d[2], d[3]),
        ),
        body_from_camera: se3_from_matrix(&m),
    }
}

/// A rectified EuRoC stereo rig.
pub struct EurocStereo {
    pub root: PathBuf,
    pub rect: StereoRectification,
    pub map0: UndistortMap,
    pub map1: UndistortMap,
    pub cam0: EurocCamera,
    pub cam1: EurocCamera,
    pub stamps: Vec<String>,
    pub ground_truth: Vec<(i64, Se3)>,
}

impl EurocStereo {
    pub fn load(root: &Path) -> Self {
        let mav = root.join("mav0");
        let cam0 = load_euroc_camera(&mav.join("cam0/sensor.yaml"));
        let cam1 = load_euroc_camera(&mav.join("cam1/sensor.yaml"));
        let right_from_left = cam1
            .body_from_camera
            .inverse()
            .compose(&cam0.body_from_camera);
        let rect = rectify_stereo(
            &cam0.camera.pinhole,
            &cam1.camera.pinhole,
            &right_from_left.rotation().rotation_matrix(),
            right_from_left.translation(),
            Vector2::new(cam0.camera.pinhole.cx, cam0.camera.pinhole.cy),
        );
        let map0 = UndistortMap::new(
            &cam0.camera,
            &rect.pinhole,
            752,
            480,
            Some(&rect.rect_from_left.transpose()),
        );
        let map1 = UndistortMap::new(
            &cam1.camera,
            &rect.pinhole,
            752,
            480,
            Some(&rect.rect_from_right.transpose()),
        );
        let stamps: Vec<String> = std::fs::read_to_string(mav.join("cam0/data.csv"))
            .expect("data.csv")
            .lines()
            .filter(|l| !l.starts_with('#'))
            .filter_map(|l| l.split(',').next().map(|s| s.trim().to_string()))
            .collect();
        let ground_truth =
            std::fs::read_to_string(mav.join("state_groundtruth_estimate0/data.csv"))
                .expect("ground truth")
                .lines()
                .filter(|l| !l.starts_with('#'))
                .map(|l| {
                    let v: Vec<f64> = l
                        .split(',')
                        .map(|x| x.trim().parse::<f64>().expect("number"))
                        .collect();
                    let t: i64 = l.split(',').next().unwrap().trim().parse().expect("stamp");
                    let q = So3::from_quaternion(v[4], v[5], v[6], v[7]).expect("unit quaternion");
                    (t, Se3::new(q, Vector3::new(v[1], v[2], v[3])))
                })
                .collect();
        Self {
            root: mav,
            rect,
            map0,
            map1,
            cam0,
            cam1,
            stamps,
            ground_truth,
        }
    }

    pub fn left_raw(&self, i: usize) -> GrayImage {
        load_gray_u8(self.root.join(format!("cam0/data/{}.png", self.stamps[i])))
            .expect("left image")
    }
    pub fn right_raw(&self, i: usize) -> GrayImage {
        load_gray_u8(self.root.join(format!("cam1/data/{}.png", self.stamps[i])))
            .expect("right image")
    }
    pub fn rectified(&self, i: usize) -> (GrayImage, GrayImage) {
        (
            self.map0.remap(&self.left_raw(i)),
            self.map1.remap(&self.right_raw(i)),
        )
    }

    /// `world_from_body` at the ground-truth sample nearest to frame `i`'s stamp.
    pub fn world_from_body(&self, i: usize) -> Se3 {
        let t: i64 = self.stamps[i].parse().expect("stamp");
        self.ground_truth
            .iter()
            .min_by_key(|(s, _)| (s - t).abs())
            .expect("ground truth")
            .1
    }

    /// `world_from_rect`: pose of the rectified left camera of frame `i`.
    pub fn world_from_rect(&self, i: usize) -> Se3 {
        let left_from_rect = Se3::new(
            So3::from_unit_quaternion(nalgebra::UnitQuaternion::from_matrix(
                &self.rect.rect_from_left.transpose(),
            )),
            Vector3::zeros(),
        );
        self.world_from_body(i)
            .compose(&self.cam0.body_from_camera)
            .compose(&left_from_rect)
    }
}

/// Non-occluded mask from a left-view ground truth alone: a pixel with disparity `d` is
/// occluded in the right view if it maps outside it (`x − d < 0`) or if another pixel of the
/// row lands on the same right pixel with a disparity larger by more than 1 (it is closer).
/// Unknown ground truth (0) is excluded.
pub fn nonocc_mask(gt: &Image<f32>) -> Image<u8> {
    let (w, h) = (gt.width(), gt.height());
    let mut mask = Image::<u8>::new(w, h);
    for y in 0..h {
        let mut zbuf = vec![f32::NEG_INFINITY; w];
        for x in 0..w {
            let d = gt.get(x, y);
            if d > 0.0 {
                let xr = (x as f32 - d).round();
                if xr >= 0.0 {
                    let xr = xr as usize;
                    zbuf[xr] = zbuf[xr].max(d);
                }
            }
        }
        for x in 0..w {
            let d = gt.get(x, y);
            if d <= 0.0 {
                continue;
            }
            let xr = (x as f32 - d).round();
            if xr < 0.0 {
                continue;
            }
            if d >= zbuf[xr as usize] - 1.0 {
                mask.set(x, y, 1);
            }
        }
    }
    mask
}

/// Middlebury scenes: (name, left, right, ground truth, scale, searched disparities).
pub const MIDDLEBURY: [(&str, &str, &str, &str, f32, usize); 3] = [
    ("tsukuba", "im3.png", "im4.png", "disp3.pgm", 16.0, 16),
    ("venus", "im2.png", "im6.png", "disp2.pgm", 8.0, 32),
    ("teddy", "im2.png", "im6.png", "disp2.png", 4.0, 64),
];

/// A Middlebury pair ready for evaluation: the images, the ground truth in pixels, its
/// non-occluded mask and the matcher's parameters for the scene's disparity range.
pub struct MiddleburyPair {
    pub name: &'static str,
    pub left: GrayImage,
    pub right: GrayImage,
    pub gt: Image<f32>,
    pub mask: Image<u8>,
    pub params: vision::stereo::StereoParams,
}

/// The [`MIDDLEBURY`] pairs of `dir` (the `middlebury_stereo` folder).
pub fn middlebury_pairs(dir: &Path) -> Vec<MiddleburyPair> {
    MIDDLEBURY
        .iter()
        .map(|&(name, l, r, gt, scale, ndisp)| {
            let d = dir.join(name);
            let gt = load_gray_u8(d.join(gt)).unwrap().map(|x| x as f32 / scale);
            MiddleburyPair {
                name,
                left: load_gray_u8(d.join(l)).unwrap(),
                right: load_gray_u8(d.join(r)).unwrap(),
                mask: nonocc_mask(&gt),
                gt,
                params: vision::stereo::StereoParams {
                    max_disparity: ndisp - 1,
                    ..Default::default()
                },
            }
        })
        .collect()
}

/// Bad-pixel rate (|d − gt| > 1, invalid counted as bad) over the non-occluded mask, and the
/// fraction of mask pixels with a valid estimate.
pub fn bad_pixel_rate(disp: &Image<f32>, gt: &Image<f32>, mask: &Image<u8>) -> (f64, f64) {
    let (mut n, mut bad, mut valid) = (0usize, 0usize, 0usize);
    for y in 0..gt.height() {
        for x in 0..gt.width() {
            if mask.get(x, y) == 0 {
                continue;
            }
            n += 1;
            let d = disp.get(x, y);
            if d.is_finite() {
                valid += 1;
                if (d - gt.get(x, y)).abs() > 1.0 {
                    bad += 1;
                }
            } else {
                bad += 1;
            }
        }
    }
    (bad as f64 / n as f64, valid as f64 / n as f64)
}

//! The sequence readers on the shared datasets: image count, sizes, a known pixel or depth
//! value, the calibration, and that ground truth lines up with the frames; EuRoC rectification.
//!
//! Known pixel and depth values were read with Python Pillow 13.0 + numpy (`np.array(
//! Image.open(path))[v, u]`) from the files named in each test; JPEG pixels may differ by a few
//! grey levels between decoders (IDCT rounding), PNG values are exact.

mod common;

use common::{median_abs, reprojection_median, stereo_matches};
use data::camera::{Calibration, LensDistortion, SensorModel};
use data::paths::require;
use data::sequence::{FrameImages, OpenOptions, Sequence, SequenceFormat};
use lie::{LieGroup, Se3};
use nalgebra::Matrix4;

fn open(path: &std::path::Path, raw: bool) -> Sequence {
    Sequence::open(
        path,
        &OpenOptions {
            raw_images: raw,
            ..Default::default()
        },
    )
    .unwrap_or_else(|e| panic!("{e}"))
}

#[test]
fn seven_scenes_reads_with_depth_in_millimetres_and_per_frame_ground_truth() {
    let Some(dir) = require("seven_scenes_redkitchen_1000") else {
        return;
    };
    let seq = open(&dir, false);
    let info = seq.info();
    assert_eq!(info.format, SequenceFormat::Tum);
    assert_eq!(info.frame_count, 1000);
    assert_eq!(info.size, (640, 480));
    // camera-intrinsics.txt: fx = fy = 585, cx = 320, cy = 240; depth in millimetres.
    let Calibration::Rgbd { camera, depth } = info.calibration else {
        panic!("{:?}", info.calibration)
    };
    assert_eq!(
        (
            camera.pinhole.fx,
            camera.pinhole.fy,
            camera.pinhole.cx,
            camera.pinhole.cy
        ),
        (585.0, 585.0, 320.0, 240.0)
    );
    assert_eq!(camera.distortion, LensDistortion::None);
    assert_eq!(depth.metres_per_unit, 1e-3);
    assert_eq!(depth.max_valid_raw, 65535);
    assert!(matches!(info.camera, SensorModel::Rgbd(_)));

    // Frame 0: depth/frame-000000.depth.png at (u, v) = (320, 240) is 1382 (mm); (100, 50) is 0
    // (invalid). rgb/frame-000000.color.jpg at (320, 240) is (236, 212, 174) in Pillow.
    let f0 = seq.read(0).unwrap().unwrap();
    let FrameImages::Rgbd {
        image,
        colour,
        depth,
    } = &f0.images
    else {
        panic!()
    };
    let d = depth.as_ref().expect("frame 0 has depth");
    assert_eq!(d.raw.get(320, 240), 1382);
    assert!((d.metres_at(320, 240).unwrap() - 1.382).abs() < 1e-12);
    assert_eq!(d.metres_at(100, 50), None);
    let c = colour.as_ref().expect("colour planes");
    for (plane, want) in c.iter().zip([236i32, 212, 174]) {
        assert!(
            (plane.get(320, 240) as i32 - want).abs() <= 3,
            "{} vs {want}",
            plane.get(320, 240)
        );
    }
    // The grey image is the Rec. 709 luma of the colour image, as vision's loader computes it
    // (to its rounding: ≤ 1 grey level).
    let gray = vision::image::load_gray_u8(dir.join("rgb/frame-000000.color.jpg")).unwrap();
    let worst = gray
        .data()
        .iter()
        .zip(image.data())
        .map(|(a, b)| (*a as i32 - *b as i32).abs())
        .max();
    assert!(worst <= Some(1), "{worst:?}");
    // Odd frames have no depth image (only even ones are shipped).
    let f1 = seq.read(1).unwrap().unwrap();
    assert!(matches!(f1.images, FrameImages::Rgbd { depth: None, .. }));
    // A monocular run does not decode depth: the same frame 0 without it, the same grey image.
    let mono = Sequence::open(
        &dir,
        &OpenOptions {
            no_depth: true,
            ..OpenOptions::default()
        },
    )
    .unwrap();
    let m0 = mono.read(0).unwrap().unwrap();
    let FrameImages::Rgbd {
        image: m_image,
        depth: None,
        ..
    } = &m0.images
    else {
        panic!("no_depth delivered a depth image")
    };
    assert_eq!(m_image, image);
    assert!((f1.timestamp - 1.0 / 30.0).abs() < 1e-6);

    // Ground truth lines up: frame i carries pose/frame-i.pose.txt (camera-to-world 4×4),
    // parsed here independently (the reader uses groundtruth_tum.txt, re-orthonormalised by
    // its author to ≤ 1.9e-4).
    for i in [0usize, 1, 500, 999] {
        let f = seq.read(i).unwrap().unwrap();
        let text =
            std::fs::read_to_string(dir.join(format!("pose/frame-{i:06}.pose.txt"))).unwrap();
        let v: Vec<f64> = text
            .split_whitespace()
            .map(|x| x.parse().unwrap())
            .collect();
        let m = Matrix4::from_row_slice(&v);
        let gt = f
            .world_from_camera
            .expect("ground truth at every frame")
            .matrix();
        assert!((gt - m).abs().max() < 2e-4, "frame {i}: {gt} vs {m}");
    }
}

#[test]
fn tum_fragment_associates_depth_and_undistorts_with_freiburg1_calibration() {
    let Some(dir) = require("tum_rgbd_fr1_xyz_fragment") else {
        return;
    };
    let raw = open(&dir, true);
    let info = raw.info();
    assert_eq!(info.frame_count, 3);
    assert_eq!(info.size, (640, 480));
    // Freiburg 1 chosen from the folder name ("fr1"): TUM's published calibration.
    let Calibration::Rgbd { camera, depth } = info.calibration else {
        panic!()
    };
    assert_eq!(
        (
            camera.pinhole.fx,
            camera.pinhole.fy,
            camera.pinhole.cx,
            camera.pinhole.cy
        ),
        (517.3, 516.5, 318.6, 255.3)
    );
    let LensDistortion::RadTan(d) = camera.distortion else {
        panic!()
    };
    assert_eq!(
        [d.k1, d.k2, d.p1, d.p2, d.k3],
        [0.2624, -0.9531, -0.0054, 0.0026, 1.1633]
    );
    assert_eq!(depth.metres_per_unit, 1.0 / 5000.0);
    // associate.py pairs rgb 1305031102.211214 with depth 1305031102.226738 (0.0155 s < 0.02);
    // the other two rgb frames are ≥ 0.048 s from it.
    let frames: Vec<_> = (0..3).map(|i| raw.read(i).unwrap().unwrap()).collect();
    let has_depth: Vec<bool> = frames
        .iter()
        .map(|f| matches!(f.images, FrameImages::Rgbd { depth: Some(_), .. }))
        .collect();
    assert_eq!(has_depth, [true, false, false]);
    assert_eq!(frames[0].timestamp, 1305031102.211214);
    // Raw pixels (Pillow): depth (320, 240) = 5177 → 1.0354 m; rgb (320, 240) = (25, 17, 25).
    let FrameImages::Rgbd {
        colour,
        depth: Some(dimg),
        ..
    } = &frames[0].images
    else {
        panic!()
    };
    assert_eq!(dimg.raw.get(320, 240), 5177);
    assert!((dimg.metres_at(320, 240).unwrap() - 1.0354).abs() < 1e-12);
    let c = colour.as_ref().unwrap();
    assert_eq!(
        [c[0].get(320, 240), c[1].get(320, 240), c[2].get(320, 240)],
        [25, 17, 25]
    );

    // Undistorted (the default): pixel q samples the raw luma at K·δ(K⁻¹q). Expected values
    // computed in numpy from the Pillow image (bilinear luma at the distorted position; depth at
    // the nearest pixel): (320, 240) → 19.0, (100, 50) → 128.0, (600, 400) → 251.0,
    // (50, 450) → 171.3; depth (320, 240) → 5177, (100, 50) → 14787 (raw there: 14541).
    let seq = open(&dir, false);
    assert_eq!(
        seq.info().camera,
        SensorModel::Rgbd(geom::RgbdCamera::new(camera.pinhole, 0.075))
    );
    let f = seq.read(0).unwrap().unwrap();
    let FrameImages::Rgbd {
        image,
        depth: Some(ud),
        ..
    } = &f.images
    else {
        panic!()
    };
    for (u, v, want) in [
        (320, 240, 19.0),
        (100, 50, 128.0),
        (600, 400, 251.0),
        (50, 450, 171.3),
    ] {
        assert!(
            (image.get(u, v) as f64 - want).abs() <= 1.0,
            "({u}, {v}): {} vs {want}",
            image.get(u, v)
        );
    }
    assert_eq!(ud.raw.get(320, 240), 5177);
    assert_eq!(ud.raw.get(100, 50), 14787);

    // Ground truth interpolated at the frame times between the bracketing 100 Hz rows
    // (1305031102.2058 and .2159 for frame 0): numpy gives the translation below.
    let p0 = frames[0].world_from_camera.unwrap();
    let want = [1.3315062792125016, 0.625692790708654, 1.6477454652754826];
    for (k, w) in want.iter().enumerate() {
        assert!((p0.translation()[k] - w).abs() < 1e-9);
    }
    let p2 = frames[2].world_from_camera.unwrap();
    let want = [1.2841030640668523, 0.6257, 1.5945869080779944];
    for (k, w) in want.iter().enumerate() {
        assert!((p2.translation()[k] - w).abs() < 1e-9);
    }
}

#[test]
fn euroc_micro_reads_rectified_stereo_with_ground_truth_in_the_left_camera() {
    let Some(dir) = require("euroc_v1_01_easy_micro") else {
        return;
    };
    let raw = open(&dir, true);
    let info = raw.info();
    assert_eq!(info.format, SequenceFormat::Euroc);
    assert_eq!(info.frame_count, 95);
    assert_eq!(info.size, (752, 480));
    // cam0/sensor.yaml: 458.654, 457.296, 367.215, 248.375 and radtan coefficients.
    let Calibration::Stereo {
        left,
        right,
        right_from_left,
    } = info.calibration
    else {
        panic!()
    };
    assert_eq!(
        (
            left.pinhole.fx,
            left.pinhole.fy,
            left.pinhole.cx,
            left.pinhole.cy
        ),
        (458.654, 457.296, 367.215, 248.375)
    );
    assert_eq!((right.pinhole.fx, right.pinhole.cx), (457.587, 379.999));
    let LensDistortion::RadTan(d) = left.distortion else {
        panic!()
    };
    assert_eq!(
        [d.k1, d.k2, d.p1, d.p2],
        [-0.28340811, 0.07395907, 0.00019359, 1.76187114e-05]
    );
    // The cameras are ~11 cm apart along the left camera's x axis.
    let c = right_from_left.inverse();
    assert!((c.translation().norm() - 0.1101).abs() < 1e-3 && c.translation().x > 0.109);
    let SensorModel::Stereo(stereo) = info.camera else {
        panic!()
    };
    assert!((stereo.baseline - c.translation().norm()).abs() < 1e-12);
    assert!((stereo.pinhole.fx - (458.654 + 457.296 + 457.587 + 456.134) / 4.0).abs() < 1e-9);
    // Raw pixels (Pillow): cam0 frame 0 (376, 240) = 89; cam1 = 98.
    let f0 = raw.read(0).unwrap().unwrap();
    let FrameImages::Stereo { left: l, right: r } = &f0.images else {
        panic!()
    };
    assert_eq!((l.get(376, 240), r.get(376, 240)), (89, 98));
    assert_eq!(f0.timestamp, 1403715273262142976.0 / 1e9);

    // Ground truth: every frame has a row (OpenVINS' ground truth at the camera times, within
    // 256 ns). The clip is the MAV standing before take-off (it moves 2 mm and 0.1° in 4.7 s),
    // so a photometric check cannot tell conventions apart here: the poses are checked against
    // state_groundtruth_estimate0/data.csv and cam0's T_BS parsed here independently:
    // world_from_camera = world_from_body · T_BS(cam0) (raw images), and · raw_from_rectified
    // for the rectified images.
    let csv =
        std::fs::read_to_string(dir.join("mav0/state_groundtruth_estimate0/data.csv")).unwrap();
    let rows: Vec<Vec<f64>> = csv
        .lines()
        .filter(|l| !l.starts_with('#'))
        .map(|l| l.split(',').map(|x| x.trim().parse().unwrap()).collect())
        .collect();
    let yaml = std::fs::read_to_string(dir.join("mav0/cam0/sensor.yaml")).unwrap();
    let start = yaml.find("data: [").unwrap() + 7;
    let t_bs: Vec<f64> = yaml[start..start + yaml[start..].find(']').unwrap()]
        .split(',')
        .map(|x| x.trim().parse().unwrap())
        .collect();
    let body_from_cam0 =
        Se3::from_matrix_with_tolerance(&Matrix4::from_row_slice(&t_bs), 1e-6).unwrap();
    let seq = open(&dir, false);
    let rect =
        data::sequence::rectify::StereoRectifier::new(&left, &right, &right_from_left).unwrap();
    let raw_from_rect = Se3::from_rotation(
        lie::So3::from_matrix_with_tolerance(&rect.rect_from_left.transpose(), 1e-9).unwrap(),
    );
    for i in [0usize, 47, 94] {
        let (fr, fd) = (raw.read(i).unwrap().unwrap(), seq.read(i).unwrap().unwrap());
        let row = rows
            .iter()
            .find(|r| (r[0] / 1e9 - fr.timestamp).abs() < 1e-6)
            .expect("a ground-truth row at the frame time");
        let world_from_body = Se3::from_quaternion_translation(
            row[4],
            row[5],
            row[6],
            row[7],
            nalgebra::Vector3::new(row[1], row[2], row[3]),
        )
        .unwrap();
        let want_raw = world_from_body.compose(&body_from_cam0);
        let want_rect = want_raw.compose(&raw_from_rect);
        assert!(
            (fr.world_from_camera.unwrap().matrix() - want_raw.matrix())
                .abs()
                .max()
                < 1e-9
        );
        assert!(
            (fd.world_from_camera.unwrap().matrix() - want_rect.matrix())
                .abs()
                .max()
                < 1e-9
        );
    }
    assert!((0..95).all(|i| seq.read(i).unwrap().unwrap().world_from_camera.is_some()));
    // The left camera looks along the body's x axis (EuRoC's VI-sensor): T_BS's rotation maps
    // the camera z axis to ≈ body x… (0.0041, 0.0257, 0.9997) → body z; sanity of the parse.
    assert!((body_from_cam0.rotation().rotation_matrix()[(2, 2)] - 0.999660727178).abs() < 1e-9);
}

#[test]
fn euroc_rectified_rows_agree_to_half_a_pixel() {
    let Some(dir) = require("euroc_v1_01_easy_micro") else {
        return;
    };
    let mut stats = Vec::new();
    for raw in [false, true] {
        let seq = open(&dir, raw);
        let mut dv = Vec::new();
        for i in (0..seq.len()).step_by(10) {
            let f = seq.read(i).unwrap().unwrap();
            let FrameImages::Stereo { left, right } = &f.images else {
                panic!()
            };
            // Correspondences searched ±12 rows (not on the row: the row offset is measured).
            for m in stereo_matches(left, right, 12.0, 100.0) {
                dv.push((m.right[1] - m.left[1]) as f64);
            }
        }
        stats.push((median_abs(&dv), dv.len()));
    }
    let ((rect, n), (raw, n_raw)) = (stats[0], stats[1]);
    eprintln!(
        "EuRoC |v_r − v_l| median: rectified {rect:.3} px ({n} matches), raw {raw:.3} px ({n_raw} matches)"
    );
    assert!(n >= 200, "{n} matches");
    assert!(rect <= 0.5, "rectified rows differ by {rect} px (median)");
    // The same measurement tells unrectified images apart (the test can fail).
    assert!(raw > 2.0, "raw {raw}");
}

#[test]
fn kitti_snippet_reads_left_and_right_with_labelless_calib() {
    let Some(dir) = require("kitti_odometry_snippets/KITTI_sequence_1") else {
        return;
    };
    let seq = open(&dir, false);
    let info = seq.info();
    assert_eq!(info.format, SequenceFormat::Kitti);
    assert_eq!(info.frame_count, 51);
    assert_eq!(info.size, (1226, 370));
    // calib.txt (no P0: labels): fx = 707.0912, cx = 601.8873, cy = 183.1104,
    // P1[0,3] = −379.8145 → baseline 379.8145/707.0912 m.
    let SensorModel::Stereo(s) = info.camera else {
        panic!()
    };
    assert_eq!(
        (s.pinhole.fx, s.pinhole.fy, s.pinhole.cx, s.pinhole.cy),
        (707.0912, 707.0912, 601.8873, 183.1104)
    );
    assert!((s.baseline - 379.8145 / 707.0912).abs() < 1e-12);
    // Pillow: image_l/000000.png (613, 185) = 86, image_r/000050.png (613, 185) = 100.
    let f0 = seq.read(0).unwrap().unwrap();
    let f50 = seq.read(50).unwrap().unwrap();
    let (FrameImages::Stereo { left: l0, .. }, FrameImages::Stereo { right: r50, .. }) =
        (&f0.images, &f50.images)
    else {
        panic!()
    };
    assert_eq!((l0.get(613, 185), r50.get(613, 185)), (86, 100));
    assert!(
        (f50.timestamp - 5.0).abs() < 1e-12,
        "10 Hz without times.txt"
    );
    // Ground truth: line i of poses.txt is frame i (line 0 the identity).
    let poses = data::trajectory::read_kitti(dir.join("poses.txt")).unwrap();
    for i in [0usize, 1, 25, 50] {
        let f = seq.read(i).unwrap().unwrap();
        assert_eq!(f.world_from_camera.unwrap(), poses[i]);
    }
    // Physically: stereo points of frame a moved by the ground truth land on frame a+1's
    // corners (the car drives ~1.2 m per frame); the inverse motion or no motion do not.
    for a in [10usize, 20, 30] {
        let fa = seq.read(a).unwrap().unwrap();
        let fb = seq.read(a + 1).unwrap().unwrap();
        let FrameImages::Stereo {
            left: la,
            right: ra,
        } = &fa.images
        else {
            panic!()
        };
        let b_from_a = poses[a + 1].inverse().compose(&poses[a]);
        let (gt, n) = reprojection_median(&s, la, ra, fb.gray(), &b_from_a);
        let (inv, _) = reprojection_median(&s, la, ra, fb.gray(), &b_from_a.inverse());
        let (still, _) = reprojection_median(&s, la, ra, fb.gray(), &Se3::identity());
        eprintln!(
            "KITTI frames {a}→{}: ground truth {gt:.2} px over {n} points, inverse {inv:.2}, no motion {still:.2}",
            a + 1
        );
        assert!(
            n >= 100 && gt < 2.0 && gt < 0.3 * still && gt < 0.3 * inv,
            "{gt} {n} {inv} {still}"
        );
    }
}

#[test]
fn the_left_folder_alone_is_read_as_monocular_kitti() {
    let Some(dir) = require("kitti_odometry_snippets/KITTI_sequence_1") else {
        return;
    };
    let tmp = tempdir("kitti-left");
    std::os::unix::fs::symlink(dir.join("image_l"), tmp.join("image_0")).unwrap();
    std::fs::copy(dir.join("calib.txt"), tmp.join("calib.txt")).unwrap();
    let seq = open(&tmp, false);
    assert!(matches!(seq.info().camera, SensorModel::Mono(_)));
    assert_eq!(seq.len(), 51);
    assert_eq!(seq.read(0).unwrap().unwrap().gray().get(613, 185), 86);
}

fn tempdir(name: &str) -> std::path::PathBuf {
    let d = std::env::temp_dir().join(format!("dwslam-seq-{name}-{}", std::process::id()));
    let _ = std::fs::remove_dir_all(&d);
    std::fs::create_dir_all(&d).unwrap();
    d
}

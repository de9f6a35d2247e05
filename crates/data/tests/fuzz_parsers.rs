//! Property-based fuzzing of every text parser of the sequence layouts, camera files and
//! trajectories: random text, and valid files with random edits, give `Ok` or an error, never a
//! panic (500 cases per parser and generator).

use data::camera_file::parse_camera_file;
use data::sequence::lists::{
    kitti_stereo, parse_euroc_body_from_sensor, parse_euroc_camera_yaml, parse_euroc_image_list,
    parse_intrinsics_matrix, parse_kitti_calib, parse_tum_list,
};
use data::trajectory::{detect_trajectory_format, parse_euroc_groundtruth, parse_kitti, parse_tum};
use proptest::prelude::*;
use std::path::Path;

const TUM_LIST: &str = "# color images\n1305031102.175304 rgb/1305031102.175304.png\n1305031102.211214 rgb/1305031102.211214.png\n";
const EUROC_LIST: &str = "#timestamp [ns],filename\n1403715273262142976,1403715273262142976.png\n1403715273312143104,1403715273312143104.png\n";
const EUROC_YAML: &str = "%YAML:1.0\nsensor_type: camera\nT_BS:\n  cols: 4\n  rows: 4\n  data: [0.0148655429818, -0.999880929698, 0.00414029679422, -0.0216401454975,\n         0.999557249008, 0.0149672133247, 0.025715529948, -0.064676986768,\n        -0.0257744366974, 0.00375618835797, 0.999660727178, 0.00981073058949,\n         0.0, 0.0, 0.0, 1.0]\nrate_hz: 20\nresolution: [752, 480]\ncamera_model: pinhole\nintrinsics: [458.654, 457.296, 367.215, 248.375]\ndistortion_model: radial-tangential\ndistortion_coefficients: [-0.28340811, 0.07395907, 0.00019359, 1.76187114e-05]\n";
const KITTI_CALIB: &str = "P0: 7.070912e+02 0 6.018873e+02 0 0 7.070912e+02 1.831104e+02 0 0 0 1 0\nP1: 7.070912e+02 0 6.018873e+02 -3.798145e+02 0 7.070912e+02 1.831104e+02 0 0 0 1 0\nTr: 1 0 0 0 0 1 0 0 0 0 1 0\n";
const K_MATRIX: &str = "5.85e+02 0 3.2e+02\n0 5.85e+02 2.4e+02\n0 0 1\n";
const DWSLAM_YAML: &str = "dwslam_camera: 1\nsensor: stereo\nfps: 20\nleft: { width: 752, height: 480, fx: 458.6, fy: 457.3, cx: 367.2, cy: 248.4, distortion: { model: radtan, coefficients: [-0.28, 0.07, 0.0002, 0.00002] } }\nright: { width: 752, height: 480, fx: 457.6, fy: 456.1, cx: 380.0, cy: 255.2 }\nright_from_left: { rotation: [1, 0, 0, 0, 1, 0, 0, 0, 1], translation: [-0.11, 0, 0] }\n";
const ORB_YAML: &str = "%YAML:1.0\nFile.version: \"1.0\"\nCamera.type: \"PinHole\"\nCamera1.fx: 458.654\nCamera1.fy: 457.296\nCamera1.cx: 367.215\nCamera1.cy: 248.375\nCamera1.k1: -0.28340811\nCamera1.k2: 0.07395907\nCamera1.p1: 0.00019359\nCamera1.p2: 1.76187114e-05\nCamera.width: 752\nCamera.height: 480\nStereo.T_c1_c2: !!opencv-matrix\n  rows: 4\n  cols: 4\n  dt: f\n  data: [1, 0, 0, 0.11, 0, 1, 0, 0, 0, 0, 1, 0, 0, 0, 0, 1]\nRGBD.DepthMapFactor: 5000.0\n";
const TUM_TRAJ: &str = "# t tx ty tz qx qy qz qw\n1305031098.6659 1.3563 0.6305 1.6380 0.6132 0.5962 -0.3311 -0.3986\n1305031098.6758 1.3543 0.6306 1.6360 0.6129 0.5966 -0.3316 -0.3980\n";
const KITTI_TRAJ: &str = "1 0 0 0 0 1 0 0 0 0 1 0\n9.999995e-01 7.196824e-04 -6.870876e-04 -1.401751e-02 -7.197717e-04 9.999997e-01 -1.295633e-04 -2.820321e-02 6.869946e-04 1.300585e-04 9.999998e-01 1.198998e+00\n";
const EUROC_GT: &str = "#time(ns),px,py,pz,qw,qx,qy,qz,vx,vy,vz\n1403715273262142976,0.878895,2.1834,0.948427,0.069433,-0.824237,-0.106942,-0.551702,0.001,0.001,-0.002\n";

/// Text made of the characters these formats use.
fn soup() -> impl Strategy<Value = String> {
    proptest::string::string_regex("[0-9a-zA-Z .,:;#\\-+e\\[\\]{}\"'!%_/\n\t]{0,400}").unwrap()
}

/// A valid file with random edits: characters replaced, inserted, deleted, lines duplicated or
/// cut.
fn mutated(valid: &'static str) -> impl Strategy<Value = String> {
    let edits = proptest::collection::vec(
        (
            0usize..4,
            any::<prop::sample::Index>(),
            proptest::char::range(' ', '~'),
        ),
        1..8,
    );
    (edits, any::<prop::sample::Index>()).prop_map(move |(edits, cut)| {
        let mut s: Vec<char> = valid.chars().collect();
        for (kind, at, c) in edits {
            if s.is_empty() {
                s.push(c);
                continue;
            }
            let i = at.index(s.len());
            match kind {
                0 => s[i] = c,
                1 => s.insert(i, c),
                2 => {
                    s.remove(i);
                }
                _ => s.insert(i, '\n'),
            }
        }
        let text: String = s.into_iter().collect();
        if cut.index(4) == 0 {
            let n = cut.index(text.len() + 1);
            text.chars().take(n).collect()
        } else {
            text
        }
    })
}

fn all_parsers(text: &str) {
    let p = Path::new("fuzz.txt");
    let _ = parse_tum_list(text, p);
    let _ = parse_euroc_image_list(text, p);
    let _ = parse_euroc_camera_yaml(text, p);
    let _ = parse_euroc_body_from_sensor(text, p);
    if let Ok(m) = parse_kitti_calib(text, p) {
        let _ = kitti_stereo(&m, p);
    }
    let _ = parse_intrinsics_matrix(text, p);
    let _ = parse_camera_file(text, p);
    if let Ok(c) = parse_camera_file(text, p) {
        for kind in [
            data::camera::SensorKind::Mono,
            data::camera::SensorKind::Stereo,
            data::camera::SensorKind::Rgbd,
        ] {
            let _ = c.calibration(kind, (640, 480), p);
        }
    }
    let _ = detect_trajectory_format(text, p);
    let _ = parse_tum(text, p);
    let _ = parse_kitti(text, p);
    let _ = parse_euroc_groundtruth(text, p);
    let _ = serde_json::from_str::<data::output::Summary>(text);
}

proptest! {
    #![proptest_config(ProptestConfig::with_cases(500))]

    #[test]
    fn random_text_never_panics(text in soup()) {
        all_parsers(&text);
    }

    #[test]
    fn edited_tum_list_never_panics(text in mutated(TUM_LIST)) { all_parsers(&text); }

    #[test]
    fn edited_euroc_list_never_panics(text in mutated(EUROC_LIST)) { all_parsers(&text); }

    #[test]
    fn edited_euroc_sensor_yaml_never_panics(text in mutated(EUROC_YAML)) { all_parsers(&text); }

    #[test]
    fn edited_kitti_calib_never_panics(text in mutated(KITTI_CALIB)) { all_parsers(&text); }

    #[test]
    fn edited_intrinsics_never_panics(text in mutated(K_MATRIX)) { all_parsers(&text); }

    #[test]
    fn edited_dwslam_camera_yaml_never_panics(text in mutated(DWSLAM_YAML)) { all_parsers(&text); }

    #[test]
    fn edited_orb_slam3_settings_never_panics(text in mutated(ORB_YAML)) { all_parsers(&text); }

    #[test]
    fn edited_trajectories_never_panic(tum in mutated(TUM_TRAJ), kitti in mutated(KITTI_TRAJ), euroc in mutated(EUROC_GT)) {
        all_parsers(&tum);
        all_parsers(&kitti);
        all_parsers(&euroc);
    }
}

#[test]
fn the_valid_samples_parse() {
    let p = Path::new("sample");
    assert_eq!(parse_tum_list(TUM_LIST, p).unwrap().len(), 2);
    assert_eq!(parse_euroc_image_list(EUROC_LIST, p).unwrap().len(), 2);
    assert_eq!(
        parse_euroc_camera_yaml(EUROC_YAML, p).unwrap().resolution,
        (752, 480)
    );
    let calib = parse_kitti_calib(KITTI_CALIB, p).unwrap();
    assert!((kitti_stereo(&calib, p).unwrap().1 - 379.8145 / 707.0912).abs() < 1e-12);
    assert_eq!(parse_intrinsics_matrix(K_MATRIX, p).unwrap().fx, 585.0);
    let d = parse_camera_file(DWSLAM_YAML, p).unwrap();
    assert!(matches!(
        d.calibration(data::camera::SensorKind::Stereo, (752, 480), p)
            .unwrap(),
        data::camera::Calibration::Stereo { .. }
    ));
    let o = parse_camera_file(ORB_YAML, p).unwrap();
    assert_eq!(o.style, data::camera_file::CameraFileStyle::OrbSlamCamera1);
    assert!((o.right_from_left.unwrap().translation().x + 0.11).abs() < 1e-3);
    assert_eq!(o.depth.unwrap().metres_per_unit, 1.0 / 5000.0);
    assert_eq!(parse_tum(TUM_TRAJ, p).unwrap().len(), 2);
    assert_eq!(parse_kitti(KITTI_TRAJ, p).unwrap().len(), 2);
    assert_eq!(parse_euroc_groundtruth(EUROC_GT, p).unwrap().len(), 1);
}

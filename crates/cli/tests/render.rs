//! `dwslam render` (issue 17): arguments are checked before any work, and rendered sequences read
//! back through the sequence readers (`data::sequence`, issue 16) — no special case for rendered
//! data — with the same calibration and the same ground-truth poses (≤ 1e-9), and the images and
//! depth that were rendered.

use data::camera::{Calibration, CameraIntrinsics, LensDistortion};
use data::dataset_writer::tum_depth_value;
use data::sequence::{
    FrameImages as ReadImages, OpenOptions, Sequence as ReadSequence, SequenceFormat,
};
use geom::{PinholeCamera, RadTan};
use lie::{LieGroup, Se3};
use sim::render::{FrameImages, SceneKind, SensorKind, SensorModel, Sequence, SequenceConfig};
use std::path::{Path, PathBuf};
use std::process::Command;

fn scratch(name: &str) -> PathBuf {
    let dir = std::env::temp_dir().join(format!("dwslam-render-{}-{name}", std::process::id()));
    let _ = std::fs::remove_dir_all(&dir);
    dir
}

fn dwslam(args: &[&str]) -> std::process::Output {
    Command::new(env!("CARGO_BIN_EXE_dwslam"))
        .args(args)
        .env("RUST_BACKTRACE", "1")
        .output()
        .expect("the binary runs")
}

fn render(args: &[&str], out: &Path) {
    let mut all = vec!["render"];
    all.extend_from_slice(args);
    all.extend_from_slice(&["--out", out.to_str().unwrap()]);
    let o = dwslam(&all);
    assert!(
        o.status.success(),
        "dwslam {all:?}:\n{}",
        String::from_utf8_lossy(&o.stderr)
    );
}

/// The renderer's own sequence for the same arguments (the ground truth and the images).
fn truth(scene: SceneKind, sensor: SensorModel, seed: u64, frames: usize) -> Sequence {
    Sequence::new(SequenceConfig {
        scene,
        sensor,
        seed,
        path_seed: None,
        frames: Some(frames),
        revisit_jitter: sim::render::DEFAULT_REVISIT_JITTER,
    })
    .unwrap()
}

/// The largest difference of two poses: translation (m) and rotation (rad).
fn pose_error(a: &Se3, b: &Se3) -> f64 {
    let d = a.inverse().compose(b);
    d.translation().norm().max(d.rotation().angle())
}

fn default_camera() -> CameraIntrinsics {
    CameraIntrinsics::ideal(PinholeCamera::new(525.0, 525.0, 319.5, 239.5), 640, 480)
}

/// The same camera: intrinsics and size equal, and the same distortion (a zero
/// radial-tangential model, as EuRoC's `sensor.yaml` always states one, is no distortion).
fn same_camera(a: &CameraIntrinsics, b: &CameraIntrinsics) -> bool {
    a.pinhole == b.pinhole
        && (a.width, a.height) == (b.width, b.height)
        && (a.distortion == b.distortion
            || (a.distortion.is_identity() && b.distortion.is_identity()))
}

#[test]
fn bad_arguments_fail_before_any_work() {
    let dir = scratch("bad");
    std::fs::create_dir_all(&dir).unwrap();
    let file = dir.join("a-file");
    std::fs::write(&file, "x").unwrap();
    let full = dir.join("full");
    std::fs::create_dir_all(&full).unwrap();
    std::fs::write(full.join("old.png"), "x").unwrap();
    let fresh = dir.join("never-created");
    let f = fresh.to_str().unwrap();
    let below = file.join("below");
    let cases: Vec<(Vec<&str>, &str)> = vec![
        (
            vec!["render", "kitchen", "--sensor", "mono", "--out", f],
            "kitchen",
        ),
        (
            vec![
                "render", "room", "--sensor", "mono", "--layout", "tum", "--out", f,
            ],
            "--layout tum",
        ),
        (
            vec![
                "render", "room", "--sensor", "rgbd", "--layout", "kitti", "--out", f,
            ],
            "not RGB-D",
        ),
        (
            vec![
                "render",
                "room",
                "--sensor",
                "stereo",
                "--radtan",
                "0.1,0,0,0",
                "--layout",
                "kitti",
                "--out",
                f,
            ],
            "rectified",
        ),
        (
            vec![
                "render", "room", "--sensor", "mono", "--size", "640", "--out", f,
            ],
            "--size",
        ),
        (
            vec![
                "render", "room", "--sensor", "mono", "--size", "8x8", "--out", f,
            ],
            "16…8192",
        ),
        (
            vec![
                "render", "room", "--sensor", "mono", "--frames", "0", "--out", f,
            ],
            "--frames",
        ),
        (
            vec![
                "render",
                "room",
                "--sensor",
                "stereo",
                "--baseline=-1",
                "--out",
                f,
            ],
            "--baseline",
        ),
        (
            vec![
                "render", "room", "--sensor", "mono", "--radtan", "1,2", "--out", f,
            ],
            "--radtan",
        ),
        (
            vec![
                "render",
                "room",
                "--sensor",
                "mono",
                "--supersampling",
                "0",
                "--out",
                f,
            ],
            "supersampling",
        ),
        (
            vec![
                "render",
                "room",
                "--sensor",
                "mono",
                "--out",
                file.to_str().unwrap(),
            ],
            "is a file",
        ),
        (
            vec![
                "render",
                "room",
                "--sensor",
                "mono",
                "--out",
                full.to_str().unwrap(),
            ],
            "not empty",
        ),
        (
            vec![
                "render",
                "room",
                "--sensor",
                "mono",
                "--out",
                below.to_str().unwrap(),
            ],
            "--out",
        ),
        (
            vec![
                "render",
                "room",
                "--sensor",
                "rgbd",
                "--revisit-jitter",
                "-0.5",
                "--out",
                f,
            ],
            "--revisit-jitter",
        ),
        (
            vec![
                "render",
                "courtyard",
                "--sensor",
                "stereo",
                "--revisit-jitter",
                "0.25",
                "--out",
                f,
            ],
            "room",
        ),
    ];
    for (args, expect) in cases {
        let start = std::time::Instant::now();
        let o = dwslam(&args);
        let stderr = String::from_utf8_lossy(&o.stderr);
        assert!(!o.status.success(), "{args:?} succeeded");
        assert!(
            stderr.contains(expect),
            "{args:?}: expected {expect:?} in\n{stderr}"
        );
        assert!(!stderr.contains("backtrace"), "{args:?}:\n{stderr}");
        assert!(
            start.elapsed().as_secs_f64() < 3.0,
            "{args:?}: work started before the check"
        );
    }
    assert!(!fresh.exists(), "a refused run created its output folder");
    std::fs::remove_dir_all(&dir).unwrap();
}

#[test]
fn tum_rgbd_round_trip() {
    let out = scratch("tum");
    render(
        &["room", "--sensor", "rgbd", "--frames", "4", "--seed", "3"],
        &out,
    );
    let seq = ReadSequence::open(&out, &OpenOptions::default()).unwrap();
    let info = seq.info();
    assert_eq!(info.format, SequenceFormat::Tum);
    assert_eq!(info.frame_count, 4);
    let Calibration::Rgbd { camera, depth } = info.calibration else {
        panic!("{:?}", info.calibration)
    };
    assert_eq!(camera, default_camera());
    assert_eq!(depth.metres_per_unit, 1.0 / 5000.0);
    // The written camera file gives the same calibration.
    let with_file = ReadSequence::open(
        &out,
        &OpenOptions {
            camera_file: Some(out.join("camera.yaml")),
            ..OpenOptions::default()
        },
    )
    .unwrap();
    assert_eq!(with_file.info().calibration, info.calibration);
    std::fs::remove_dir_all(&out).unwrap();
    // The camera.yaml beside rgb.txt is the sequence's calibration (no --camera needed): a
    // smaller image has a shorter focal length than TUM's 525.
    render(
        &[
            "room", "--sensor", "rgbd", "--frames", "2", "--size", "320x240",
        ],
        &out,
    );
    let small = ReadSequence::open(&out, &OpenOptions::default()).unwrap();
    let Calibration::Rgbd { camera: c, .. } = small.info().calibration else {
        panic!("{:?}", small.info().calibration)
    };
    assert_eq!((c.width, c.height, c.pinhole.fx), (320, 240, 262.5));
    assert!(
        small.info().warnings.is_empty(),
        "{:?}",
        small.info().warnings
    );
    std::fs::remove_dir_all(&out).unwrap();
    render(
        &["room", "--sensor", "rgbd", "--frames", "4", "--seed", "3"],
        &out,
    );
    let mut own = truth(
        SceneKind::Room,
        SensorModel::new(SensorKind::Rgbd, 640, 480),
        3,
        4,
    );
    for k in 0..4 {
        let frame = seq.read(k).unwrap().unwrap();
        let rendered = own.render_frame(k).unwrap();
        assert!((frame.timestamp - rendered.timestamp_us as f64 * 1e-6).abs() < 1e-6);
        // What `dwslam demo` feeds the live system without writing files is what the reader
        // delivers for the written ones (the camera too).
        let direct = rendered.to_sequence_frame();
        assert_eq!(
            direct.images, frame.images,
            "frame {k}: images on the fly and read back"
        );
        assert_eq!(direct.index, frame.index);
        assert!((direct.timestamp - frame.timestamp).abs() < 1e-6);
        assert_eq!(
            own.config().sensor.sequence_camera(),
            Some(info.camera),
            "the camera of frames rendered on the fly"
        );
        let e = pose_error(
            &frame.world_from_camera.unwrap(),
            &rendered.world_from_camera,
        );
        assert!(e <= 1e-9, "frame {k}: pose differs by {e}");
        let (ReadImages::Rgbd { colour, depth, .. }, FrameImages::Rgbd { rgb, depth: z }) =
            (&frame.images, &rendered.images)
        else {
            panic!("rgbd frames")
        };
        let planes = colour.as_ref().expect("colour planes");
        let raw = &depth.as_ref().expect("a depth image").raw;
        for v in (0..480).step_by(13) {
            for u in (0..640).step_by(11) {
                let c = rgb.get(u, v);
                assert_eq!(
                    [
                        planes[0].get(u, v),
                        planes[1].get(u, v),
                        planes[2].get(u, v)
                    ],
                    c
                );
                assert_eq!(
                    raw.get(u, v),
                    tum_depth_value(z.get(u, v)),
                    "frame {k} ({u}, {v})"
                );
            }
        }
    }
    std::fs::remove_dir_all(&out).unwrap();
}

#[test]
fn euroc_stereo_round_trip() {
    let out = scratch("euroc");
    render(
        &[
            "courtyard",
            "--sensor",
            "stereo",
            "--frames",
            "3",
            "--baseline",
            "0.2",
        ],
        &out,
    );
    let options = OpenOptions {
        raw_images: true,
        ..OpenOptions::default()
    };
    let seq = ReadSequence::open(&out, &options).unwrap();
    let info = seq.info();
    assert_eq!(info.format, SequenceFormat::Euroc);
    let Calibration::Stereo {
        left,
        right,
        right_from_left,
    } = info.calibration
    else {
        panic!("{:?}", info.calibration)
    };
    assert!(same_camera(&left, &default_camera()), "{left:?}");
    assert!(same_camera(&right, &default_camera()), "{right:?}");
    assert!(pose_error(&right_from_left, &SensorModel::right_from_left(0.2)) <= 1e-12);
    let mut own = truth(
        SceneKind::Courtyard,
        SensorModel::new(SensorKind::Stereo { baseline: 0.2 }, 640, 480),
        1,
        3,
    );
    for k in 0..3 {
        let frame = seq.read(k).unwrap().unwrap();
        let rendered = own.render_frame(k).unwrap();
        let e = pose_error(
            &frame.world_from_camera.unwrap(),
            &rendered.world_from_camera,
        );
        assert!(e <= 1e-9, "frame {k}: pose differs by {e}");
        let (ReadImages::Stereo { left, right }, FrameImages::Stereo { left: l, right: r }) =
            (&frame.images, &rendered.images)
        else {
            panic!("stereo frames")
        };
        assert_eq!((left, right), (l, r), "frame {k}: images differ");
    }
    std::fs::remove_dir_all(&out).unwrap();
}

#[test]
fn euroc_mono_with_distortion_round_trip() {
    let out = scratch("euroc-mono");
    let radtan = "-0.28340811,0.07395907,0.00019359,1.76187114e-05";
    render(
        &[
            "building", "--sensor", "mono", "--layout", "euroc", "--frames", "2", "--radtan",
            radtan,
        ],
        &out,
    );
    let seq = ReadSequence::open(&out, &OpenOptions::default()).unwrap();
    let Calibration::Mono { camera } = seq.info().calibration else {
        panic!("{:?}", seq.info().calibration)
    };
    let mut expected = default_camera();
    expected.distortion = LensDistortion::RadTan(RadTan::new(
        -0.28340811,
        0.07395907,
        0.00019359,
        1.76187114e-05,
    ));
    assert_eq!(camera, expected);
    let mut sensor = SensorModel::new(SensorKind::Mono, 640, 480);
    sensor.camera.distortion = Some(RadTan::new(
        -0.28340811,
        0.07395907,
        0.00019359,
        1.76187114e-05,
    ));
    let own = truth(SceneKind::Building, sensor, 1, 2);
    for k in 0..2 {
        let frame = seq.read(k).unwrap().unwrap();
        let e = pose_error(&frame.world_from_camera.unwrap(), &own.world_from_camera(k));
        assert!(e <= 1e-9, "frame {k}: pose differs by {e}");
    }
    std::fs::remove_dir_all(&out).unwrap();
}

#[test]
fn kitti_mono_and_stereo_round_trip() {
    for (sensor, kind) in [
        ("mono", SensorKind::Mono),
        ("stereo", SensorKind::Stereo { baseline: 0.11 }),
    ] {
        let out = scratch(&format!("kitti-{sensor}"));
        render(
            &[
                "building", "--sensor", sensor, "--layout", "kitti", "--frames", "3", "--size",
                "320x240",
            ],
            &out,
        );
        let seq = ReadSequence::open(&out, &OpenOptions::default()).unwrap();
        let info = seq.info();
        assert_eq!(info.format, SequenceFormat::Kitti);
        let camera =
            CameraIntrinsics::ideal(PinholeCamera::new(262.5, 262.5, 159.5, 119.5), 320, 240);
        match (info.calibration, kind) {
            (Calibration::Mono { camera: c }, SensorKind::Mono) => assert_eq!(c, camera),
            (
                Calibration::RectifiedStereo {
                    camera: c,
                    baseline,
                },
                SensorKind::Stereo { .. },
            ) => {
                assert_eq!(c, camera);
                assert!((baseline - 0.11).abs() < 1e-12, "{baseline}");
            }
            (c, _) => panic!("{sensor}: {c:?}"),
        }
        let mut own = truth(SceneKind::Building, SensorModel::new(kind, 320, 240), 1, 3);
        let first = own.world_from_camera(0);
        for k in 0..3 {
            let frame = seq.read(k).unwrap().unwrap();
            // KITTI poses are camera 0 in the first frame's camera 0.
            let expected = first.inverse().compose(&own.world_from_camera(k));
            let e = pose_error(&frame.world_from_camera.unwrap(), &expected);
            assert!(e <= 1e-9, "{sensor} frame {k}: pose differs by {e}");
            let rendered = own.render_frame(k).unwrap();
            match (&frame.images, &rendered.images) {
                (ReadImages::Mono { image, .. }, FrameImages::Mono(g)) => assert_eq!(image, g),
                (ReadImages::Stereo { left, right }, FrameImages::Stereo { left: l, right: r }) => {
                    assert_eq!((left, right), (l, r))
                }
                _ => panic!("{sensor}: other images"),
            }
        }
        std::fs::remove_dir_all(&out).unwrap();
    }
}

#[test]
fn revisit_jitter_reaches_the_written_ground_truth() {
    let out = scratch("revisit");
    render(
        &[
            "room",
            "--sensor",
            "rgbd",
            "--frames",
            "3",
            "--size",
            "160x120",
            "--revisit-jitter",
            "0.25",
        ],
        &out,
    );
    let seq = ReadSequence::open(&out, &OpenOptions::default()).unwrap();
    let sensor = SensorModel::new(SensorKind::Rgbd, 160, 120);
    let config = |revisit_jitter| SequenceConfig {
        scene: SceneKind::Room,
        sensor,
        seed: 1,
        path_seed: None,
        frames: Some(3),
        revisit_jitter,
    };
    let (own, default) = (
        Sequence::new(config(0.25)).unwrap(),
        Sequence::new(config(1.0)).unwrap(),
    );
    for k in 0..3 {
        let read = seq.read(k).unwrap().unwrap().world_from_camera.unwrap();
        let e = pose_error(&read, &own.world_from_camera(k));
        assert!(e <= 1e-9, "frame {k}: pose differs by {e}");
        // Not the default browsing: the first view's variation is scaled down.
        let d = pose_error(&read, &default.world_from_camera(k));
        assert!(d > 1e-3, "frame {k}: the default pose ({d})");
    }
    std::fs::remove_dir_all(&out).unwrap();
}

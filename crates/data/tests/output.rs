//! The run writers: every frame's trajectory in TUM (read back by our TUM reader, which reads
//! what evo reads) and KITTI, keyframes, PLY (parsed back here), summary.json, the incremental
//! log, and `dwslam eval`'s file discovery.

use data::output::{
    FrameRecord, KeyframeRecord, MapPoint, OutputOptions, PlyFormat, RunOutput, RunRecord,
    TrackingState, find_run_files, read_summary, write_ply,
};
use data::trajectory::{read_kitti, read_tum};
use lie::{LieGroup, Se3};
use nalgebra::{Vector3, Vector6};
use std::time::Duration;

fn record() -> RunRecord {
    let mut r = RunRecord {
        sequence: "seq".into(),
        sensor: "rgbd".into(),
        ..Default::default()
    };
    for i in 0..5 {
        let pose = Se3::exp(&Vector6::new(
            0.1 * i as f64,
            0.0,
            0.02,
            0.0,
            0.01 * i as f64,
            0.0,
        ));
        r.frames.push(FrameRecord {
            index: i,
            timestamp: 10.0 + i as f64 / 30.0,
            world_from_camera: (i != 3).then_some(pose),
            state: match i {
                2 => TrackingState::Weak("42 of 150 points matched".into()),
                3 => TrackingState::Lost("no points matched".into()),
                _ => TrackingState::Good,
            },
        });
        r.timings
            .record("tracking", Duration::from_micros(1000 + 100 * i as u64));
    }
    r.keyframes.push(KeyframeRecord {
        id: 0,
        frame_index: 0,
        timestamp: 10.0,
        world_from_camera: Se3::identity(),
    });
    r.points = vec![
        MapPoint {
            position: Vector3::new(1.0, 2.0, 3.0),
            colour: Some([10, 20, 30]),
        },
        MapPoint {
            position: Vector3::new(-1.5, 0.25, 4.0),
            colour: None,
        },
    ];
    r
}

#[test]
fn a_run_folder_is_written_whole_and_read_back() {
    let dir = std::env::temp_dir().join(format!("dwslam-run-{}", std::process::id()));
    let _ = std::fs::remove_dir_all(&dir);
    let mut out = RunOutput::create(
        &dir,
        OutputOptions {
            kitti: true,
            ply: PlyFormat::Binary,
        },
    )
    .unwrap();
    let r = record();
    for f in &r.frames {
        out.log_frame(f).unwrap();
    }
    // The log is on disk frame by frame, before any final write.
    let log = std::fs::read_to_string(dir.join("tracking_log.txt")).unwrap();
    assert_eq!(log.lines().count(), 6);
    assert!(log.lines().nth(4).unwrap().starts_with("3 10.1 lost nan"));
    assert!(log.contains("weak"));
    let gt = r.trajectory();
    out.write(&r, Some(&gt)).unwrap();

    let t = read_tum(dir.join("trajectory.tum")).unwrap();
    assert_eq!(
        t.timestamps,
        [
            10.0,
            10.0 + 1.0 / 30.0,
            10.0 + 2.0 / 30.0,
            10.0 + 4.0 / 30.0
        ]
    );
    assert_eq!(t.world_from_body[1], r.frames[1].world_from_camera.unwrap());
    let k = read_kitti(dir.join("trajectory.kitti")).unwrap();
    assert_eq!(k.len(), 4);
    assert!(
        (k[2].matrix() - r.frames[2].world_from_camera.unwrap().matrix())
            .abs()
            .max()
            < 1e-12
    );
    assert_eq!(read_tum(dir.join("keyframes.tum")).unwrap().len(), 1);
    let s = read_summary(dir.join("summary.json")).unwrap();
    assert_eq!(
        (s.frames, s.frames_with_pose, s.keyframes, s.points),
        (5, 4, 1, 2)
    );
    assert_eq!(
        (s.tracking.good, s.tracking.weak, s.tracking.lost),
        (3, 1, 1)
    );
    assert_eq!(
        s.frame_states[3].state,
        TrackingState::Lost("no points matched".into())
    );
    assert_eq!(s.timings[0].count, 5);
    assert!((s.timings[0].median_ms - 1.2).abs() < 1e-9);
    let json = std::fs::read_to_string(dir.join("summary.json")).unwrap();
    assert!(
        json.contains("\"state\": \"weak\"")
            && json.contains("\"reason\": \"42 of 150 points matched\"")
    );
    let files = find_run_files(&dir).unwrap();
    assert_eq!(files.ground_truth, Some(dir.join("ground_truth.tum")));
    assert!(!dir.join("trajectory.tum.tmp").exists());
    // Written again (e.g. at the next keyframe or on Ctrl-C): replaced whole.
    let mut r2 = r.clone();
    r2.interrupted = true;
    out.write(&r2, None).unwrap();
    assert!(read_summary(dir.join("summary.json")).unwrap().interrupted);
}

#[test]
fn ply_binary_and_ascii_hold_the_points() {
    let pts = record().points;
    let mut bin = Vec::new();
    write_ply(&pts, PlyFormat::Binary, &mut bin).unwrap();
    let header_end = bin.windows(11).position(|w| w == b"end_header\n").unwrap() + 11;
    let header = std::str::from_utf8(&bin[..header_end]).unwrap();
    assert!(
        header.contains("format binary_little_endian 1.0")
            && header.contains("element vertex 2")
            && header.contains("property uchar red")
    );
    let body = &bin[header_end..];
    assert_eq!(body.len(), 2 * (3 * 4 + 3));
    let f = |o: usize| f32::from_le_bytes(body[o..o + 4].try_into().unwrap());
    assert_eq!((f(0), f(4), f(8)), (1.0, 2.0, 3.0));
    assert_eq!(&body[12..15], &[10, 20, 30]);
    assert_eq!((f(15), f(19), f(23)), (-1.5, 0.25, 4.0));
    assert_eq!(&body[27..30], &[128, 128, 128]);
    let mut ascii = Vec::new();
    write_ply(&pts, PlyFormat::Ascii, &mut ascii).unwrap();
    let text = String::from_utf8(ascii).unwrap();
    assert!(
        text.ends_with("end_header\n1 2 3 10 20 30\n-1.5 0.25 4 128 128 128\n"),
        "{text}"
    );
    let mut plain = Vec::new();
    write_ply(
        &[MapPoint {
            position: Vector3::zeros(),
            colour: None,
        }],
        PlyFormat::Ascii,
        &mut plain,
    )
    .unwrap();
    assert!(!String::from_utf8(plain).unwrap().contains("red"));
}

#[test]
fn an_unwritable_run_folder_is_refused_at_creation() {
    let file = std::env::temp_dir().join(format!("dwslam-run-file-{}", std::process::id()));
    std::fs::write(&file, "x").unwrap();
    let e = RunOutput::create(file.join("sub"), OutputOptions::default())
        .err()
        .unwrap();
    assert!(e.to_string().contains("dwslam-run-file"), "{e}");
}

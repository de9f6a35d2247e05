//! Malformed inputs: each gives an error that names the file, the line or the frame, and what
//! was expected; `--on-bad-frame skip` goes on past bad frames; nothing panics.

use data::DataError;
use data::paths::require;
use data::sequence::{BadFramePolicy, FrameErrorKind, OpenOptions, Sequence};
use std::path::{Path, PathBuf};
use std::time::{Duration, Instant};

fn tempdir(name: &str) -> PathBuf {
    let d = std::env::temp_dir().join(format!("dwslam-bad-{name}-{}", std::process::id()));
    let _ = std::fs::remove_dir_all(&d);
    std::fs::create_dir_all(&d).unwrap();
    d
}

fn write_rgb(path: &Path, w: u32, h: u32) {
    image::RgbImage::from_fn(w, h, |u, v| image::Rgb([(u * 3) as u8, (v * 5) as u8, 7]))
        .save(path)
        .unwrap();
}

fn write_depth(path: &Path, w: u32, h: u32) {
    image::ImageBuffer::<image::Luma<u16>, Vec<u16>>::from_fn(w, h, |u, _| {
        image::Luma([1000 + u as u16])
    })
    .save(path)
    .unwrap();
}

/// A small TUM-layout folder: three 64×48 colour frames, depth for each.
fn tum(name: &str) -> PathBuf {
    let d = tempdir(name);
    std::fs::create_dir_all(d.join("rgb")).unwrap();
    std::fs::create_dir_all(d.join("depth")).unwrap();
    let (mut rgb, mut depth) = (String::from("# rgb\n"), String::from("# depth\n"));
    for i in 0..3 {
        write_rgb(&d.join(format!("rgb/{i}.png")), 64, 48);
        write_depth(&d.join(format!("depth/{i}.png")), 64, 48);
        rgb += &format!("{}.0 rgb/{i}.png\n", 10 + i);
        depth += &format!("{}.005 depth/{i}.png\n", 10 + i);
    }
    std::fs::write(d.join("rgb.txt"), rgb).unwrap();
    std::fs::write(d.join("depth.txt"), depth).unwrap();
    d
}

fn open(d: &Path, policy: BadFramePolicy) -> Result<Sequence, DataError> {
    Sequence::open(
        d,
        &OpenOptions {
            on_bad_frame: policy,
            ..Default::default()
        },
    )
}

/// Reads every frame through the prefetching reader; returns the indices read and the errors.
fn read_all(seq: Sequence) -> (Vec<usize>, Vec<data::sequence::FrameError>) {
    let (mut ok, mut bad) = (Vec::new(), Vec::new());
    for item in seq.into_reader(2) {
        match item {
            Ok(f) => ok.push(f.index),
            Err(e) => bad.push(e),
        }
    }
    (ok, bad)
}

fn assert_mentions(message: &str, parts: &[&str]) {
    for p in parts {
        assert!(message.contains(p), "{message:?} does not mention {p:?}");
    }
}

#[test]
fn bad_frames_are_reported_with_frame_and_file_and_skipped_on_request() {
    // (case, how to break frame 1, expected error kind, words of the message)
    type Break = fn(&Path);
    type Case<'a> = (&'a str, Break, fn(&FrameErrorKind) -> bool, &'a [&'a str]);
    let cases: [Case; 5] = [
        (
            "missing image",
            |d| std::fs::remove_file(d.join("rgb/1.png")).unwrap(),
            |k| matches!(k, FrameErrorKind::Missing),
            &["frame 1", "rgb/1.png", "does not exist"],
        ),
        (
            "truncated image",
            |d| {
                let b = std::fs::read(d.join("rgb/1.png")).unwrap();
                std::fs::write(d.join("rgb/1.png"), &b[..b.len() / 2]).unwrap();
            },
            |k| matches!(k, FrameErrorKind::Decode(_)),
            &["frame 1", "rgb/1.png", "cannot decode"],
        ),
        (
            "undecodable image",
            |d| std::fs::write(d.join("rgb/1.png"), "not a PNG at all").unwrap(),
            |k| matches!(k, FrameErrorKind::Decode(_)),
            &["frame 1", "rgb/1.png", "cannot decode"],
        ),
        (
            "depth of the wrong size",
            |d| write_depth(&d.join("depth/1.png"), 32, 24),
            |k| matches!(k, FrameErrorKind::Size { .. }),
            &[
                "frame 1",
                "depth/1.png",
                "depth image is 32×24, expected 64×48",
            ],
        ),
        (
            "8-bit depth image",
            |d| {
                image::GrayImage::new(64, 48)
                    .save(d.join("depth/1.png"))
                    .unwrap()
            },
            |k| matches!(k, FrameErrorKind::PixelFormat { .. }),
            &["frame 1", "depth/1.png", "expected 16-bit single-channel"],
        ),
    ];
    for (name, break_it, kind, words) in cases {
        let d = tum(&name.replace(' ', "-"));
        break_it(&d);
        // stop (default): the error is the last item.
        let (ok, bad) = read_all(open(&d, BadFramePolicy::Stop).unwrap());
        assert_eq!(ok, [0], "{name}");
        assert_eq!(bad.len(), 1, "{name}");
        assert!(kind(&bad[0].kind), "{name}: {:?}", bad[0].kind);
        assert_mentions(&bad[0].to_string(), words);
        // skip: reported, and the reader goes on.
        let (ok, bad) = read_all(open(&d, BadFramePolicy::Skip).unwrap());
        assert_eq!((ok, bad.len()), (vec![0, 2], 1), "{name}");
    }
}

#[test]
fn malformed_files_name_the_file_the_line_and_what_was_expected() {
    let d = tum("backwards");
    std::fs::write(
        d.join("rgb.txt"),
        "10.0 rgb/0.png\n12.0 rgb/1.png\n11.0 rgb/2.png\n",
    )
    .unwrap();
    let e = open(&d, BadFramePolicy::Stop).err().unwrap().to_string();
    assert_mentions(
        &e,
        &[
            "rgb.txt:3",
            "a timestamp after 12 (line 2)",
            "11",
            "must increase",
        ],
    );
    let s = open(&d, BadFramePolicy::Skip).unwrap();
    assert_eq!(s.len(), 2);
    assert!(s.info().warnings.iter().any(|w| w.contains("rgb.txt:3")));

    let d = tum("badlist");
    std::fs::write(d.join("depth.txt"), "10.0 depth/0.png\n11.0\n").unwrap();
    let e = open(&d, BadFramePolicy::Stop).err().unwrap().to_string();
    assert_mentions(&e, &["depth.txt:2", "expected 2 fields", "found 1"]);

    // EuRoC data.csv with a non-integer timestamp.
    let d = tempdir("euroc");
    std::fs::create_dir_all(d.join("mav0/cam0/data")).unwrap();
    std::fs::write(
        d.join("mav0/cam0/data.csv"),
        "#timestamp [ns],filename\n1403715273262142976,a.png\n14037152733.5,b.png\n",
    )
    .unwrap();
    let e = open(&d, BadFramePolicy::Stop).err().unwrap().to_string();
    assert_mentions(
        &e,
        &[
            "data.csv:3",
            "timestamp [ns]",
            "non-negative integer",
            "14037152733.5",
        ],
    );
    // … and a sensor.yaml whose T_BS is not 4×4.
    std::fs::write(d.join("mav0/cam0/data.csv"), "#t,f\n1,a.png\n").unwrap();
    std::fs::write(
        d.join("mav0/cam0/sensor.yaml"),
        "%YAML:1.0\nT_BS:\n  cols: 3\n  rows: 3\n  data: [1, 0, 0, 0, 1, 0, 0, 0, 1]\n",
    )
    .unwrap();
    let e = open(&d, BadFramePolicy::Stop).err().unwrap().to_string();
    assert_mentions(
        &e,
        &[
            "sensor.yaml",
            "T_BS: rows 4, cols 4 and 16 data entries",
            "rows 3",
        ],
    );
    std::fs::write(
        d.join("mav0/cam0/sensor.yaml"),
        "%YAML:1.0\nT_BS:\n  cols: 4\n  rows: 4\n  data: [1, 0, 0, 0]\nintrinsics: [458.6, abc]\n",
    )
    .unwrap();
    let e = open(&d, BadFramePolicy::Stop).err().unwrap().to_string();
    assert_mentions(&e, &["sensor.yaml:6", "YAML"]);

    // KITTI calib.txt with 11 numbers on a line.
    let d = tempdir("kitti");
    std::fs::create_dir_all(d.join("image_0")).unwrap();
    image::GrayImage::new(40, 30)
        .save(d.join("image_0/000000.png"))
        .unwrap();
    std::fs::write(
        d.join("calib.txt"),
        "P0: 1 0 0 0 0 1 0 0 0 0 1 0\nP1: 1 0 0 -1 0 1 0 0 0 0 1\n",
    )
    .unwrap();
    let e = open(&d, BadFramePolicy::Stop).err().unwrap().to_string();
    assert_mentions(
        &e,
        &[
            "calib.txt:2",
            "KITTI projection matrix",
            "expected 12 fields",
            "found 11",
        ],
    );

    // A camera YAML with a misspelt key and one with a bad number.
    let d = tempdir("folder");
    write_rgb(&d.join("000.png"), 16, 12);
    std::fs::write(d.join("camera.yaml"), "dwslam_camera: 1\nsensor: mono\ncamera:\n  width: 16\n  height: 12\n  fx: 10\n  fy: 10\n  cx: 8\n  cy: 6\n  fps: 30\n").unwrap();
    let e = open(&d, BadFramePolicy::Stop).err().unwrap().to_string();
    assert_mentions(&e, &["camera.yaml:10", "YAML", "fps"]);
    std::fs::write(
        d.join("camera.yaml"),
        "%YAML:1.0\nCamera.fx: 10\nCamera.fy: ten\n",
    )
    .unwrap();
    let e = open(&d, BadFramePolicy::Stop).err().unwrap().to_string();
    assert_mentions(&e, &["camera.yaml:3", "YAML"]);
    std::fs::write(
        d.join("camera.yaml"),
        "%YAML:1.0\nCamera.fx: 10\nCamera.cx: 8\nCamera.cy: 6\n",
    )
    .unwrap();
    let e = open(&d, BadFramePolicy::Stop).err().unwrap().to_string();
    assert_mentions(&e, &["camera.yaml", "expected Camera.fy, found missing"]);

    // An unknown layout lists what is there.
    let d = tempdir("unknown");
    std::fs::write(d.join("notes.txt"), "hello").unwrap();
    let e = open(&d, BadFramePolicy::Stop).err().unwrap().to_string();
    assert_mentions(
        &e,
        &[
            "dwslam-bad-unknown",
            "expected a known layout",
            "found notes.txt",
        ],
    );
    let e = open(&d.join("absent"), BadFramePolicy::Stop)
        .err()
        .unwrap()
        .to_string();
    assert_mentions(&e, &["absent", "does not exist"]);
}

#[test]
fn a_stalled_consumer_stops_the_decoder_at_the_queue_length_and_dropping_ends_it() {
    let Some(dir) = require("seven_scenes_redkitchen_1000") else {
        return;
    };
    let queue = 4;
    let mut reader = Sequence::open(&dir, &OpenOptions::default())
        .unwrap()
        .into_reader(queue);
    let first = reader.next().unwrap().unwrap();
    assert_eq!(first.index, 0);
    std::thread::sleep(Duration::from_millis(500));
    let s = reader.stats();
    assert!(s.decoded - s.delivered <= queue + 1, "{s:?}");
    assert!(s.decoded >= queue, "{s:?}: the decoder kept ahead");
    let t = Instant::now();
    drop(reader); // joins the thread
    assert!(t.elapsed() < Duration::from_secs(2));
}

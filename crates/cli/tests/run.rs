//! `dwslam run`: bad arguments fail before any work with one line naming what is wrong; a short
//! real RGB-D run writes every output — both trajectories, the map, the summary with its
//! evaluation, the report's pictures and, with `--dense-ply`, the dense model.

use std::path::PathBuf;
use std::process::Command;

fn dwslam(args: &[&str]) -> std::process::Output {
    Command::new(env!("CARGO_BIN_EXE_dwslam"))
        .args(args)
        .output()
        .expect("the binary runs")
}

fn scratch(name: &str) -> PathBuf {
    let dir = std::env::temp_dir().join(format!("dwslam-run-{}-{name}", std::process::id()));
    let _ = std::fs::remove_dir_all(&dir);
    std::fs::create_dir_all(&dir).unwrap();
    dir
}

#[test]
fn bad_arguments_fail_first() {
    let Some(kitchen) = data::paths::require("seven_scenes_redkitchen_1000") else {
        return;
    };
    let kitchen = kitchen.to_str().unwrap();
    let dir = scratch("bad");
    let out = dir.join("out");
    let out = out.to_str().unwrap();
    let config = dir.join("c.yml");
    std::fs::write(&config, "tracker:\n  serch_radius: 2\n").unwrap();
    let bad_value = dir.join("v.yml");
    std::fs::write(&bad_value, "loops:\n  queue: 0\n").unwrap();
    let missing = dir.join("nope");
    for (args, expect) in [
        (vec!["run", missing.to_str().unwrap(), "--out", out], "nope"),
        (
            vec![
                "run",
                kitchen,
                "--out",
                out,
                "--config",
                config.to_str().unwrap(),
            ],
            "serch_radius",
        ),
        (
            vec![
                "run",
                kitchen,
                "--out",
                out,
                "--config",
                bad_value.to_str().unwrap(),
            ],
            "loops.queue",
        ),
        (
            vec!["run", kitchen, "--out", out, "--max-frames", "0"],
            "--max-frames",
        ),
        (
            vec!["run", kitchen, "--out", out, "--sensor", "stereo"],
            "--sensor stereo",
        ),
        (
            vec!["run", kitchen, "--out", out, "--localise"],
            "--load-map",
        ),
        (
            vec![
                "run",
                kitchen,
                "--out",
                out,
                "--load-map",
                missing.to_str().unwrap(),
            ],
            "nope",
        ),
        (
            vec![
                "run",
                kitchen,
                "--out",
                out,
                "--load-map",
                config.to_str().unwrap(),
            ],
            "is not a dwslam map",
        ),
        (
            vec!["run", kitchen, "--out", out, "--start-frame", "5000"],
            "--start-frame 5000",
        ),
    ] {
        let o = dwslam(&args);
        let stderr = String::from_utf8_lossy(&o.stderr);
        assert!(!o.status.success(), "{args:?} succeeded");
        assert!(
            stderr.contains(expect),
            "{args:?}: {expect:?} not in {stderr}"
        );
        // One error line (a YAML error goes on to show the offending line), no panic.
        assert!(
            stderr.starts_with("error: ") && !stderr.contains("panicked"),
            "{stderr}"
        );
    }
    assert!(!dir.join("out").exists(), "nothing is written");
    std::fs::remove_dir_all(&dir).unwrap();
}

#[test]
fn a_short_run_writes_every_output() {
    let Some(kitchen) = data::paths::require("seven_scenes_redkitchen_1000") else {
        return;
    };
    let dir = scratch("short");
    let out = dir.join("out");
    let o = dwslam(&[
        "run",
        kitchen.to_str().unwrap(),
        "--depth-frames-only",
        "--max-frames",
        "40",
        "--deterministic",
        "--dense-ply",
        "--quiet",
        "--out",
        out.to_str().unwrap(),
    ]);
    let stdout = String::from_utf8_lossy(&o.stdout);
    assert!(
        o.status.success(),
        "{stdout}{}",
        String::from_utf8_lossy(&o.stderr)
    );
    assert!(
        stdout.contains("live trajectory (40 of 40 frames"),
        "{stdout}"
    );
    for f in [
        "trajectory.tum",
        "trajectory_final.tum",
        "keyframes.tum",
        "map.ply",
        "summary.json",
        "frames.csv",
        "optimisations.csv",
        "trajectory.png",
        "keyframe_graph.png",
        "time_per_frame.png",
        "time_per_keyframe.png",
        "tracked_points.png",
    ] {
        let p = out.join(f);
        assert!(
            p.metadata().is_ok_and(|m| m.len() > 0),
            "{f} missing or empty"
        );
    }
    let tum = std::fs::read_to_string(out.join("trajectory.tum")).unwrap();
    assert_eq!(tum.lines().filter(|l| !l.starts_with('#')).count(), 40);
    let summary: serde_json::Value =
        serde_json::from_str(&std::fs::read_to_string(out.join("summary.json")).unwrap()).unwrap();
    let live = summary["evaluation"]["live"]["ate_rmse_m"]
        .as_f64()
        .unwrap();
    assert!(live > 0.0 && live < 0.05, "live ATE {live}");
    // The appearance loops the drift test refused are listed in the summary.
    assert!(
        summary["refused_loops"].is_array(),
        "{}",
        summary["refused_loops"]
    );
    // The dense model: a binary PLY with many coloured points.
    let ply = std::fs::read(out.join("dense.ply")).unwrap();
    let header = String::from_utf8_lossy(&ply[..ply.len().min(400)]);
    assert!(
        header.starts_with("ply\nformat binary_little_endian"),
        "{header}"
    );
    let n: usize = header
        .lines()
        .find_map(|l| l.strip_prefix("element vertex "))
        .and_then(|n| n.trim().parse().ok())
        .unwrap();
    // 40 frames, five keyframes or so of a kitchen at 1–3 m: thousands of 1.7 cm voxels.
    assert!(n > 5_000, "{n} dense points");
    assert!(header.contains("property uchar red"), "{header}");
    std::fs::remove_dir_all(&dir).unwrap();
}

/// `dwslam demo`: the live system on the room rendered on the fly, scored against the
/// renderer's exact ground truth (no dataset needed). A short clip: every frame tracked, the
/// trajectory sub-centimetre (the full default run is ~1 mm; README), the report and the
/// dense model written.
#[test]
fn the_demo_runs_the_live_system_on_a_rendered_room() {
    let dir = scratch("demo");
    let out = dir.join("out");
    let refused = dwslam(&["demo", "--frames", "1", "--out", out.to_str().unwrap()]);
    assert!(!refused.status.success());
    assert!(
        String::from_utf8_lossy(&refused.stderr).contains("--frames"),
        "{}",
        String::from_utf8_lossy(&refused.stderr)
    );
    assert!(!out.exists(), "nothing written for refused arguments");
    let o = dwslam(&[
        "demo",
        "--frames",
        "90",
        "--deterministic",
        "--quiet",
        "--out",
        out.to_str().unwrap(),
    ]);
    let stdout = String::from_utf8_lossy(&o.stdout);
    assert!(
        o.status.success(),
        "{stdout}{}",
        String::from_utf8_lossy(&o.stderr)
    );
    assert!(stdout.contains("demo: 90 frames (0 lost)"), "{stdout}");
    assert!(stdout.contains("demo: ATE RMSE"), "{stdout}");
    let summary: serde_json::Value =
        serde_json::from_str(&std::fs::read_to_string(out.join("summary.json")).unwrap()).unwrap();
    for which in ["live", "final"] {
        let e = &summary["evaluation"][which];
        assert_eq!(e["poses"].as_u64(), Some(90), "{which}: {e}");
        let ate = e["ate_rmse_m"].as_f64().unwrap();
        assert!(ate > 0.0 && ate < 0.01, "{which} ATE {ate} m");
    }
    for f in [
        "trajectory.tum",
        "trajectory.png",
        "keyframe_graph.png",
        "dense.ply",
    ] {
        assert!(
            out.join(f).metadata().is_ok_and(|m| m.len() > 0),
            "{f} missing or empty"
        );
    }
    std::fs::remove_dir_all(&dir).unwrap();
}

/// The lines of a TUM trajectory file: each `timestamp tx ty tz qx qy qz qw`, every number
/// finite (panics naming the file otherwise).
fn tum_lines(path: &std::path::Path) -> usize {
    let text = std::fs::read_to_string(path).unwrap_or_else(|e| panic!("{}: {e}", path.display()));
    let mut n = 0;
    for line in text
        .lines()
        .filter(|l| !l.starts_with('#') && !l.trim().is_empty())
    {
        let values: Vec<f64> = line
            .split_whitespace()
            .map(|v| v.parse().unwrap_or(f64::NAN))
            .collect();
        assert!(
            values.len() == 8 && values.iter().all(|v| v.is_finite()),
            "{}: {line}",
            path.display()
        );
        n += 1;
    }
    n
}

/// Ctrl-C (SIGINT) in the middle of a threaded run: the run stops at the next frame, the
/// back-end's threads finish, and every output is written complete and parseable — the
/// summary says it was interrupted and counts the frames processed, the trajectories hold
/// their frames, the map and keyframes are there.
#[test]
fn an_interrupted_run_writes_complete_outputs() {
    let Some(kitchen) = data::paths::require("seven_scenes_redkitchen_1000") else {
        return;
    };
    let dir = scratch("sigint");
    let out = dir.join("out");
    let mut child = Command::new(env!("CARGO_BIN_EXE_dwslam"))
        .args(["run", kitchen.to_str().unwrap(), "--quiet", "--out"])
        .arg(&out)
        .stdout(std::process::Stdio::null())
        .stderr(std::process::Stdio::null())
        .spawn()
        .expect("the binary runs");
    // Interrupted once 100 frames are in the frame-by-frame log.
    let log = out.join("tracking_log.txt");
    let start = std::time::Instant::now();
    while std::fs::read_to_string(&log).map_or(0, |t| t.lines().count()) < 100 {
        assert!(
            start.elapsed().as_secs() < 120,
            "100 frames within 2 minutes"
        );
        assert!(child.try_wait().unwrap().is_none(), "still running");
        std::thread::sleep(std::time::Duration::from_millis(20));
    }
    let kill = Command::new("kill")
        .args(["-INT", &child.id().to_string()])
        .status()
        .unwrap();
    assert!(kill.success());
    let status = child.wait().unwrap();
    assert!(status.success(), "{status}");
    let summary: serde_json::Value =
        serde_json::from_str(&std::fs::read_to_string(out.join("summary.json")).unwrap())
            .expect("summary.json parses");
    assert_eq!(summary["interrupted"], serde_json::Value::Bool(true));
    let frames = summary["frames"].as_u64().unwrap() as usize;
    assert!((100..1000).contains(&frames), "{frames} frames");
    let posed = summary["frames_with_pose"].as_u64().unwrap() as usize;
    assert_eq!(tum_lines(&out.join("trajectory.tum")), posed);
    assert!(tum_lines(&out.join("trajectory_final.tum")) >= posed * 9 / 10);
    assert!(tum_lines(&out.join("keyframes.tum")) > 0);
    assert_eq!(
        summary["frame_states"].as_array().map(Vec::len),
        Some(frames),
        "every frame's state"
    );
    let ply = std::fs::read(out.join("map.ply")).unwrap();
    assert!(ply.starts_with(b"ply"));
    std::fs::remove_dir_all(&dir).unwrap();
}

/// A back-end worker that dies in a run of the binary (the test switch `DWSLAM_TEST_FAULT`):
/// the run completes, its summary carries the warning.
#[test]
fn a_run_whose_loop_closer_panics_completes_with_a_warning() {
    let Some(kitti) = data::paths::require("kitti_odometry_snippets/KITTI_sequence_1") else {
        return;
    };
    let dir = scratch("fault");
    let out = dir.join("out");
    let o = Command::new(env!("CARGO_BIN_EXE_dwslam"))
        .args(["run", kitti.to_str().unwrap(), "--quiet", "--out"])
        .arg(&out)
        .env("DWSLAM_TEST_FAULT", "loops:panic:3")
        .output()
        .unwrap();
    assert!(o.status.success(), "{}", String::from_utf8_lossy(&o.stderr));
    let summary: serde_json::Value =
        serde_json::from_str(&std::fs::read_to_string(out.join("summary.json")).unwrap()).unwrap();
    let warnings = summary["warnings"].as_array().unwrap();
    assert!(
        warnings
            .iter()
            .any(|w| w.as_str().unwrap().contains("loop closure thread panicked")),
        "{warnings:?}"
    );
    assert_eq!(tum_lines(&out.join("trajectory.tum")), 51);
    let bad = Command::new(env!("CARGO_BIN_EXE_dwslam"))
        .args(["run", kitti.to_str().unwrap(), "--quiet", "--out"])
        .arg(dir.join("bad"))
        .env("DWSLAM_TEST_FAULT", "loops:explode:3")
        .output()
        .unwrap();
    assert!(!bad.status.success());
    assert!(String::from_utf8_lossy(&bad.stderr).contains("DWSLAM_TEST_FAULT"));
    std::fs::remove_dir_all(&dir).unwrap();
}

/// A map saved by one run is what `dwslam map info` describes and what the next run loads:
/// with `--localise` its frames are found in it and nothing is added; a monocular run cannot
/// go on in an RGB-D map, and says so.
#[test]
fn a_saved_map_is_described_and_loaded_by_the_next_run() {
    let Some(kitchen) = data::paths::require("seven_scenes_redkitchen_1000") else {
        return;
    };
    let kitchen = kitchen.to_str().unwrap();
    let dir = scratch("maps");
    let map = dir.join("maps").join("kitchen.map");
    let map_arg = map.to_str().unwrap();
    let first = dir.join("first");
    let o = dwslam(&[
        "run",
        kitchen,
        "--depth-frames-only",
        "--max-frames",
        "60",
        "--deterministic",
        "--quiet",
        "--out",
        first.to_str().unwrap(),
        "--save-map",
        map_arg,
    ]);
    let stdout = String::from_utf8_lossy(&o.stdout);
    assert!(o.status.success(), "{}", String::from_utf8_lossy(&o.stderr));
    assert!(stdout.contains("saved map"), "{stdout}");
    let summary: serde_json::Value =
        serde_json::from_str(&std::fs::read_to_string(first.join("summary.json")).unwrap())
            .unwrap();
    let keyframes = summary["saved_map"]["holds"]["keyframes"].as_u64().unwrap();
    assert!(keyframes >= 3, "{summary}");
    // The map's size and the process's memory over the run: a sample every 100 frames and
    // one at the end.
    let over_time = summary["over_time"].as_array().unwrap();
    let last = over_time.last().unwrap();
    assert_eq!(last["frames"].as_u64(), Some(60));
    assert_eq!(last["keyframes"].as_u64(), Some(keyframes));
    assert!(last["resident_mb"].as_f64().unwrap() > 1.0, "{last}");
    assert_eq!(
        summary["saved_map"]["bytes"].as_u64().unwrap(),
        std::fs::metadata(&map).unwrap().len()
    );
    // What the map holds, as text and as JSON.
    let o = dwslam(&["map", "info", map_arg]);
    let text = String::from_utf8_lossy(&o.stdout);
    assert!(o.status.success());
    assert!(
        text.contains(&format!("{keyframes} keyframes")) && text.contains("rgbd fx 585"),
        "{text}"
    );
    let o = dwslam(&["map", "info", map_arg, "--json"]);
    let info: serde_json::Value = serde_json::from_slice(&o.stdout).unwrap();
    assert_eq!(info["holds"]["keyframes"].as_u64(), Some(keyframes));
    // The next frames localised in it: nothing added.
    let second = dir.join("second");
    let o = dwslam(&[
        "run",
        kitchen,
        "--depth-frames-only",
        "--start-frame",
        "40",
        "--max-frames",
        "20",
        "--deterministic",
        "--quiet",
        "--out",
        second.to_str().unwrap(),
        "--load-map",
        map_arg,
        "--localise",
    ]);
    assert!(o.status.success(), "{}", String::from_utf8_lossy(&o.stderr));
    let summary: serde_json::Value =
        serde_json::from_str(&std::fs::read_to_string(second.join("summary.json")).unwrap())
            .unwrap();
    assert_eq!(summary["keyframes_made"].as_u64(), Some(0), "{summary}");
    assert!(!summary["relocalisations"].as_array().unwrap().is_empty());
    assert_eq!(summary["keyframes"].as_u64(), Some(keyframes));
    // A monocular run and an RGB-D map.
    let o = dwslam(&[
        "run",
        kitchen,
        "--sensor",
        "mono",
        "--max-frames",
        "5",
        "--quiet",
        "--out",
        dir.join("third").to_str().unwrap(),
        "--load-map",
        map_arg,
    ]);
    let stderr = String::from_utf8_lossy(&o.stderr);
    assert!(!o.status.success());
    assert!(
        stderr.contains("the sensor rgbd") && stderr.contains("kitchen.map"),
        "{stderr}"
    );
    std::fs::remove_dir_all(&dir).unwrap();
}

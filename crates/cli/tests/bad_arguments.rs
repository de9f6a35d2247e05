//! Bad command-line arguments fail before any work starts, for every command: a non-zero
//! exit within a second or two, one line naming the argument and what is wrong, no backtrace,
//! and no output left behind.

use std::path::{Path, PathBuf};
use std::process::Command;
use std::time::{Duration, Instant};

fn dwslam() -> Command {
    Command::new(env!("CARGO_BIN_EXE_dwslam"))
}

fn scratch(name: &str) -> PathBuf {
    let dir = std::env::temp_dir().join(format!("dwslam-bad-args-{}-{name}", std::process::id()));
    let _ = std::fs::remove_dir_all(&dir);
    std::fs::create_dir_all(&dir).unwrap();
    dir
}

/// Runs `dwslam args…` and checks that it fails fast with `expect` in its message; returns the
/// message.
fn fails(args: &[&str], expect: &str) -> String {
    let start = Instant::now();
    let out = dwslam()
        .args(args)
        .env("RUST_BACKTRACE", "1")
        .output()
        .expect("the binary runs");
    let elapsed = start.elapsed();
    let stderr = String::from_utf8_lossy(&out.stderr).to_string();
    assert!(
        !out.status.success(),
        "dwslam {args:?} succeeded:\n{stderr}"
    );
    assert!(
        stderr.contains(expect),
        "dwslam {args:?}: expected {expect:?} in\n{stderr}"
    );
    assert!(
        !stderr.contains("backtrace") && !stderr.contains("Caused by"),
        "dwslam {args:?}: the message is one line:\n{stderr}"
    );
    assert!(
        elapsed < Duration::from_secs(3),
        "dwslam {args:?} took {elapsed:?}: work started before the arguments were checked"
    );
    stderr
}

fn path(p: &Path) -> &str {
    p.to_str().unwrap()
}

#[test]
fn experiments_check_their_arguments_first() {
    let dir = scratch("experiments");
    let file = dir.join("a-file");
    std::fs::write(&file, "x").unwrap();
    let fresh = dir.join("never-created");
    // dwo
    fails(
        &["experiment", "dwo", "--noise", "0", "--out", path(&fresh)],
        "--noise",
    );
    fails(
        &[
            "experiment",
            "dwo",
            "--keyframes",
            "5",
            "--out",
            path(&fresh),
        ],
        "--keyframes must be at least 20",
    );
    fails(&["experiment", "dwo", "--out", path(&file)], "is a file");
    fails(&["experiment", "dwo", "--methods", "ba,xyz"], "xyz");
    fails(&["experiment", "dwo", "--scenario", "moon"], "moon");
    fails(
        &[
            "experiment",
            "dwo",
            "--out",
            path(&file.join("below-a-file")),
        ],
        "--out",
    );
    // scale-drift
    fails(
        &[
            "experiment",
            "scale-drift",
            "--runs",
            "0",
            "--out",
            path(&fresh),
        ],
        "--runs",
    );
    fails(
        &[
            "experiment",
            "scale-drift",
            "--noise=-1",
            "--out",
            path(&fresh),
        ],
        "--noise",
    );
    fails(
        &[
            "experiment",
            "scale-drift",
            "--repeats",
            "0",
            "--out",
            path(&fresh),
        ],
        "--repeats",
    );
    // why-filter
    fails(&["experiment", "why-filter", "--setting", "v"], "v");
    fails(
        &[
            "experiment",
            "why-filter",
            "--trials",
            "1",
            "--out",
            path(&fresh),
        ],
        "--trials",
    );
    fails(
        &[
            "experiment",
            "why-filter",
            "--workers",
            "0",
            "--out",
            path(&fresh),
        ],
        "--workers",
    );
    fails(
        &[
            "experiment",
            "why-filter",
            "--setting",
            "motion",
            "--sensor",
            "stereo",
        ],
        "monocular",
    );
    // cbh-jacobians
    fails(
        &["experiment", "cbh-jacobians", "--samples", "0"],
        "--samples",
    );
    fails(
        &["experiment", "cbh-jacobians", "--out", path(&file)],
        "is a file",
    );
    assert!(!fresh.exists(), "a refused run created its output folder");
    std::fs::remove_dir_all(&dir).unwrap();
}

#[test]
fn ba_checks_its_arguments_first() {
    let dir = scratch("ba");
    let missing = dir.join("problem-missing.txt");
    let message = fails(&["ba", path(&missing)], "no such file");
    assert!(!message.contains("decode"), "{message}");
    fails(&["ba"], "give a BAL file or --synthetic");
    fails(&["ba", "--synthetic", "2,10"], "at least 3 cameras");
    fails(&["ba", "--synthetic", "10"], "CAMERAS,POINTS");
    fails(&["ba", "--synthetic", "10,100", "--huber=-1"], "--huber");
    fails(
        &["ba", "--synthetic", "10,100", "--threads", "0"],
        "--threads",
    );
    fails(
        &["ba", "--synthetic", "10,100", "--json", path(&dir)],
        "is a folder",
    );
    let file = dir.join("a-file");
    std::fs::write(&file, "x").unwrap();
    fails(
        &[
            "ba",
            "--synthetic",
            "10,100",
            "--out",
            path(&file.join("x.txt")),
        ],
        "--out",
    );
    std::fs::remove_dir_all(&dir).unwrap();
}

#[test]
fn inspect_checks_its_arguments_first() {
    let dir = scratch("inspect");
    let missing = dir.join("missing.png");
    let out = dir.join("out.png");
    let message = fails(
        &["inspect", "features", path(&missing), "--out", path(&out)],
        "no such file",
    );
    assert!(!message.contains("decode"), "{message}");
    let image = dir.join("image.png");
    std::fs::write(&image, "not a png").unwrap();
    fails(
        &["inspect", "features", path(&image), "--out", path(&dir)],
        "is a folder",
    );
    fails(
        &[
            "inspect",
            "stereo",
            path(&image),
            path(&image),
            "--block",
            "4",
            "--out",
            path(&out),
        ],
        "--block",
    );
    fails(
        &[
            "inspect",
            "flow",
            path(&image),
            path(&missing),
            "--out",
            path(&out),
        ],
        "no such file",
    );
    fails(
        &[
            "inspect",
            "track",
            path(&dir.join("no-frames")),
            "--out",
            path(&dir.join("tracks")),
        ],
        "no such folder",
    );
    fails(
        &[
            "inspect",
            "match",
            path(&image),
            path(&image),
            "--features",
            "0",
            "--out",
            path(&out),
        ],
        "--features",
    );
    assert!(!out.exists() && !dir.join("tracks").exists());
    std::fs::remove_dir_all(&dir).unwrap();
}

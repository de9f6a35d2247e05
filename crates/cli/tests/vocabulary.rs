//! `dwslam vocabulary`: bad arguments fail before any work with one line naming the argument;
//! given images, it trains and writes a DBoW2 YAML vocabulary that the reader loads back.

use std::path::PathBuf;
use std::process::Command;

fn dwslam(args: &[&str]) -> std::process::Output {
    Command::new(env!("CARGO_BIN_EXE_dwslam"))
        .args(args)
        .output()
        .expect("the binary runs")
}

fn scratch(name: &str) -> PathBuf {
    let dir = std::env::temp_dir().join(format!("dwslam-vocabulary-{}-{name}", std::process::id()));
    let _ = std::fs::remove_dir_all(&dir);
    std::fs::create_dir_all(&dir).unwrap();
    dir
}

#[test]
fn bad_arguments_fail_first() {
    let dir = scratch("bad");
    let out = dir.join("v.yml");
    let out = out.to_str().unwrap();
    let dir_s = dir.to_str().unwrap();
    let missing = dir.join("missing.png");
    for (args, expect) in [
        (vec!["vocabulary", "--out", dir_s], "--out"),
        (
            vec!["vocabulary", "--out", out, missing.to_str().unwrap()],
            "no such file",
        ),
        (vec!["vocabulary", "--out", out, "--k", "5"], "--levels"),
        (
            vec!["vocabulary", "--out", out, "--k", "1", "--levels", "3"],
            "--k must be at least 2",
        ),
        (vec!["vocabulary", "--out", out, dir_s], "holds no images"),
    ] {
        let o = dwslam(&args);
        let stderr = String::from_utf8_lossy(&o.stderr);
        assert!(!o.status.success(), "{args:?} succeeded");
        assert!(
            stderr.contains(expect),
            "{args:?}: {expect:?} not in {stderr}"
        );
    }
    assert!(!dir.join("v.yml").exists(), "nothing is written");
    std::fs::remove_dir_all(&dir).unwrap();
}

#[test]
fn trains_and_writes_a_readable_vocabulary() {
    let Some(teddy) = data::paths::require("middlebury_stereo/teddy") else {
        return;
    };
    let dir = scratch("train");
    let out = dir.join("sub/v.yml");
    let o = dwslam(&[
        "vocabulary",
        "--out",
        out.to_str().unwrap(),
        "--k",
        "4",
        "--levels",
        "3",
        teddy.join("im2.png").to_str().unwrap(),
        teddy.join("im6.png").to_str().unwrap(),
    ]);
    let stdout = String::from_utf8_lossy(&o.stdout);
    assert!(o.status.success(), "{}", String::from_utf8_lossy(&o.stderr));
    assert!(stdout.contains("training on 2 images"), "{stdout}");
    let voc = vision::bow::Vocabulary::load_dbow_yaml(&out).unwrap();
    assert_eq!((voc.k, voc.levels), (4, 3));
    assert!(
        voc.num_words() > 30 && voc.num_words() <= 64,
        "{}",
        voc.num_words()
    );
    std::fs::remove_dir_all(&dir).unwrap();
}

//! `dwslam eval`: a run folder alone, validation before any work, and agreement with the
//! recorded evo number (the full comparison is bench/eval/compare_evo.sh).

use std::process::Command;

fn dwslam(args: &[&str]) -> (bool, String, String) {
    let out = Command::new(env!("CARGO_BIN_EXE_dwslam"))
        .args(args)
        .env_remove("RUST_BACKTRACE")
        .env_remove("RUST_LIB_BACKTRACE")
        .output()
        .unwrap();
    (
        out.status.success(),
        String::from_utf8_lossy(&out.stdout).into(),
        String::from_utf8_lossy(&out.stderr).into(),
    )
}

#[test]
fn eval_reads_a_run_folder_and_validates_its_arguments_first() {
    let Some(evo) = data::paths::require("trajectories_evo") else {
        return;
    };
    let run = std::env::temp_dir().join(format!("dwslam-eval-run-{}", std::process::id()));
    let _ = std::fs::remove_dir_all(&run);
    std::fs::create_dir_all(&run).unwrap();
    std::fs::copy(
        evo.join("fr2_desk_groundtruth.txt"),
        run.join("ground_truth.tum"),
    )
    .unwrap();
    std::fs::copy(evo.join("fr2_desk_ORB.txt"), run.join("trajectory.tum")).unwrap();
    let json = run.join("eval.json");
    let plots = run.join("plots");
    let (ok, stdout, stderr) = dwslam(&[
        "eval",
        run.to_str().unwrap(),
        "--json",
        json.to_str().unwrap(),
        "--plot",
        plots.to_str().unwrap(),
    ]);
    assert!(ok, "{stderr}");
    assert!(stdout.contains("ATE [m]"));
    let v: serde_json::Value =
        serde_json::from_str(&std::fs::read_to_string(&json).unwrap()).unwrap();
    // evo_ape tum fr2_desk_groundtruth.txt fr2_desk_ORB.txt --align: rmse 0.008118977562044926.
    let rmse = v["ate"]["rmse"].as_f64().unwrap();
    assert!(
        (rmse - 0.008118977562044926).abs() < 1e-6 * 0.0081,
        "{rmse}"
    );
    for f in [
        "trajectory_top.png",
        "trajectory_side.png",
        "ate_over_time.png",
        "rpe_over_time.png",
    ] {
        assert!(
            std::fs::metadata(plots.join(f)).unwrap().len() > 10_000,
            "{f}"
        );
    }

    // Missing inputs are reported as missing; unwritable outputs are refused before any work.
    let (ok, _, stderr) = dwslam(&["eval", "/no/such/gt.txt", run.to_str().unwrap()]);
    assert!(
        !ok && stderr.contains("the ground truth /no/such/gt.txt does not exist"),
        "{stderr}"
    );
    let (ok, _, stderr) = dwslam(&[
        "eval",
        run.to_str().unwrap(),
        "--json",
        "/no/such/dir/x.json",
    ]);
    assert!(
        !ok && stderr
            .contains("--json /no/such/dir/x.json: the folder /no/such/dir does not exist"),
        "{stderr}"
    );
    let gt = run.join("ground_truth.tum");
    let (ok, _, stderr) = dwslam(&[
        "eval",
        run.to_str().unwrap(),
        "--plot",
        gt.to_str().unwrap(),
    ]);
    assert!(
        !ok && stderr.contains("is a file, not a folder"),
        "{stderr}"
    );
    // A malformed trajectory names the file and the line, once.
    std::fs::write(run.join("bad.tum"), "1 2 3 4 5 6 7 8\n2 2 3 x 5 6 7 8\n").unwrap();
    let bad = run.join("bad.tum");
    let (ok, _, stderr) = dwslam(&["eval", gt.to_str().unwrap(), bad.to_str().unwrap()]);
    assert!(
        !ok && stderr.contains("bad.tum:2: tz: expected a number, found \"x\""),
        "{stderr}"
    );
    assert_eq!(stderr.matches("bad.tum:2").count(), 1, "{stderr}");
}

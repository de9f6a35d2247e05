//! `dwslam experiment …`: reproductions of the thesis's experiments.

use anyhow::{Context, Result};
use clap::{Args, Subcommand};
use std::path::PathBuf;

pub mod cbh_jacobians;
mod common;
pub mod dwo;
pub mod scale_drift;
pub mod why_filter;

pub(crate) use common::progress;
use common::read_summary;

/// The experiments of the thesis.
#[derive(Subcommand, Debug)]
pub enum ExperimentCommand {
    /// Thesis Table 5.1: accuracy of the CBH approximations of the pose-graph Jacobian.
    CbhJacobians(CbhArgs),
    /// Thesis §6.5.1, Figures 6.9–6.12: full BA vs double window optimisation (cDWO, gDWO,
    /// cDWO with a fixed outer window) on the simulated spiral and double loop.
    Dwo(dwo::DwoArgs),
    /// Thesis §5.4: scale drift in monocular SLAM, SE(3) vs Sim(3) loop closure (Fig. 5.4–5.6).
    ScaleDrift(scale_drift::ScaleDriftArgs),
    /// Thesis ch. 4 (Figures 4.3, 4.5–4.13): filtering versus keyframe bundle adjustment.
    WhyFilter(WhyFilterArgs),
}

/// Options of `dwslam experiment why-filter`.
#[derive(Args, Debug)]
pub struct WhyFilterArgs {
    /// `preliminary` (§4.3), a setting of §4.6.1 (`i`, `ii`, `iii`, `iv`), `motion` (§4.6.3,
    /// Fig. 4.10: the monocular filter's pose prediction by motion-only BA vs Alg. 6), or `all`.
    #[arg(long, default_value = "all", value_parser = why_filter_settings())]
    setting: String,
    /// Monte Carlo trials per (setting, sensor, M, N) cell (the thesis uses 500).
    #[arg(long, default_value_t = 12)]
    trials: usize,
    /// `stereo`, `mono` or `both`.
    #[arg(long, default_value = "both", value_parser = why_filter_sensors())]
    sensor: String,
    /// Output directory (CSV, PNG, summary.json).
    #[arg(long, default_value = "out/why-filter")]
    out: PathBuf,
    /// Master seed.
    #[arg(long, default_value_t = 2012)]
    seed: u64,
    /// Worker threads, each running whole trials single-threaded (default: all cores).
    #[arg(long)]
    workers: Option<usize>,
}

/// The names `--setting` takes: the library's settings and the studies around them.
fn why_filter_settings() -> clap::builder::PossibleValuesParser {
    let settings = sim::why_filter::Setting::ALL.map(|s| s.name());
    clap::builder::PossibleValuesParser::new(
        std::iter::once("preliminary")
            .chain(settings)
            .chain(["motion", "all"]),
    )
}

/// The names `--sensor` takes: the library's sensors, or both.
fn why_filter_sensors() -> clap::builder::PossibleValuesParser {
    clap::builder::PossibleValuesParser::new(
        sim::sensor::SensorKind::ALL
            .map(|s| s.name())
            .into_iter()
            .chain(["both"]),
    )
}

/// Options of `dwslam experiment cbh-jacobians`.
#[derive(Args, Debug)]
pub struct CbhArgs {
    /// Samples per cell (the thesis uses 100).
    #[arg(long, default_value_t = 100)]
    samples: usize,
    /// Seed of the random draws.
    #[arg(long, default_value_t = 2012)]
    seed: u64,
    /// Output directory for the table as JSON, `table.json` (`rows`: group, sigma, d_norm,
    /// err_j1, err_j2, err_j3); without it the table is only printed.
    #[arg(long)]
    out: Option<PathBuf>,
}

/// Runs one experiment.
pub fn run(cmd: ExperimentCommand) -> Result<()> {
    match cmd {
        ExperimentCommand::CbhJacobians(args) => run_cbh(args),
        ExperimentCommand::Dwo(args) => dwo::run(args),
        ExperimentCommand::ScaleDrift(args) => scale_drift::run(args),
        ExperimentCommand::WhyFilter(args) => run_why_filter(args),
    }
}

fn run_why_filter(args: WhyFilterArgs) -> Result<()> {
    use sim::why_filter::{SensorKind, Setting};
    let (preliminary, settings, motion): (bool, Vec<Setting>, bool) = match args.setting.as_str() {
        "all" => (true, Setting::ALL.to_vec(), true),
        "preliminary" => (true, Vec::new(), false),
        "motion" => (false, Vec::new(), true),
        s => (
            false,
            vec![Setting::parse(s).expect("clap accepts only the listed settings")],
            false,
        ),
    };
    let sensors: Vec<SensorKind> = SensorKind::ALL
        .into_iter()
        .filter(|k| args.sensor == "both" || args.sensor == k.name())
        .collect();
    // The pose-prediction study (Fig. 4.10) is about the monocular filter.
    anyhow::ensure!(
        args.setting != "motion" || sensors.contains(&SensorKind::Mono),
        "--setting motion is the monocular filter's study (Fig. 4.10): use --sensor mono or both"
    );
    let motion = motion && sensors.contains(&SensorKind::Mono);
    anyhow::ensure!(
        args.trials >= 2,
        "--trials must be at least 2 (sample covariances)"
    );
    anyhow::ensure!(args.workers != Some(0), "--workers must be at least 1");
    let workers = args
        .workers
        .unwrap_or_else(|| std::thread::available_parallelism().map_or(1, |n| n.get()));
    crate::args::output_dir(&args.out, "--out")?;
    let started = std::time::Instant::now();
    let path = args.out.join("summary.json");
    let mut summary = read_summary(&path)?;
    let config = serde_json::json!({
        "setting": args.setting, "sensor": args.sensor, "trials": args.trials,
        "seed": args.seed, "workers": workers,
        "timing": "CPU time of the thread running each trial (one-thread rayon pool per worker; CLOCK_THREAD_CPUTIME_ID), independent of the machine load",
    });
    if preliminary || !settings.is_empty() {
        summary.insert("config".into(), config.clone());
    }
    if preliminary {
        let t = std::time::Instant::now();
        let p = why_filter::run_preliminary();
        let s = why_filter::write_preliminary(&p, &args.out)?;
        println!(
            "preliminary (§4.3): doubling N beats doubling M at {}/{} grid points (translation and rotation); {:.1} s",
            s["points_beat_frames"],
            s["grid_points_compared"],
            t.elapsed().as_secs_f64()
        );
        summary.insert("preliminary".into(), s);
    }
    if !settings.is_empty() {
        let total = sim::why_filter::trial_specs(&settings, &sensors, args.trials, args.seed).len();
        let bar = progress(total, "trials");
        let results = why_filter::run_settings(
            &settings,
            &sensors,
            args.trials,
            args.seed,
            workers,
            &|| bar.inc(1),
        );
        bar.finish();
        let (groups, table, _) = why_filter::write_settings(&results, &args.out)?;
        println!("{table}");
        std::fs::write(args.out.join("table.txt"), &table)
            .with_context(|| format!("writing {}", args.out.join("table.txt").display()))?;
        summary.insert("settings".into(), groups);
    }
    if motion {
        let started = std::time::Instant::now();
        let specs = sim::why_filter::motion_specs(args.trials, args.seed);
        let bar = progress(specs.len(), "Fig. 4.10 trials");
        let results = sim::why_filter::run_parallel(
            &specs,
            workers,
            sim::why_filter::run_motion_trial,
            &|| bar.inc(1),
        );
        bar.finish();
        let (mut entry, table) = why_filter::write_motion(&results, &args.out)?;
        entry["config"] = config;
        entry["elapsed_seconds"] = serde_json::json!(started.elapsed().as_secs_f64());
        println!("{table}");
        std::fs::write(args.out.join("motion_table.txt"), &table)
            .with_context(|| format!("writing {}", args.out.join("motion_table.txt").display()))?;
        summary.insert("motion".into(), entry);
    }
    if preliminary || !settings.is_empty() {
        summary.insert(
            "elapsed_seconds".into(),
            serde_json::json!(started.elapsed().as_secs_f64()),
        );
    }
    std::fs::write(
        &path,
        serde_json::to_string_pretty(&serde_json::Value::Object(summary))?,
    )
    .with_context(|| format!("writing {}", path.display()))?;
    println!("wrote {} (and CSV/PNG files beside it)", path.display());
    Ok(())
}

fn run_cbh(args: CbhArgs) -> Result<()> {
    anyhow::ensure!(args.samples > 0, "--samples must be at least 1");
    if let Some(out) = &args.out {
        crate::args::output_dir(out, "--out")?;
    }
    let rows = cbh_jacobians::table(args.seed, args.samples);
    println!(
        "Thesis Table 5.1 — ‖J_num − J_k‖_F of the k-th order CBH pose-graph Jacobian, mean over {} samples (seed {})",
        args.samples, args.seed
    );
    println!(
        "each cell: ours / thesis; ✓ = within 5× (or < 1e-7 where the thesis is below 1e-8)\n"
    );
    println!(
        "{:<7} {:>7}  {:>22}  {:>22}  {:>22}  {:>22}  {:>9}",
        "group", "σ", "‖d‖", "‖J_num − J1‖", "‖J_num − J2‖", "‖J_num − J3‖", "‖J_num − J_exact‖"
    );
    let mut all_agree = true;
    for row in &rows {
        let ours = [row.d_norm, row.err_j1, row.err_j2, row.err_j3];
        let cells: Vec<String> = ours
            .iter()
            .zip(row.thesis)
            .map(|(&o, t)| {
                let mark = if cbh_jacobians::cell_agrees(o, t) {
                    "✓"
                } else {
                    "✗"
                };
                format!("{o:.3e} / {t:.3e} {mark}")
            })
            .collect();
        all_agree &= row.agrees_with_thesis();
        println!(
            "{:<7} {:>7}  {:>22}  {:>22}  {:>22}  {:>22}  {:>9.1e}",
            row.group, row.sigma, cells[0], cells[1], cells[2], cells[3], row.err_exact
        );
    }
    let ordered = rows
        .iter()
        .all(|r| r.err_j3 < r.err_j2 && r.err_j2 < r.err_j1);
    println!(
        "\nJ3 < J2 < J1 in every cell: {}; every cell within the tolerance: {}",
        if ordered { "yes" } else { "NO" },
        if all_agree { "yes" } else { "NO" }
    );
    if let Some(out) = &args.out {
        let path = out.join("table.json");
        let json = serde_json::json!({ "samples": args.samples, "seed": args.seed, "rows": rows });
        std::fs::write(&path, serde_json::to_string_pretty(&json)?)
            .with_context(|| format!("writing {}", path.display()))?;
        println!("wrote {}", path.display());
    }
    Ok(())
}

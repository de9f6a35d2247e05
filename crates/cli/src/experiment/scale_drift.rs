//! `dwslam experiment scale-drift`: the scale-drift experiments of thesis §5.4 — monocular
//! exploration on simulated measurements, loop closure by SE(3) versus Sim(3) pose-graph
//! optimisation (Fig. 5.5, 5.6), and the convergence of the Sim(3) pose graph with numeric and
//! CBH Jacobians (Fig. 5.4). The computations live in [`sim::scale_drift`]; this module runs
//! them with progress bars and writes CSV files, PNG plots and `summary.json`.

use super::common::{progress, read_summary};
use crate::plot::{self, Figure, GREY, PALETTE, Series, Style};
use anyhow::{Context, Result, bail};
use lie::Se3;
use serde_json::{Map, Value, json};
use sim::scale_drift::{
    CircleConfig, CircleRecord, JacobianTrace, LoopRun, NoiseLevelSummary, RunSettings,
    SphereConfig, aligned_centres, circle_monte_carlo, jacobian_convergence, run_sphere, summarise,
};
use std::fmt::Write as _;
use std::path::{Path, PathBuf};

/// Which part of the experiment to run.
#[derive(Clone, Copy, Debug, PartialEq, Eq, clap::ValueEnum)]
pub enum Part {
    /// The circle Monte Carlo experiment (Fig. 5.5).
    Circle,
    /// The flight over a sphere with ten loop closures (Fig. 5.6).
    Sphere,
    /// Sim(3) pose-graph convergence with numeric and CBH Jacobians (Fig. 5.4).
    Jacobians,
    /// All three.
    All,
}

/// Options of `dwslam experiment scale-drift`.
#[derive(clap::Args, Debug)]
pub struct ScaleDriftArgs {
    /// The part to run.
    #[arg(long, value_enum, default_value_t = Part::All)]
    pub part: Part,
    /// Output directory (CSV, PNG, summary.json); created if missing.
    #[arg(long, default_value = "out/scale-drift")]
    pub out: PathBuf,
    /// Runs per noise level of the circle (the thesis: 10).
    #[arg(long, default_value_t = 10)]
    pub runs: usize,
    /// Pixel noise levels of the circle, comma separated (the thesis: 0 to 1.2 px).
    #[arg(
        long,
        value_delimiter = ',',
        default_value = "0,0.2,0.4,0.6,0.8,1.0,1.2"
    )]
    pub noise: Vec<f64>,
    /// Base seed: run `r` uses seed `seed + r`.
    #[arg(long, default_value_t = 0)]
    pub seed: u64,
    /// Iterations of the Jacobian comparison.
    #[arg(long, default_value_t = 10)]
    pub iterations: usize,
    /// Timing repeats of the Jacobian comparison (the fastest is kept).
    #[arg(long, default_value_t = 5)]
    pub repeats: usize,
    /// Run full BA after the structure-only refinement.
    #[arg(long)]
    pub full_ba: bool,
}

/// Runs the experiment.
pub fn run(args: ScaleDriftArgs) -> Result<()> {
    if args.runs == 0 {
        bail!("--runs must be at least 1");
    }
    if args.noise.is_empty() || args.noise.iter().any(|s| !(s.is_finite() && *s >= 0.0)) {
        bail!("--noise must list finite pixel noise levels ≥ 0");
    }
    if args.iterations == 0 {
        bail!("--iterations must be at least 1");
    }
    if args.repeats == 0 {
        bail!("--repeats must be at least 1");
    }
    crate::args::output_dir(&args.out, "--out")?;
    let summary_path = args.out.join("summary.json");
    let mut summary = read_summary(&summary_path)?;
    let settings = RunSettings {
        full_ba: args.full_ba,
        ..RunSettings::default()
    };
    let mut sphere: Option<LoopRun> = None;
    if matches!(args.part, Part::Circle | Part::All) {
        circle(&args, &settings, &mut summary)?;
    }
    if matches!(args.part, Part::Sphere | Part::Jacobians | Part::All) {
        let config = SphereConfig {
            settings: RunSettings {
                seed: args.seed,
                ..settings.clone()
            },
            ..SphereConfig::default()
        };
        let bar = progress(config.poses, "sphere: exploring");
        let run = run_sphere(&config, &mut |done, _| bar.set_position(done as u64))
            .context("the sphere run failed")?;
        bar.finish();
        if matches!(args.part, Part::Sphere | Part::All) {
            sphere_outputs(&args.out, &config, &run, &mut summary)?;
        }
        sphere = Some(run);
    }
    if matches!(args.part, Part::Jacobians | Part::All) {
        let run = sphere.as_ref().expect("the sphere ran");
        jacobians(&args, run, &mut summary)?;
    }
    std::fs::write(&summary_path, serde_json::to_string_pretty(&summary)?)
        .with_context(|| format!("writing {}", summary_path.display()))?;
    println!("wrote {}", summary_path.display());
    Ok(())
}

fn write(path: &Path, text: &str) -> Result<()> {
    std::fs::write(path, text).with_context(|| format!("writing {}", path.display()))
}

/// Top-view (`x`, `y` = world axes `a`, `b`) series of trajectories aligned to the truth.
fn trajectory_series(
    truth: &[Se3],
    estimates: &[(&str, &[Se3])],
    a: usize,
    b: usize,
) -> Vec<Series> {
    let project = |c: &nalgebra::Vector3<f64>| (c[a], c[b]);
    let mut series = vec![Series {
        label: "ground truth".into(),
        points: truth
            .iter()
            .map(|t| project(&sim::trajectory::centre(t)))
            .collect(),
        color: GREY,
        style: Style::Line,
    }];
    for (k, (label, est)) in estimates.iter().enumerate() {
        let (aligned, _) = aligned_centres(truth, est);
        series.push(Series {
            label: (*label).to_string(),
            points: aligned.iter().map(project).collect(),
            color: PALETTE[k % PALETTE.len()],
            style: Style::Line,
        });
    }
    series
}

fn circle(
    args: &ScaleDriftArgs,
    settings: &RunSettings,
    summary: &mut Map<String, Value>,
) -> Result<()> {
    let base = CircleConfig {
        settings: settings.clone(),
        ..CircleConfig::default()
    };
    let total = args.noise.len() * args.runs;
    let bar = progress(total, "circle: runs");
    // Keep the run at 1 px (or the largest level) with the base seed for the trajectory plot.
    let keep_sigma = args
        .noise
        .iter()
        .copied()
        .min_by(|a, b| (a - 1.0).abs().total_cmp(&(b - 1.0).abs()))
        .expect("non-empty");
    let (records, kept) = circle_monte_carlo(
        &base,
        &args.noise,
        args.runs,
        args.seed,
        Some((keep_sigma, args.seed)),
        &|done| bar.set_position(done as u64),
    );
    bar.finish();
    let levels = summarise(&records, &args.noise);
    write(
        &args.out.join("circle_runs.csv"),
        &circle_runs_csv(&records),
    )?;
    write(
        &args.out.join("circle_summary.csv"),
        &circle_summary_csv(&levels),
    )?;
    println!(
        "Circle (thesis Fig. 5.5 d): r = 10 m, 720 poses, 5000 points on a ring of r = 11 m, window 10, {} runs per level",
        args.runs
    );
    println!(
        "{:>6} {:>5} {:>6} {:>12} {:>12} {:>12} {:>12} {:>12} {:>8}",
        "σ px",
        "ok",
        "failed",
        "scale drift",
        "RMSE explor",
        "RMSE SE(3)",
        "RMSE Sim(3)",
        "Sim3+BA",
        "SE3/Sim3"
    );
    for l in &levels {
        println!(
            "{:>6.2} {:>5} {:>6} {:>12.4} {:>12.3} {:>12.3} {:>12.3} {:>12.3} {:>8.1}",
            l.sigma,
            l.runs,
            l.failed,
            l.scale_drift,
            l.rmse_explored,
            l.rmse_se3,
            l.rmse_sim3,
            l.rmse_refined,
            l.rmse_se3 / l.rmse_sim3
        );
    }
    for r in records.iter().filter(|r| r.error.is_some()) {
        println!(
            "  failed: σ {} seed {}: {}",
            r.sigma,
            r.seed,
            r.error.as_deref().unwrap_or("")
        );
    }
    let monotone = levels
        .windows(2)
        .all(|w| w[1].scale_drift > w[0].scale_drift);
    println!("scale drift strictly increasing with noise: {monotone}");
    let per_level: Vec<Value> = levels
        .iter()
        .map(|l| {
            json!({
                "sigma": l.sigma,
                "runs": l.runs,
                "failed": l.failed,
                "circle_scale_drift": l.scale_drift,
                "circle_rmse_explored": l.rmse_explored,
                "circle_rmse_se3": l.rmse_se3,
                "circle_rmse_sim3": l.rmse_sim3,
                "circle_rmse_sim3_refined": l.rmse_refined,
            })
        })
        .collect();
    summary.insert(
        "circle".into(),
        json!({
            "runs_per_level": args.runs,
            "base_seed": args.seed,
            "levels": per_level,
            "scale_drift_monotone": monotone,
        }),
    );
    let line = |label: &str, k: usize, f: &dyn Fn(&NoiseLevelSummary) -> f64| Series {
        label: label.into(),
        points: levels.iter().map(|l| (l.sigma, f(l))).collect(),
        color: PALETTE[k],
        style: Style::Line,
    };
    plot::plot(
        &args.out.join("circle_rmse.png"),
        &Figure {
            title: "Circle: RMSE after loop closure vs pixel noise (Fig. 5.5 d)",
            x_label: "pixel noise σ [px]",
            y_label: "scale-aligned RMSE [m]",
            equal_aspect: false,
            log_y: false,
        },
        &[
            line("before correction", 3, &|l| l.rmse_explored),
            line("SE(3) correction", 2, &|l| l.rmse_se3),
            line("Sim(3) correction", 1, &|l| l.rmse_sim3),
        ],
    )?;
    plot::plot(
        &args.out.join("circle_scale_drift.png"),
        &Figure {
            title: "Circle: scale drift at loop closure vs pixel noise (Fig. 5.5 d)",
            x_label: "pixel noise σ [px]",
            y_label: "scale drift exp(|ln s_loop|) − 1",
            equal_aspect: false,
            log_y: false,
        },
        &[line("mean scale drift", 0, &|l| l.scale_drift)],
    )?;
    // Fig. 5.5 e: RMSE against the run's scale drift, one dot per run.
    let dots = |label: &str, k: usize, f: &dyn Fn(&CircleRecord) -> f64| Series {
        label: label.into(),
        points: records
            .iter()
            .filter(|r| r.error.is_none())
            .map(|r| (100.0 * r.scale_drift, f(r)))
            .collect(),
        color: PALETTE[k],
        style: Style::Points,
    };
    plot::plot(
        &args.out.join("circle_rmse_vs_drift.png"),
        &Figure {
            title: "Circle: RMSE vs scale drift, one dot per run (Fig. 5.5 e)",
            x_label: "scale drift [%]",
            y_label: "scale-aligned RMSE [m]",
            equal_aspect: false,
            log_y: false,
        },
        &[
            dots("SE(3) correction", 2, &|r| r.rmse_se3),
            dots("Sim(3) correction", 1, &|r| r.rmse_sim3),
        ],
    )?;
    if let Some(run) = kept {
        let title = format!(
            "Circle, σ = {keep_sigma} px, seed {}: top view (Fig. 5.5 a–c)",
            args.seed
        );
        plot::plot(
            &args.out.join("circle_trajectories.png"),
            &Figure {
                title: &title,
                x_label: "x [m]",
                y_label: "y [m]",
                equal_aspect: true,
                log_y: false,
            },
            &trajectory_series(
                &run.truth,
                &[
                    ("explored (before correction)", &run.explored),
                    ("SE(3) correction", &run.corrected_se3),
                    ("Sim(3) correction", &run.corrected_sim3),
                ],
                0,
                1,
            ),
        )?;
        write(
            &args.out.join("circle_trajectories.csv"),
            &trajectories_csv(&run),
        )?;
    }
    Ok(())
}

fn circle_runs_csv(records: &[CircleRecord]) -> String {
    let mut s = String::from(
        "sigma,seed,loop_scale,true_loop_scale,scale_drift,rmse_explored,rmse_se3,rmse_sim3,rmse_sim3_refined,keyframes,loop_inliers,error\n",
    );
    for r in records {
        let _ = writeln!(
            s,
            "{},{},{},{},{},{},{},{},{},{},{},{}",
            r.sigma,
            r.seed,
            r.loop_scale,
            r.true_loop_scale,
            r.scale_drift,
            r.rmse_explored,
            r.rmse_se3,
            r.rmse_sim3,
            r.rmse_refined,
            r.keyframes,
            r.loop_inliers,
            r.error.as_deref().unwrap_or("").replace(',', ";")
        );
    }
    s
}

fn circle_summary_csv(levels: &[NoiseLevelSummary]) -> String {
    let mut s = String::from(
        "sigma,runs,failed,scale_drift,rmse_explored,rmse_se3,rmse_sim3,rmse_sim3_refined\n",
    );
    for l in levels {
        let _ = writeln!(
            s,
            "{},{},{},{},{},{},{},{}",
            l.sigma,
            l.runs,
            l.failed,
            l.scale_drift,
            l.rmse_explored,
            l.rmse_se3,
            l.rmse_sim3,
            l.rmse_refined
        );
    }
    s
}

/// Keyframe centres: truth and the aligned estimates.
fn trajectories_csv(run: &LoopRun) -> String {
    let mut s = String::from("keyframe,truth_x,truth_y,truth_z");
    let estimates: [(&str, &[Se3]); 4] = [
        ("explored", &run.explored),
        ("se3", &run.corrected_se3),
        ("sim3", &run.corrected_sim3),
        ("sim3_refined", &run.refined_sim3),
    ];
    for (name, _) in &estimates {
        let _ = write!(s, ",{name}_x,{name}_y,{name}_z");
    }
    s.push('\n');
    let aligned: Vec<Vec<nalgebra::Vector3<f64>>> = estimates
        .iter()
        .map(|(_, e)| aligned_centres(&run.truth, e).0)
        .collect();
    for (k, t) in run.truth.iter().enumerate() {
        let c = sim::trajectory::centre(t);
        let _ = write!(s, "{k},{},{},{}", c.x, c.y, c.z);
        for a in &aligned {
            let _ = write!(s, ",{},{},{}", a[k].x, a[k].y, a[k].z);
        }
        s.push('\n');
    }
    s
}

fn sphere_outputs(
    out: &Path,
    config: &SphereConfig,
    run: &LoopRun,
    summary: &mut Map<String, Value>,
) -> Result<()> {
    println!(
        "Sphere (thesis Fig. 5.6): r = {} m, altitude {} m, {} poses, {} points, {} loops; {} keyframes, {} map points",
        config.radius,
        config.altitude,
        config.poses,
        config.points,
        run.loops.len(),
        run.explored.len(),
        run.points
    );
    println!(
        "{:>8} {:>8} {:>10} {:>10} {:>8}",
        "old kf", "cur kf", "s_loop", "map ratio", "inliers"
    );
    for l in &run.loops {
        println!(
            "{:>8} {:>8} {:>10.4} {:>10.4} {:>8}",
            l.edge.old,
            l.edge.current,
            l.edge.old_from_current.scale(),
            l.true_scale,
            l.inliers
        );
    }
    println!(
        "RMSE: explored {:.3}, SE(3) {:.3} (thesis 2.187), Sim(3) {:.3} (thesis 0.328), Sim(3) + BA {:.3}; SE(3)/Sim(3) = {:.1}",
        run.rmse_explored,
        run.rmse_se3,
        run.rmse_sim3,
        run.rmse_refined,
        run.rmse_se3 / run.rmse_sim3
    );
    summary.insert("sphere_rmse_explored".into(), json!(run.rmse_explored));
    summary.insert("sphere_rmse_se3".into(), json!(run.rmse_se3));
    summary.insert("sphere_rmse_sim3".into(), json!(run.rmse_sim3));
    summary.insert("sphere_rmse_sim3_refined".into(), json!(run.rmse_refined));
    summary.insert(
        "sphere".into(),
        json!({
            "seed": config.settings.seed,
            "keyframes": run.explored.len(),
            "map_points": run.points,
            "loops": run.loops.iter().map(|l| json!({
                "old": l.edge.old,
                "current": l.edge.current,
                "s_loop": l.edge.old_from_current.scale(),
                "map_scale_ratio": l.true_scale,
                "inliers": l.inliers,
            })).collect::<Vec<_>>(),
            "exploration_seconds": run.exploration_seconds,
        }),
    );
    write(&out.join("sphere_trajectories.csv"), &trajectories_csv(run))?;
    for (file, a, b, view) in [
        ("sphere_side.png", 0, 2, "side view (x, z)"),
        ("sphere_top.png", 0, 1, "top view (x, y)"),
    ] {
        let title = format!("Sphere flight, 10 loops: {view} (Fig. 5.6)");
        let (xl, yl) = (
            ["x [m]", "y [m]", "z [m]"][a],
            ["x [m]", "y [m]", "z [m]"][b],
        );
        plot::plot(
            &out.join(file),
            &Figure {
                title: &title,
                x_label: xl,
                y_label: yl,
                equal_aspect: true,
                log_y: false,
            },
            &trajectory_series(
                &run.truth,
                &[
                    ("explored (before correction)", &run.explored),
                    ("SE(3) correction", &run.corrected_se3),
                    ("Sim(3) correction", &run.corrected_sim3),
                ],
                a,
                b,
            ),
        )?;
    }
    Ok(())
}

fn jacobians(args: &ScaleDriftArgs, run: &LoopRun, summary: &mut Map<String, Value>) -> Result<()> {
    let traces: Vec<JacobianTrace> = jacobian_convergence(run, args.iterations, args.repeats)
        .context("the Jacobian comparison failed")?;
    println!(
        "Sim(3) pose graph of the sphere run ({} keyframes, {} loops), {} LM iterations, best of {} timings, 1 thread (thesis Fig. 5.4)",
        run.explored.len(),
        run.loops.len(),
        args.iterations,
        args.repeats
    );
    let numeric = traces.iter().find(|t| t.method == "numeric");
    println!(
        "{:<8} {:>14} {:>14} {:>14} {:>16} {:>12}",
        "method", "initial ½χ²", "final ½χ²", "ms / iter", "linearise ms/it", "speed-up"
    );
    let mut rows = Vec::new();
    let mut csv = String::from("method,iteration,seconds,cost\n");
    for t in &traces {
        let speedup = numeric
            .map(|n| n.seconds_per_iteration / t.seconds_per_iteration)
            .unwrap_or(f64::NAN);
        println!(
            "{:<8} {:>14.6e} {:>14.6e} {:>14.3} {:>16.3} {:>12.2}",
            t.method,
            t.initial_cost,
            t.final_cost,
            1e3 * t.seconds_per_iteration,
            1e3 * t.linearize_seconds_per_iteration,
            speedup
        );
        let _ = writeln!(csv, "{},0,0,{}", t.method, t.initial_cost);
        for (k, (s, c)) in t.trace.iter().enumerate() {
            let _ = writeln!(csv, "{},{},{},{}", t.method, k + 1, s, c);
        }
        rows.push(json!({
            "method": t.method,
            "initial_cost": t.initial_cost,
            "final_cost": t.final_cost,
            "seconds_per_iteration": t.seconds_per_iteration,
            "linearize_seconds_per_iteration": t.linearize_seconds_per_iteration,
            "speedup_vs_numeric": speedup,
        }));
    }
    write(&args.out.join("jacobians.csv"), &csv)?;
    summary.insert(
        "jacobians".into(),
        json!({
            "graph": "sphere run, Sim(3)",
            "keyframes": run.explored.len(),
            "loops": run.loops.len(),
            "iterations": args.iterations,
            "methods": rows,
        }),
    );
    let series: Vec<Series> = traces
        .iter()
        .enumerate()
        .map(|(k, t)| Series {
            label: t.method.to_string(),
            points: std::iter::once((0.0, t.initial_cost))
                .chain(t.trace.iter().map(|(s, c)| (1e3 * s, *c)))
                .collect(),
            color: PALETTE[k % PALETTE.len()],
            style: Style::Line,
        })
        .collect();
    plot::plot(
        &args.out.join("jacobians.png"),
        &Figure {
            title: "Sim(3) pose graph: cost vs time per Jacobian (Fig. 5.4)",
            x_label: "time [ms]",
            y_label: "½χ²",
            equal_aspect: false,
            log_y: true,
        },
        &series,
    )?;
    Ok(())
}

//! `dwslam experiment dwo` and `dwslam demo`: the double window optimisation experiments of
//! thesis §6.5.1 (Figures 6.9–6.12) on simulated data, with CSV, PNG plots and a summary.

use crate::args::{self, Named, parser};
use crate::plot::{self, Figure, PALETTE, Series, Style};
use anyhow::{Context, Result};
use clap::Args;
use indicatif::{ProgressBar, ProgressStyle};
use serde_json::json;
use sim::dwo::{
    self, KeyframeRecord, Method, RunConfig, RunResult, Scenario, SensorKind, SimCamera, World,
};
use sim::sensor::{MonoSensor, StereoSensor};
use slam::dwo::ConstraintInformation;
use std::fmt::Write as _;
use std::path::{Path, PathBuf};

impl Named for Scenario {
    fn all() -> &'static [Self] {
        &Scenario::ALL
    }
    fn name(self) -> &'static str {
        Scenario::name(self)
    }
    fn help(self) -> &'static str {
        self.description()
    }
}

impl Named for SensorKind {
    fn all() -> &'static [Self] {
        &SensorKind::ALL
    }
    fn name(self) -> &'static str {
        SensorKind::name(self)
    }
    fn help(self) -> &'static str {
        match self {
            SensorKind::Stereo => "rectified stereo",
            SensorKind::Mono => "monocular",
        }
    }
}

impl Named for Method {
    fn all() -> &'static [Self] {
        &Method::ALL
    }
    fn name(self) -> &'static str {
        self.slug()
    }
    fn help(self) -> &'static str {
        Method::name(self)
    }
}

impl Named for ConstraintInformation {
    fn all() -> &'static [Self] {
        &ConstraintInformation::ALL
    }
    fn name(self) -> &'static str {
        ConstraintInformation::name(self)
    }
    fn help(self) -> &'static str {
        match self {
            ConstraintInformation::Coarse => "thesis eq. 6.2",
            ConstraintInformation::Marginal => {
                "pair-wise marginalisation of the points each constraint stands for"
            }
        }
    }
}

/// Options of `dwslam experiment dwo`.
#[derive(Args, Debug, Clone)]
pub struct DwoArgs {
    /// The scenario.
    #[arg(long, value_parser = parser::<Scenario>(), default_value = "spiral")]
    scenario: Scenario,
    /// The sensor (default: stereo for the spiral and the room, monocular for the double
    /// loop; f = 300, stereo baseline 5 cm).
    #[arg(long, value_parser = parser::<SensorKind>())]
    sensor: Option<SensorKind>,
    /// Output directory (CSV, PNG plots, summary.json).
    #[arg(long, default_value = "out/dwo")]
    out: PathBuf,
    /// Number of keyframes (default: 500 for the spiral, 2 × 150 for the double loop).
    #[arg(long)]
    keyframes: Option<usize>,
    /// Seed of the world and the measurement noise.
    #[arg(long, default_value_t = 1)]
    seed: u64,
    /// Methods to run, comma separated (default: all four).
    #[arg(long, value_delimiter = ',', value_parser = parser::<Method>())]
    methods: Option<Vec<Method>>,
    /// Worker threads of the optimiser (the thesis timed one core).
    #[arg(long, default_value_t = 1)]
    threads: usize,
    /// Joint optimisation iterations per keyframe, every method (the thesis: 3).
    #[arg(long, default_value_t = 3)]
    iterations: usize,
    /// Information of the pose-pose constraints.
    #[arg(long, value_parser = parser::<ConstraintInformation>(), default_value = "marginal")]
    constraint_information: ConstraintInformation,
    /// Standard deviation of the image noise (pixels; the thesis: 1).
    #[arg(long, default_value_t = 1.0)]
    noise: f64,
}

impl DwoArgs {
    /// The double-loop study (what `dwslam demo` ran before the live system existed):
    /// `dwslam experiment dwo --scenario double-loop --methods cdwo,gdwo`.
    #[cfg(test)]
    pub fn double_loop() -> Self {
        DwoArgs {
            scenario: Scenario::DoubleLoop,
            sensor: None,
            out: PathBuf::from("dwslam-demo"),
            keyframes: None,
            seed: 1,
            methods: Some(vec![Method::Cdwo, Method::Gdwo]),
            iterations: 3,
            constraint_information: ConstraintInformation::default(),
            threads: 1,
            noise: 1.0,
        }
    }
}

/// Runs the experiment and writes its outputs.
pub fn run(args: DwoArgs) -> Result<()> {
    anyhow::ensure!(args.threads >= 1, "--threads must be at least 1");
    anyhow::ensure!(args.iterations >= 1, "--iterations must be at least 1");
    args::positive(args.noise, "--noise (pixels)")?;
    let scenario = args.scenario;
    let sensor = args.sensor.unwrap_or(match scenario {
        Scenario::Spiral | Scenario::Room => SensorKind::Stereo,
        Scenario::DoubleLoop => SensorKind::Mono,
    });
    let methods: Vec<Method> = args.methods.clone().unwrap_or_else(|| Method::ALL.to_vec());
    anyhow::ensure!(!methods.is_empty(), "--methods is empty");
    if let Some(n) = args.keyframes {
        anyhow::ensure!(n >= 20, "--keyframes must be at least 20 (got {n})");
    }
    args::output_dir(&args.out, "--out")?;
    let world = match (scenario, args.keyframes) {
        (Scenario::Spiral, n) => dwo::spiral_world(args.seed, n.unwrap_or(500)),
        (Scenario::Room, n) => dwo::room_world(args.seed, n.unwrap_or(500)),
        (Scenario::DoubleLoop, n) => {
            let per_loop = n.map(|n| n / 2).unwrap_or(150);
            anyhow::ensure!(
                per_loop >= 10,
                "--keyframes must be at least 20 for the double loop"
            );
            dwo::double_loop_world(args.seed, per_loop)
        }
    };
    let config = RunConfig {
        iterations: args.iterations,
        information: args.constraint_information,
        ..RunConfig::for_scenario(scenario, args.seed)
    };
    println!(
        "double window optimisation (thesis §6.5.1): {} keyframes, {:?} {}, methods {}, seed {}, noise {} px, output {}",
        world.camera_from_world.len(),
        scenario,
        match sensor {
            SensorKind::Stereo => "stereo",
            SensorKind::Mono => "monocular",
        },
        methods
            .iter()
            .map(|m| m.name())
            .collect::<Vec<_>>()
            .join(", "),
        args.seed,
        args.noise,
        args.out.display()
    );
    let pool = rayon::ThreadPoolBuilder::new()
        .num_threads(args.threads)
        .build()?;
    let results = pool.install(|| match sensor {
        SensorKind::Stereo => run_all(
            &StereoSensor::vga(300.0, 0.05, args.noise),
            &world,
            &methods,
            &config,
        ),
        SensorKind::Mono => run_all(
            &MonoSensor::vga(300.0, args.noise),
            &world,
            &methods,
            &config,
        ),
    })?;
    report(
        &args.out, scenario, sensor, args.noise, &config, &world, &results,
    )
}

fn run_all<C: SimCamera<N>, const N: usize>(
    camera: &C,
    world: &World,
    methods: &[Method],
    config: &RunConfig,
) -> Result<Vec<RunResult>> {
    let measurements = dwo::measure(camera, world, config.seed);
    let n = world.camera_from_world.len();
    let mut out = Vec::new();
    for &m in methods {
        let bar = ProgressBar::new(n as u64);
        bar.set_style(
            ProgressStyle::with_template(
                "{prefix:>18} [{bar:40}] {pos}/{len} keyframes {elapsed_precise} {msg}",
            )
            .expect("valid template")
            .progress_chars("=> "),
        );
        bar.set_prefix(m.name());
        let result = dwo::run(camera, world, &measurements, m, config, |k| {
            bar.set_position(k as u64 + 1);
        })
        .with_context(|| format!("running {}", m.name()))?;
        let last = result.records.last().expect("at least one keyframe");
        bar.finish_with_message(format!(
            "global RMSE {:.4}, inner {:.4}",
            last.rmse_global, last.rmse_inner
        ));
        out.push(result);
    }
    Ok(out)
}

fn csv(records: &[KeyframeRecord]) -> String {
    let mut s = String::from(
        "keyframe,time_optimise_s,time_setup_s,time_frontend_s,rmse_inner,rmse_both,rmse_global,rmse_all_pairs,inner_frames,outer_frames,points,point_constraints,pose_constraints,metric_loop_edges,appearance_closure,local_scale,graph_keyframes,graph_points,graph_edges\n",
    );
    for r in records {
        let _ = writeln!(
            s,
            "{},{:.6},{:.6},{:.6},{:.6e},{:.6e},{:.6e},{:.6e},{},{},{},{},{},{},{},{:.6},{},{},{}",
            r.index,
            r.time_optimise,
            r.time_setup,
            r.time_frontend,
            r.rmse_inner,
            r.rmse_both,
            r.rmse_global,
            r.rmse_all_pairs,
            r.stats.inner_frames,
            r.stats.outer_frames,
            r.stats.points,
            r.stats.point_constraints,
            r.stats.pose_constraints,
            r.metric_loop_edges,
            r.appearance_closure as u8,
            r.local_scale,
            r.graph_size.0,
            r.graph_size.1,
            r.graph_size.2
        );
    }
    s
}

fn series(results: &[RunResult], f: impl Fn(&KeyframeRecord) -> f64) -> Vec<Series> {
    results
        .iter()
        .enumerate()
        .map(|(i, r)| Series {
            label: r.method.name().to_string(),
            points: r
                .records
                .iter()
                .map(|x| (x.index as f64, f(x)))
                .filter(|p| p.1.is_finite())
                .collect(),
            color: PALETTE[i % PALETTE.len()],
            style: Style::Line,
        })
        .collect()
}

fn figure<'a>(title: &'a str, y: &'a str, log_y: bool) -> Figure<'a> {
    Figure {
        title,
        x_label: "keyframe",
        y_label: y,
        equal_aspect: false,
        log_y,
    }
}

fn report(
    out: &Path,
    scenario: Scenario,
    sensor: SensorKind,
    noise_px: f64,
    config: &RunConfig,
    world: &World,
    results: &[RunResult],
) -> Result<()> {
    let mono = sensor == SensorKind::Mono;
    let unit = if mono {
        "RMSE (unit-normalised)"
    } else {
        "RMSE (m)"
    };
    for r in results {
        let path = out.join(format!("{}.csv", r.method.slug()));
        std::fs::write(&path, csv(&r.records))
            .with_context(|| format!("writing {}", path.display()))?;
    }
    let name = match scenario {
        Scenario::Spiral => "spiral",
        Scenario::Room => "room",
        Scenario::DoubleLoop => "double loop",
    };
    let s = if mono { "mono" } else { "stereo" };
    let t_inner = format!(
        "{name} ({s}): eq. 6.10 RMSE in the inner window ({})",
        config.inner
    );
    let t_both = format!(
        "{name} ({s}): RMSE in both windows ({} + {})",
        config.inner, config.outer
    );
    let t_global = format!("{name} ({s}): RMSE over all edges");
    let t_pairs = format!("{name} ({s}): RMSE over all keyframe pairs");
    plot::plot(
        &out.join("rmse_inner.png"),
        &figure(&t_inner, unit, true),
        &series(results, |r| r.rmse_inner),
    )?;
    plot::plot(
        &out.join("rmse_both.png"),
        &figure(&t_both, unit, true),
        &series(results, |r| r.rmse_both),
    )?;
    plot::plot(
        &out.join("rmse_global.png"),
        &figure(&t_global, unit, true),
        &series(results, |r| r.rmse_global),
    )?;
    plot::plot(
        &out.join("rmse_all_pairs.png"),
        &figure(&t_pairs, unit, true),
        &series(results, |r| r.rmse_all_pairs),
    )?;
    let t_time = format!("{name} ({s}): optimisation time per keyframe");
    plot::plot(
        &out.join("time.png"),
        &figure(&t_time, "seconds", true),
        &series(results, |r| r.time_optimise),
    )?;
    let t_scale = format!("{name} ({s}): local scale (estimated / true distance over 5 keyframes)");
    plot::plot(
        &out.join("local_scale.png"),
        &figure(&t_scale, "scale", false),
        &series(results, |r| r.local_scale),
    )?;
    // Window contents of cDWO (Figure 6.10(b), bottom).
    if let Some(c) = results.iter().find(|r| r.method == Method::Cdwo) {
        let counts: [(&str, RecordValue); 4] = [
            ("frames", |r: &KeyframeRecord| {
                (r.stats.inner_frames + r.stats.outer_frames) as f64
            }),
            ("points", |r: &KeyframeRecord| r.stats.points as f64),
            ("point-pose constraints", |r: &KeyframeRecord| {
                r.stats.point_constraints as f64
            }),
            ("pose-pose constraints", |r: &KeyframeRecord| {
                r.stats.pose_constraints as f64
            }),
        ];
        let series: Vec<Series> = counts
            .iter()
            .enumerate()
            .map(|(i, (label, f))| Series {
                label: label.to_string(),
                points: c
                    .records
                    .iter()
                    .map(|r| (r.index as f64, f(r)))
                    .filter(|p| p.1 > 0.0)
                    .collect(),
                color: PALETTE[i],
                style: Style::Line,
            })
            .collect();
        let t = format!("{name} ({s}): contents of the cDWO windows");
        plot::plot(
            &out.join("cdwo_counts.png"),
            &figure(&t, "count", true),
            &series,
        )?;
    }
    // Top view of the final trajectories (side view of the helix), Sim(3)-aligned.
    {
        let side = scenario == Scenario::Spiral;
        let view = move |c: nalgebra::Vector3<f64>| if side { (c.x, c.z) } else { (c.x, c.y) };
        let truth: Vec<(f64, f64)> = world
            .camera_from_world
            .iter()
            .map(|t| view(sim::trajectory::centre(t)))
            .collect();
        let mut series = vec![Series {
            label: "true".into(),
            points: truth,
            color: plot::GREY,
            style: Style::Line,
        }];
        for (i, r) in results.iter().enumerate() {
            let pts = aligned_centres(world, &r.camera_from_world)
                .into_iter()
                .map(view)
                .collect();
            series.push(Series {
                label: r.method.name().into(),
                points: pts,
                color: PALETTE[i % PALETTE.len()],
                style: Style::Line,
            });
        }
        let (t, y_label) = if side {
            (
                format!("{name} ({s}): final keyframe centres, side view (Sim(3)-aligned)"),
                "z (m)",
            )
        } else {
            (
                format!("{name} ({s}): final keyframe centres, top view (Sim(3)-aligned)"),
                "y (m)",
            )
        };
        plot::plot(
            &out.join("trajectory.png"),
            &Figure {
                title: &t,
                x_label: "x (m)",
                y_label,
                equal_aspect: true,
                log_y: false,
            },
            &series,
        )?;
    }
    // Summary.
    let n = world.camera_from_world.len();
    let mut methods = serde_json::Map::new();
    println!(
        "\n{:<18} {:>12} {:>12} {:>8} {:>12} {:>12} {:>12} {:>12}",
        "method",
        "t 100–200",
        "t 400–500",
        "ratio",
        "RMSE inner",
        "RMSE both",
        "RMSE global",
        "all pairs"
    );
    for r in results {
        let t1 = dwo::median_time(&r.records, 100..200);
        let t2 = dwo::median_time(&r.records, 400..500);
        let mean =
            |f: fn(&KeyframeRecord) -> f64| dwo::mean(&r.records.iter().map(f).collect::<Vec<_>>());
        let last = r.records.last().expect("records");
        let (inner, both, global) = (
            mean(|x| x.rmse_inner),
            mean(|x| x.rmse_both),
            mean(|x| x.rmse_global),
        );
        // Keyframe ranges the run does not reach print as "—", not NaN.
        let ms = |t: f64| {
            if t.is_finite() {
                format!("{:.2}ms", t * 1e3)
            } else {
                "—".to_string()
            }
        };
        let ratio = if (t2 / t1).is_finite() {
            format!("{:.2}", t2 / t1)
        } else {
            "—".to_string()
        };
        println!(
            "{:<18} {:>12} {:>12} {:>8} {:>12.3e} {:>12.3e} {:>12.3e} {:>12.3e}",
            r.method.name(),
            ms(t1),
            ms(t2),
            ratio,
            inner,
            both,
            global,
            last.rmse_all_pairs
        );
        let mut entry = json!({
            "median_time_per_keyframe_100_200_s": nan_null(t1),
            "median_time_per_keyframe_400_500_s": nan_null(t2),
            "time_ratio_400_500_over_100_200": nan_null(t2 / t1),
            "mean_rmse_inner": nan_null(inner),
            "mean_rmse_both": nan_null(both),
            "mean_rmse_global": nan_null(global),
            "final_rmse_inner": nan_null(last.rmse_inner),
            "final_rmse_both": nan_null(last.rmse_both),
            "final_rmse_global": nan_null(last.rmse_global),
            "final_rmse_all_pairs": nan_null(last.rmse_all_pairs),
            "total_optimisation_time_s": r.records.iter().map(|x| x.time_optimise).sum::<f64>(),
            "metric_loop_edges": r.records.iter().map(|x| x.metric_loop_edges).sum::<usize>(),
            "final_graph": { "keyframes": last.graph_size.0, "points": last.graph_size.1, "edges": last.graph_size.2 },
        });
        if let Some(closure) = r.records.iter().find(|x| x.appearance_closure) {
            let k = closure.index;
            let before = r
                .records
                .get(k.saturating_sub(1))
                .map_or(f64::NAN, |x| x.rmse_all_pairs);
            let at_end = scale_stats(world, &r.camera_from_world, k);
            entry["loop_closure"] = json!({
                "keyframe": k,
                "rmse_all_pairs_before": nan_null(before),
                "rmse_all_pairs_first_loop_at_end": nan_null(at_end.rmse_first_loop),
                "rmse_all_pairs_at_end": nan_null(last.rmse_all_pairs),
                "improvement_first_loop": nan_null(before / at_end.rmse_first_loop),
                "local_scale_before_closure": nan_null(r.records.get(k.saturating_sub(1)).map_or(f64::NAN, |x| x.local_scale)),
                "local_scale_spread_before": nan_null(scale_spread(&r.records[..k])),
                "local_scale_spread_after": nan_null(at_end.scale_spread),
            });
        }
        methods.insert(r.method.name().to_string(), entry);
    }
    let summary = json!({
        "scenario": match scenario { Scenario::Spiral => "spiral", Scenario::Room => "room", Scenario::DoubleLoop => "double-loop" },
        "sensor": if mono { "mono" } else { "stereo" },
        "noise_px": noise_px,
        "keyframes": n,
        "points": world.points.len(),
        "inner_window": config.inner,
        "outer_window": config.outer,
        "iterations_per_keyframe": config.iterations,
        "constraint_information": format!("{:?}", config.information),
        "theta": config.theta,
        "seed": config.seed,
        "rmse": if mono { "eq. 6.10 with unit-normalised relative translations" } else { "eq. 6.10 (m)" },
        "methods": methods,
    });
    let path = out.join("summary.json");
    std::fs::write(&path, serde_json::to_string_pretty(&summary)?)
        .with_context(|| format!("writing {}", path.display()))?;
    println!(
        "wrote CSV, PNG plots and {} to {}",
        path.file_name().unwrap().to_string_lossy(),
        out.display()
    );
    Ok(())
}

/// A per-keyframe quantity to plot.
type RecordValue = fn(&KeyframeRecord) -> f64;

fn nan_null(x: f64) -> serde_json::Value {
    if x.is_finite() {
        json!(x)
    } else {
        serde_json::Value::Null
    }
}

/// Keyframe centres of an estimate, Sim(3)-aligned to the truth.
fn aligned_centres(world: &World, estimate: &[lie::Sim3]) -> Vec<nalgebra::Vector3<f64>> {
    use lie::LieGroup;
    let est: Vec<nalgebra::Vector3<f64>> = estimate
        .iter()
        .map(|t| t.inverse().act(&nalgebra::Vector3::zeros()))
        .collect();
    let tru: Vec<nalgebra::Vector3<f64>> = world
        .camera_from_world
        .iter()
        .map(sim::trajectory::centre)
        .collect();
    match geom::align::align_sim3(&tru, &est) {
        Ok(s) => est.iter().map(|c| s.act(c)).collect(),
        Err(_) => est,
    }
}

struct ScaleStats {
    rmse_first_loop: f64,
    scale_spread: f64,
}

/// After a run: the all-pairs RMSE among the keyframes before the closure, and the spread of
/// the local scale over the whole run.
fn scale_stats(world: &World, estimate: &[lie::Sim3], closure: usize) -> ScaleStats {
    let rmse = dwo::relative_translation_rmse(
        estimate,
        &world.camera_from_world,
        (0..closure).flat_map(|i| (i + 1..closure).map(move |j| (i, j))),
        true,
    );
    use lie::LieGroup;
    let scales: Vec<f64> = (5..estimate.len())
        .map(|k| {
            let c = |t: &lie::Sim3| t.inverse().act(&nalgebra::Vector3::zeros());
            (c(&estimate[k]) - c(&estimate[k - 5])).norm()
                / (sim::trajectory::centre(&world.camera_from_world[k])
                    - sim::trajectory::centre(&world.camera_from_world[k - 5]))
                .norm()
        })
        .collect();
    ScaleStats {
        rmse_first_loop: rmse,
        scale_spread: spread(&scales),
    }
}

/// max/min of the local scale.
fn spread(scales: &[f64]) -> f64 {
    let v: Vec<f64> = scales
        .iter()
        .copied()
        .filter(|x| x.is_finite() && *x > 0.0)
        .collect();
    if v.is_empty() {
        return f64::NAN;
    }
    v.iter().copied().fold(f64::MIN, f64::max) / v.iter().copied().fold(f64::MAX, f64::min)
}

fn scale_spread(records: &[KeyframeRecord]) -> f64 {
    spread(
        &records
            .iter()
            .filter(|r| r.index >= 5)
            .map(|r| r.local_scale)
            .collect::<Vec<_>>(),
    )
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn bad_options_are_refused_before_anything_runs() {
        let out = std::env::temp_dir().join("dwslam-dwo-bad-options");
        for noise in [0.0, -1.0, f64::NAN, f64::INFINITY] {
            let args = DwoArgs {
                noise,
                out: out.clone(),
                ..DwoArgs::double_loop()
            };
            let e = run(args).expect_err("a non-positive or non-finite noise must be refused");
            assert!(e.to_string().contains("--noise"), "{e}");
        }
        // Unknown method names are refused by the parser (tests/bad_arguments.rs).
        let args = DwoArgs {
            methods: Some(Vec::new()),
            out: out.clone(),
            ..DwoArgs::double_loop()
        };
        assert!(
            run(args)
                .unwrap_err()
                .to_string()
                .contains("--methods is empty")
        );
        assert!(!out.exists(), "nothing is written for refused options");
    }
}

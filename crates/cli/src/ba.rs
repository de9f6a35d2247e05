//! `dwslam ba`: bundle adjustment of a BAL problem (thesis §3.3), or of a synthetic scene.

use crate::args;
use anyhow::{Context, Result, bail};
use clap::{Args, ValueEnum};
use data::bal::{BalProblem, read_bal, write_bal};
use lsq::{LinearSolver, SolverOptions};
use nalgebra::Vector2;
use sim::ba_scene::{CircleSceneParams, circle_scene, perturb, to_bal};
use slam::ba::BalAdjustment;
use slam::factors::BalCameraState;
use std::path::PathBuf;
use std::time::Instant;

/// The linear solver of `dwslam ba`.
#[derive(Clone, Copy, Debug, PartialEq, Eq, ValueEnum)]
pub enum BaSolver {
    /// Schur complement, reduced camera system by sparse Cholesky.
    SchurCholesky,
    /// Schur complement, reduced system by conjugate gradients (Schur-Jacobi preconditioner).
    SchurPcg,
    /// Dense Cholesky of the full system (small problems only).
    Dense,
}

/// Options of `dwslam ba`.
#[derive(Args, Debug)]
pub struct BaArgs {
    /// A BAL problem (`problem-*.txt`, plain or `.bz2`). Not needed with `--synthetic`.
    pub file: Option<PathBuf>,
    /// Generate a synthetic scene instead: `CAMERAS,POINTS` (cameras on a circle of radius
    /// 10 m looking at a ball of points of radius 3 m, tracks of up to 8 cameras).
    #[arg(long, value_name = "CAMERAS,POINTS")]
    pub synthetic: Option<String>,
    /// Pixel noise σ of the synthetic scene.
    #[arg(long, default_value_t = 1.0)]
    pub noise: f64,
    /// Seed of the synthetic scene and of its initial perturbation.
    #[arg(long, default_value_t = 1)]
    pub seed: u64,
    /// Write the (synthetic or read) problem at its initial values as a BAL file, e.g. for a
    /// peer solver.
    #[arg(long)]
    pub save_problem: Option<PathBuf>,
    /// Linear solver.
    #[arg(long, value_enum, default_value_t = BaSolver::SchurCholesky)]
    pub solver: BaSolver,
    /// Maximum Levenberg-Marquardt iterations (each linear solve counts, as in Ceres).
    #[arg(long, default_value_t = 50)]
    pub max_iterations: usize,
    /// Stop when a step reduces the cost by less than this fraction (Ceres's default).
    #[arg(long, default_value_t = 1e-6)]
    pub function_tolerance: f64,
    /// Relative residual at which conjugate gradients stop (`--solver schur-pcg`): each
    /// Levenberg-Marquardt step needs only an inexact solve; 0.1 is Ceres's default forcing
    /// constant η.
    #[arg(long, default_value_t = 0.1)]
    pub pcg_tolerance: f64,
    /// Worker threads (default: all cores).
    #[arg(long)]
    pub threads: Option<usize>,
    /// Sparse Cholesky organisation of the reduced camera system (`--solver schur-cholesky`).
    #[arg(long, value_enum, default_value_t = crate::pgo::CholeskyArg::Auto)]
    pub cholesky: crate::pgo::CholeskyArg,
    /// Huber kernel of this width in pixels (default: plain least squares).
    #[arg(long)]
    pub huber: Option<f64>,
    /// Write the optimised problem here (BAL format: cameras and points at the optimum).
    #[arg(long)]
    pub out: Option<PathBuf>,
    /// Write a machine-readable summary here.
    #[arg(long)]
    pub json: Option<PathBuf>,
    /// No per-iteration lines.
    #[arg(long)]
    pub quiet: bool,
}

fn parse_synthetic(spec: &str) -> Result<(usize, usize)> {
    let parts: Vec<&str> = spec.split(',').collect();
    let [c, p] = parts.as_slice() else {
        bail!("--synthetic expects CAMERAS,POINTS, got {spec:?}");
    };
    let cameras: usize = c
        .trim()
        .parse()
        .with_context(|| format!("--synthetic: cameras {c:?} is not a count"))?;
    let points: usize = p
        .trim()
        .parse()
        .with_context(|| format!("--synthetic: points {p:?} is not a count"))?;
    if cameras < 3 || points < 1 {
        bail!("--synthetic needs at least 3 cameras and 1 point");
    }
    Ok((cameras, points))
}

/// Entry point of `dwslam ba`.
pub fn run(args: BaArgs) -> Result<()> {
    // Everything the command line says is checked before any work.
    let synthetic = match (&args.file, &args.synthetic) {
        (Some(_), Some(_)) => bail!("give either a BAL file or --synthetic, not both"),
        (None, None) => bail!("give a BAL file or --synthetic CAMERAS,POINTS"),
        (Some(file), None) => {
            args::input_file(file, "BAL file")?;
            None
        }
        (None, Some(spec)) => Some(parse_synthetic(spec)?),
    };
    if !(args.noise.is_finite() && args.noise >= 0.0) {
        bail!("--noise must be a non-negative number (got {})", args.noise);
    }
    let kernel = match args.huber {
        Some(b) if b.is_finite() && b > 0.0 => Some(lsq::RobustKernel::Huber(b)),
        Some(b) => bail!("--huber must be a positive width, got {b}"),
        None => None,
    };
    anyhow::ensure!(args.threads != Some(0), "--threads must be at least 1");
    anyhow::ensure!(
        args.pcg_tolerance > 0.0 && args.pcg_tolerance < 1.0,
        "--pcg-tolerance must lie in (0, 1) (got {})",
        args.pcg_tolerance
    );
    anyhow::ensure!(
        args.function_tolerance.is_finite() && args.function_tolerance >= 0.0,
        "--function-tolerance must be a non-negative number (got {})",
        args.function_tolerance
    );
    for (path, what) in [
        (&args.save_problem, "--save-problem"),
        (&args.out, "--out"),
        (&args.json, "--json"),
    ] {
        if let Some(p) = path {
            args::output_file(p, what)?;
        }
    }
    let start = Instant::now();
    let (mut problem, name): (BalProblem, String) = match (&args.file, synthetic) {
        (Some(file), _) => (read_bal(file)?, file.display().to_string()),
        (None, Some((cameras, points))) => {
            let scene = circle_scene(&CircleSceneParams {
                cameras,
                points,
                noise_sigma: args.noise,
                seed: args.seed,
                ..Default::default()
            });
            let (poses, pts) = perturb(&scene, 0.05, 0.005, 0.05, args.seed.wrapping_add(1));
            (
                to_bal(&scene, &poses, &pts),
                format!(
                    "synthetic {cameras} cameras, {points} points, σ = {} px",
                    args.noise
                ),
            )
        }
        (None, None) => unreachable!("checked above"),
    };
    if let Some(path) = &args.save_problem {
        write_bal(&problem, path).with_context(|| format!("writing {}", path.display()))?;
        println!("wrote {}", path.display());
    }
    let cameras: Vec<BalCameraState> = problem
        .cameras
        .iter()
        .map(|c| BalCameraState {
            camera_from_world: c.camera_from_world,
            intrinsics: c.intrinsics,
        })
        .collect();
    let observations: Vec<(usize, usize, Vector2<f64>)> = problem
        .observations
        .iter()
        .map(|o| (o.camera, o.point, o.measurement))
        .collect();
    let mut ba = BalAdjustment::new(&cameras, &problem.points_world, &observations, kernel)?;
    println!(
        "{name}: {} cameras, {} points, {} observations",
        cameras.len(),
        problem.points_world.len(),
        observations.len()
    );
    if !ba.rejected.is_empty() {
        println!(
            "{} observation(s) have their point behind the camera at the initial values and are left out (first: #{})",
            ba.rejected.len(),
            ba.rejected[0]
        );
    }
    let unknowns = 9 * cameras.len() + 3 * problem.points_world.len();
    let linear_solver = match args.solver {
        BaSolver::SchurCholesky => LinearSolver::SchurCholesky,
        BaSolver::SchurPcg => LinearSolver::SchurPcg,
        BaSolver::Dense => {
            if unknowns > 3000 {
                bail!(
                    "--solver dense is for small problems (≤ 3000 unknowns); this one has {unknowns}"
                );
            }
            ba.problem.set_eliminated::<nalgebra::Vector3<f64>>(false);
            LinearSolver::Dense
        }
    };
    let options = SolverOptions {
        linear_solver,
        max_iterations: args.max_iterations,
        function_tolerance: args.function_tolerance,
        threads: args.threads,
        pcg_tolerance: args.pcg_tolerance,
        cholesky_method: args.cholesky.into(),
        ..Default::default()
    };
    if !args.quiet {
        println!(
            "{:>4}  {:>16}  {:>9}  {:>9}  {:>6}  {:>6}  {:>8}  {:>8}  {:>8}  {:>9}",
            "iter",
            "½Σ‖r‖²",
            "λ",
            "‖δ‖",
            "step",
            "lin.it",
            "lin ms",
            "build ms",
            "solve ms",
            "total s"
        );
    }
    let quiet = args.quiet;
    let cpu_before = slam::clock::process_cpu_time().map(|t| t.as_secs_f64());
    let summary = ba.problem.optimise_with(&options, |it| {
        if !quiet {
            println!(
                "{:>4}  {:>16.6}  {:>9.2e}  {:>9.2e}  {:>6}  {:>6}  {:>8.2}  {:>8.2}  {:>8.2}  {:>9.3}",
                it.iteration,
                it.cost,
                it.lambda,
                it.step_norm,
                if it.accepted { "taken" } else { "reject" },
                it.linear_iterations,
                it.time_linearize.as_secs_f64() * 1e3,
                it.time_build.as_secs_f64() * 1e3,
                it.time_solve.as_secs_f64() * 1e3,
                it.elapsed.as_secs_f64()
            );
        }
    })?;
    let cpu_seconds = match (
        cpu_before,
        slam::clock::process_cpu_time().map(|t| t.as_secs_f64()),
    ) {
        (Some(a), Some(b)) => Some(b - a),
        _ => None,
    };
    let n_obs = observations.len() - ba.rejected.len();
    // With no kernel, cost = ½Σ‖r‖², so RMS per observation = √(2·cost/n).
    let rms = |chi2: f64| (chi2 / n_obs.max(1) as f64).sqrt();
    let iterations = summary.iterations.len();
    let per_iteration = if iterations > 0 {
        (summary.time_total - summary.time_structure).as_secs_f64() / iterations as f64
    } else {
        0.0
    };
    println!(
        "{:?} after {} iterations ({} steps taken)",
        summary.termination,
        iterations,
        summary.accepted_steps()
    );
    println!(
        "initial: ½Σ‖r‖² = {:.6}, RMS reprojection error {:.4} px",
        summary.initial_chi2 / 2.0,
        rms(summary.initial_chi2)
    );
    println!(
        "final:   ½Σ‖r‖² = {:.6}, RMS reprojection error {:.4} px   [½Σ‖r‖² is Ceres's cost; RMS = √(Σ‖r‖²/observations)]",
        summary.final_chi2 / 2.0,
        rms(summary.final_chi2)
    );
    if kernel.is_some() {
        println!(
            "         robust cost ½Σρ: {:.6} → {:.6}",
            summary.initial_cost, summary.final_cost
        );
    }
    println!(
        "time: {:.3} s optimisation ({:.4} s per iteration, {:.3} s set-up), {:.3} s total",
        summary.time_total.as_secs_f64(),
        per_iteration,
        summary.time_structure.as_secs_f64(),
        start.elapsed().as_secs_f64()
    );
    if let Some(path) = &args.out {
        for (c, v) in problem.cameras.iter_mut().zip(&ba.cameras) {
            let state = ba.problem.value(*v);
            c.camera_from_world = state.camera_from_world;
            c.intrinsics = state.intrinsics;
        }
        for (p, v) in problem.points_world.iter_mut().zip(&ba.points) {
            *p = *ba.problem.value(*v);
        }
        write_bal(&problem, path).with_context(|| format!("writing {}", path.display()))?;
        println!("wrote the optimised problem to {}", path.display());
    }
    if let Some(path) = &args.json {
        let json = serde_json::json!({
            "problem": name,
            "cameras": cameras.len(),
            "points": problem.points_world.len(),
            "observations": n_obs,
            "rejected_observations": ba.rejected.len(),
            "solver": format!("{:?}", summary.linear_solver),
            "threads": args.threads,
            "initial_cost": summary.initial_chi2 / 2.0,
            "final_cost": summary.final_chi2 / 2.0,
            "initial_robust_cost": summary.initial_cost,
            "final_robust_cost": summary.final_cost,
            "iterations": iterations,
            "accepted_steps": summary.accepted_steps(),
            "termination": format!("{:?}", summary.termination),
            "time_per_iteration_s": per_iteration,
            "cpu_time_per_iteration_s": cpu_seconds.map(|c| c / iterations.max(1) as f64),
            "setup_time_s": summary.time_structure.as_secs_f64(),
            "solve_time_s": summary.time_total.as_secs_f64(),
            "total_time_s": start.elapsed().as_secs_f64(),
            "rms_px": rms(summary.final_chi2),
            "initial_rms_px": rms(summary.initial_chi2),
            "per_iteration": summary.iterations.iter().map(|it| serde_json::json!({
                "iteration": it.iteration, "cost": it.chi2 / 2.0, "accepted": it.accepted,
                "elapsed_s": it.elapsed.as_secs_f64(), "linear_iterations": it.linear_iterations,
            })).collect::<Vec<_>>(),
        });
        std::fs::write(path, serde_json::to_string_pretty(&json)?)
            .with_context(|| format!("writing {}", path.display()))?;
        println!("wrote {}", path.display());
    }
    Ok(())
}

//! `dwslam pgo`: pose-graph optimisation of a g2o file (thesis §5.3.2–5.3.3).

use crate::plot::{self, Figure, Series, Style};
use anyhow::{Context, Result, bail};
use clap::{Args, ValueEnum};
use data::PoseGraph;
use data::g2o::{G2oGraph, read_g2o, write_g2o_graph};
use lie::{LieGroup, LogJacobian, Se3, Sim3};
use lsq::{LinearSolver, Manifold, SolverOptions, Summary};
use nalgebra::SMatrix;
use slam::pose_graph::{Constraint, PoseGraphProblem, rigid_from_similarity};
use std::path::PathBuf;
use std::time::Instant;

/// The group the poses are optimised in.
/// Organisation of the sparse Cholesky factorisation (shared by `pgo` and `ba`).
#[derive(Clone, Copy, Debug, PartialEq, Eq, ValueEnum)]
pub enum CholeskyArg {
    /// faer's choice from the flop count per non-zero of the factor
    Auto,
    /// Column by column, scalar (best for very sparse factors)
    Simplicial,
    /// Dense panels of columns (supernodes)
    Supernodal,
}

impl From<CholeskyArg> for lsq::CholeskyMethod {
    fn from(a: CholeskyArg) -> Self {
        match a {
            CholeskyArg::Auto => lsq::CholeskyMethod::Auto,
            CholeskyArg::Simplicial => lsq::CholeskyMethod::Simplicial,
            CholeskyArg::Supernodal => lsq::CholeskyMethod::Supernodal,
        }
    }
}

#[derive(Clone, Copy, Debug, PartialEq, Eq, ValueEnum)]
pub enum Group {
    /// Rigid motions: SE(3) for 3D files, SE(2) for 2D files.
    Se3,
    /// Similarities Sim(3) (3D files): scale may drift between poses (thesis eq. 5.17).
    Sim3,
}

/// The linear solver.
#[derive(Clone, Copy, Debug, PartialEq, Eq, ValueEnum)]
pub enum Solver {
    /// Sparse Cholesky (faer, AMD ordering on the block graph).
    Cholesky,
    /// Conjugate gradients with a block-Jacobi preconditioner.
    Pcg,
    /// Dense Cholesky (small graphs only).
    Dense,
}

/// The pose-graph Jacobian.
#[derive(Clone, Copy, Debug, PartialEq, Eq, ValueEnum)]
pub enum JacobianArg {
    /// Exact: inverse left Jacobian.
    Exact,
    /// First-order CBH (thesis eq. A.49).
    Cbh1,
    /// Second-order CBH (thesis eq. A.50).
    Cbh2,
    /// Third-order CBH (thesis eq. 5.22).
    Cbh3,
}

impl From<JacobianArg> for LogJacobian {
    fn from(j: JacobianArg) -> Self {
        match j {
            JacobianArg::Exact => LogJacobian::Exact,
            JacobianArg::Cbh1 => LogJacobian::Cbh1,
            JacobianArg::Cbh2 => LogJacobian::Cbh2,
            JacobianArg::Cbh3 => LogJacobian::Cbh3,
        }
    }
}

/// The damping of Levenberg-Marquardt.
#[derive(Clone, Copy, Debug, PartialEq, Eq, ValueEnum)]
pub enum DampingArg {
    /// `λ·diag(H)`.
    Marquardt,
    /// `λ·I`.
    Levenberg,
}

/// Options of `dwslam pgo`.
#[derive(Args, Debug)]
pub struct PgoArgs {
    /// A g2o file (VERTEX_SE2/EDGE_SE2 or VERTEX_SE3:QUAT/EDGE_SE3:QUAT, FIX).
    pub file: PathBuf,
    /// Group to optimise in.
    #[arg(long, value_enum, default_value_t = Group::Se3)]
    pub group: Group,
    /// Linear solver.
    #[arg(long, value_enum, default_value_t = Solver::Cholesky)]
    pub solver: Solver,
    /// Jacobian of the pose-graph residual.
    #[arg(long, value_enum, default_value_t = JacobianArg::Exact)]
    pub jacobian: JacobianArg,
    /// Maximum Levenberg-Marquardt iterations.
    #[arg(long, default_value_t = 100)]
    pub max_iterations: usize,
    /// Stop when a step reduces ½χ² by less than this fraction (GTSAM's default relativeErrorTol).
    #[arg(long, default_value_t = 1e-5)]
    pub relative_tolerance: f64,
    /// Stop when a step reduces ½χ² by less than this amount (GTSAM's default absoluteErrorTol).
    #[arg(long, default_value_t = 1e-5)]
    pub absolute_tolerance: f64,
    /// Levenberg-Marquardt damping: `levenberg` (λ·I) or `marquardt` (λ·diag H). The
    /// defaults (levenberg, λ₀ = 1e-5, decrease floor 0.1) were chosen on all twelve standard
    /// pose graphs: they reach the same minima as Marquardt damping in fewer iterations, and
    /// on MIT Marquardt scaling does not converge in 200 iterations (see bench/README.md).
    #[arg(long, value_enum, default_value_t = DampingArg::Levenberg)]
    pub damping: DampingArg,
    /// Initial damping λ.
    #[arg(long, default_value_t = 1e-5)]
    pub initial_lambda: f64,
    /// Floor of the damping decrease factor per good step (Nielsen's rule).
    #[arg(long, default_value_t = 0.1)]
    pub lambda_decrease_floor: f64,
    /// Worker threads (default: all cores).
    #[arg(long)]
    pub threads: Option<usize>,
    /// Sparse Cholesky organisation (`--solver cholesky`).
    #[arg(long, value_enum, default_value_t = CholeskyArg::Auto)]
    pub cholesky: CholeskyArg,
    /// Information of the log-scale σ of each constraint for `--group sim3` (default: the mean
    /// rotational information of the constraint, so scale is held as firmly as rotation).
    #[arg(long)]
    pub scale_information: Option<f64>,
    /// Hold this vertex fixed (default: the file's FIX vertices, else the first vertex).
    #[arg(long)]
    pub fix: Option<u64>,
    /// Write the optimised graph here (g2o).
    #[arg(long)]
    pub out: Option<PathBuf>,
    /// Plot the initial and optimised trajectories here (top view for 3D; .png or .svg).
    #[arg(long)]
    pub plot: Option<PathBuf>,
    /// Write a machine-readable summary here.
    #[arg(long)]
    pub json: Option<PathBuf>,
    /// No per-iteration progress lines.
    #[arg(long)]
    pub quiet: bool,
}

/// The pose graph converted to the thesis's convention: `T_i = world_from_body⁻¹`,
/// `T_ji = Z⁻¹`.
fn to_problem_inputs<G: LieGroup<D>, const D: usize>(
    graph: &PoseGraph<G, D>,
) -> (Vec<G>, Vec<Constraint<G, D>>) {
    let poses = graph
        .vertices()
        .iter()
        .map(|v| v.world_from_body.inverse())
        .collect();
    let constraints = graph
        .edges()
        .iter()
        .map(|e| Constraint {
            i: graph
                .vertex_index(e.from)
                .expect("reader checked edge ends"),
            j: graph.vertex_index(e.to).expect("reader checked edge ends"),
            measured: e.measurement.inverse(),
            information: e.information,
        })
        .collect();
    (poses, constraints)
}

fn fixed_indices<G, const D: usize>(graph: &PoseGraph<G, D>, fix: Option<u64>) -> Result<Vec<usize>>
where
    G: LieGroup<D>,
{
    let ids: Vec<u64> = match fix {
        Some(id) => vec![id],
        None if !graph.fixed().is_empty() => graph.fixed().to_vec(),
        None => graph
            .vertices()
            .first()
            .map(|v| vec![v.id])
            .unwrap_or_default(),
    };
    ids.iter()
        .map(|id| {
            graph
                .vertex_index(*id)
                .with_context(|| format!("--fix {id}: no such vertex"))
        })
        .collect()
}

/// Runs the optimisation; returns the summary and the optimised `camera_from_world` poses.
fn optimise<G: LieGroup<D> + Manifold, const D: usize>(
    poses: &[G],
    constraints: &[Constraint<G, D>],
    fixed: &[usize],
    args: &PgoArgs,
) -> Result<(Summary, Vec<G>)> {
    let mut pg = PoseGraphProblem::new(poses, constraints, fixed, args.jacobian.into())?;
    let options = SolverOptions {
        linear_solver: match args.solver {
            Solver::Cholesky => LinearSolver::SparseCholesky,
            Solver::Pcg => LinearSolver::Pcg,
            Solver::Dense => LinearSolver::Dense,
        },
        max_iterations: args.max_iterations,
        function_tolerance: args.relative_tolerance,
        absolute_function_tolerance: args.absolute_tolerance,
        threads: args.threads,
        cholesky_method: args.cholesky.into(),
        damping: match args.damping {
            DampingArg::Marquardt => lsq::Damping::Marquardt,
            DampingArg::Levenberg => lsq::Damping::Levenberg,
        },
        initial_lambda: args.initial_lambda,
        lambda_decrease_floor: args.lambda_decrease_floor,
        ..Default::default()
    };
    if !args.quiet {
        println!(
            "{:>4}  {:>14}  {:>10}  {:>9}  {:>9}  {:>6}  {:>8}  {:>8}  {:>8}",
            "iter", "½χ²", "rel. Δ", "λ", "‖δ‖", "step", "lin ms", "build ms", "solve ms"
        );
    }
    let mut previous = None;
    let quiet = args.quiet;
    let summary = pg.problem.optimise_with(&options, |it| {
        if quiet {
            return;
        }
        let rel = match previous {
            Some(p) if it.accepted => (p - it.cost) / p,
            _ => 0.0,
        };
        if it.accepted {
            previous = Some(it.cost);
        }
        println!(
            "{:>4}  {:>14.6}  {:>10.3e}  {:>9.2e}  {:>9.2e}  {:>6}  {:>8.2}  {:>8.2}  {:>8.2}",
            it.iteration,
            it.cost,
            rel,
            it.lambda,
            it.step_norm,
            if it.accepted { "taken" } else { "reject" },
            it.time_linearize.as_secs_f64() * 1e3,
            it.time_build.as_secs_f64() * 1e3,
            it.time_solve.as_secs_f64() * 1e3,
        );
    })?;
    Ok((summary, pg.camera_from_world()))
}

/// Sim(3) inputs from SE(3) ones: unit scales, constraint information extended by the
/// log-scale entry.
fn to_sim3(
    poses: &[Se3],
    constraints: &[Constraint<Se3, 6>],
    scale_information: Option<f64>,
) -> (Vec<Sim3>, Vec<Constraint<Sim3, 7>>) {
    let poses = poses.iter().map(Sim3::from_se3).collect();
    let constraints = constraints
        .iter()
        .map(|c| {
            let mut info = SMatrix::<f64, 7, 7>::zeros();
            info.fixed_view_mut::<6, 6>(0, 0).copy_from(&c.information);
            let rot = (c.information[(3, 3)] + c.information[(4, 4)] + c.information[(5, 5)]) / 3.0;
            info[(6, 6)] = scale_information.unwrap_or(rot);
            Constraint {
                i: c.i,
                j: c.j,
                measured: Sim3::from_se3(&c.measured),
                information: info,
            }
        })
        .collect();
    (poses, constraints)
}

/// Entry point of `dwslam pgo`.
pub fn run(args: PgoArgs) -> Result<()> {
    let start = Instant::now();
    let file = read_g2o(&args.file).with_context(|| format!("reading {}", args.file.display()))?;
    for tag in &file.report.unknown_tags {
        eprintln!(
            "warning: {}: {} line(s) with unknown tag {:?} ignored (first at line {})",
            args.file.display(),
            tag.count,
            tag.tag,
            tag.lines.first().copied().unwrap_or(0)
        );
    }
    for w in &file.report.information {
        eprintln!("warning: {}: {w}", args.file.display());
    }
    if let Some(init) = &file.report.initialisation {
        println!(
            "{}: no vertices in the file; initial poses chained along a spanning tree from vertex {} ({} of {} tree edges are odometry, {} component(s))",
            args.file.display(),
            init.root,
            init.odometry_tree_edges,
            init.tree_edges,
            init.components
        );
    }
    let mut graph = file.graph;
    println!(
        "{}: {}D pose graph, {} vertices, {} edges; optimising in {}",
        args.file.display(),
        graph.dimension(),
        graph.vertex_count(),
        graph.edge_count(),
        match (&graph, args.group) {
            (G2oGraph::Se2(_), _) => "SE(2)",
            (G2oGraph::Se3(_), Group::Se3) => "SE(3)",
            (G2oGraph::Se3(_), Group::Sim3) => "Sim(3)",
        }
    );
    let initial_xy: Vec<(f64, f64)> = trajectory_xy(&graph);
    let (summary, optimised_cost) = match &mut graph {
        G2oGraph::Se2(g) => {
            if args.group == Group::Sim3 {
                bail!(
                    "--group sim3 needs a 3D pose graph; {} is 2D",
                    args.file.display()
                );
            }
            let (poses, constraints) = to_problem_inputs(g);
            let fixed = fixed_indices(g, args.fix)?;
            let (summary, result) = optimise(&poses, &constraints, &fixed, &args)?;
            for (k, t) in result.iter().enumerate() {
                let id = g.vertices()[k].id;
                g.set_pose(id, t.inverse());
            }
            let cost = g.cost();
            (summary, cost)
        }
        G2oGraph::Se3(g) => {
            let (poses, constraints) = to_problem_inputs(g);
            let fixed = fixed_indices(g, args.fix)?;
            let (summary, result): (Summary, Vec<Se3>) = match args.group {
                Group::Se3 => optimise(&poses, &constraints, &fixed, &args)?,
                Group::Sim3 => {
                    let (p, c) = to_sim3(&poses, &constraints, args.scale_information);
                    let (summary, result) = optimise(&p, &c, &fixed, &args)?;
                    (summary, result.iter().map(rigid_from_similarity).collect())
                }
            };
            for (k, t) in result.iter().enumerate() {
                let id = g.vertices()[k].id;
                g.set_pose(id, t.inverse());
            }
            let cost = g.cost();
            (summary, cost)
        }
    };
    let total = start.elapsed();
    println!(
        "{:?} after {} iterations ({} steps taken)",
        summary.termination,
        summary.iterations.len(),
        summary.accepted_steps()
    );
    println!(
        "initial: ½χ² = {:.6}  (χ² = {:.6})",
        summary.initial_cost, summary.initial_chi2
    );
    println!(
        "final:   ½χ² = {:.6}  (χ² = {:.6})   [½χ² is what Ceres and GTSAM report; g2o reports χ²]",
        summary.final_cost, summary.final_chi2
    );
    if args.group == Group::Sim3 {
        println!(
            "         SE(3) ½χ² of the rigid poses recovered from the similarities: {optimised_cost:.6}"
        );
    }
    println!(
        "time: optimisation {:.3} s (structure {:.3} s), total {:.3} s",
        summary.time_total.as_secs_f64(),
        summary.time_structure.as_secs_f64(),
        total.as_secs_f64()
    );
    if let Some(out) = &args.out {
        write_g2o_graph(&graph, out).with_context(|| format!("writing {}", out.display()))?;
        println!("wrote {}", out.display());
    }
    if let Some(path) = &args.plot {
        let optimised_xy = trajectory_xy(&graph);
        let name = args
            .file
            .file_name()
            .map(|n| n.to_string_lossy().into_owned())
            .unwrap_or_default();
        let title = format!(
            "{name}: initial and optimised ({})",
            if graph.dimension() == 3 {
                "top view"
            } else {
                "2D"
            }
        );
        plot::plot(
            path,
            &Figure {
                title: &title,
                x_label: "x",
                y_label: "y",
                equal_aspect: true,
                log_y: false,
            },
            &[
                Series {
                    label: "initial".into(),
                    points: initial_xy,
                    color: plot::GREY,
                    style: Style::Line,
                },
                Series {
                    label: "optimised".into(),
                    points: optimised_xy,
                    color: plot::PALETTE[0],
                    style: Style::Line,
                },
            ],
        )?;
        println!("wrote {}", path.display());
    }
    if let Some(path) = &args.json {
        let iterations: Vec<_> = summary
            .iterations
            .iter()
            .map(|it| {
                serde_json::json!({
                    "iteration": it.iteration, "cost": it.cost, "lambda": it.lambda,
                    "step_norm": it.step_norm, "accepted": it.accepted,
                    "time_linearize_s": it.time_linearize.as_secs_f64(),
                    "time_build_s": it.time_build.as_secs_f64(),
                    "time_solve_s": it.time_solve.as_secs_f64(),
                    "elapsed_s": it.elapsed.as_secs_f64(),
                })
            })
            .collect();
        let json = serde_json::json!({
            "file": args.file.display().to_string(),
            "dimension": graph.dimension(),
            "group": format!("{:?}", args.group).to_lowercase(),
            "vertices": graph.vertex_count(),
            "edges": graph.edge_count(),
            "solver": format!("{:?}", summary.linear_solver),
            "jacobian": format!("{:?}", args.jacobian).to_lowercase(),
            "initial_cost": summary.initial_cost,
            "final_cost": summary.final_cost,
            "initial_chi2": summary.initial_chi2,
            "final_chi2": summary.final_chi2,
            "iterations": summary.iterations.len(),
            "accepted_steps": summary.accepted_steps(),
            "termination": format!("{:?}", summary.termination),
            "solve_time_s": summary.time_total.as_secs_f64(),
            "structure_time_s": summary.time_structure.as_secs_f64(),
            "total_time_s": total.as_secs_f64(),
            "per_iteration": iterations,
        });
        std::fs::write(path, serde_json::to_string_pretty(&json)?)
            .with_context(|| format!("writing {}", path.display()))?;
        println!("wrote {}", path.display());
    }
    Ok(())
}

/// `(x, y)` of every vertex's position (`world_from_body` translation), in vertex order.
fn trajectory_xy(graph: &G2oGraph) -> Vec<(f64, f64)> {
    match graph {
        G2oGraph::Se2(g) => g
            .vertices()
            .iter()
            .map(|v| {
                (
                    v.world_from_body.translation().x,
                    v.world_from_body.translation().y,
                )
            })
            .collect(),
        G2oGraph::Se3(g) => g
            .vertices()
            .iter()
            .map(|v| {
                (
                    v.world_from_body.translation().x,
                    v.world_from_body.translation().y,
                )
            })
            .collect(),
    }
}

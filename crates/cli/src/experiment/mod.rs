//! `dwslam experiment …`: reproductions of the thesis's experiments.

use anyhow::{Context, Result};
use clap::{Args, Subcommand};
use std::path::PathBuf;

pub mod cbh_jacobians;
pub mod dwo;
pub mod scale_drift;

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
    /// Write the table as JSON (`rows`: group, sigma, d_norm, err_j1, err_j2, err_j3).
    #[arg(long)]
    json: Option<PathBuf>,
}

/// Runs one experiment.
pub fn run(cmd: ExperimentCommand) -> Result<()> {
    match cmd {
        ExperimentCommand::CbhJacobians(args) => run_cbh(args),
        ExperimentCommand::Dwo(args) => dwo::run(args),
        ExperimentCommand::ScaleDrift(args) => scale_drift::run(args),
    }
}

fn run_cbh(args: CbhArgs) -> Result<()> {
    anyhow::ensure!(args.samples > 0, "--samples must be at least 1");
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
    if let Some(path) = &args.json {
        let json = serde_json::json!({ "samples": args.samples, "seed": args.seed, "rows": rows });
        std::fs::write(path, serde_json::to_string_pretty(&json)?)
            .with_context(|| format!("writing {}", path.display()))?;
        println!("wrote {}", path.display());
    }
    Ok(())
}

//! `dwslam`: the command-line front of the dwslam visual SLAM system.

use anyhow::Result;
use clap::{Parser, Subcommand};

mod ba;
mod experiment;
mod inspect;
mod pgo;
mod plot;
mod render;

/// dwslam — double window optimisation visual SLAM (Strasdat 2012).
#[derive(Parser, Debug)]
#[command(name = "dwslam", version, about, long_about = None)]
struct Cli {
    #[command(subcommand)]
    command: Command,
}

#[derive(Subcommand, Debug)]
enum Command {
    /// Reproduce an experiment of the thesis.
    #[command(subcommand)]
    Experiment(experiment::ExperimentCommand),
    /// Pose-graph optimisation of a g2o file (SE(2), SE(3) or Sim(3)).
    Pgo(pgo::PgoArgs),
    /// Bundle adjustment of a BAL problem or a synthetic scene.
    Ba(ba::BaArgs),
    /// Look at what the visual front-end sees (corners, disparity, flow, tracks, matches).
    #[command(subcommand)]
    Inspect(inspect::InspectCommand),
    /// Render an image sequence with exact ground truth (TUM, EuRoC or KITTI layout).
    Render(render::RenderArgs),
    /// The demo: double window optimisation on the simulated monocular double loop (thesis
    /// Figures 6.11–6.12) with cDWO and gDWO; plots and summary.json written to dwslam-demo/.
    Demo,
}

fn main() -> Result<()> {
    let cli = Cli::parse();
    match cli.command {
        Command::Experiment(cmd) => experiment::run(cmd),
        Command::Pgo(args) => pgo::run(args),
        Command::Ba(args) => ba::run(args),
        Command::Inspect(cmd) => inspect::run(cmd),
        Command::Render(args) => render::run(args),
        Command::Demo => experiment::dwo::run(experiment::dwo::DwoArgs::demo()),
    }
}

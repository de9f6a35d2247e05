//! `dwslam`: the command-line front of the dwslam visual SLAM system.

use anyhow::Result;
use clap::{Parser, Subcommand};

mod experiment;
mod inspect;

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
    /// Look at what the visual front-end sees (corners, disparity, flow, tracks, matches).
    #[command(subcommand)]
    Inspect(inspect::InspectCommand),
}

fn main() -> Result<()> {
    let cli = Cli::parse();
    match cli.command {
        Command::Experiment(cmd) => experiment::run(cmd),
        Command::Inspect(cmd) => inspect::run(cmd),
    }
}

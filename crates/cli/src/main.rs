//! `dwslam`: the command-line front of the dwslam visual SLAM system.

use anyhow::Result;
use clap::{Parser, Subcommand};

mod experiment;

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
}

fn main() -> Result<()> {
    let cli = Cli::parse();
    match cli.command {
        Command::Experiment(cmd) => experiment::run(cmd),
    }
}

//! `dwslam experiment …`: reproductions of the thesis's experiments.

use anyhow::Result;
use clap::Subcommand;

/// The experiments of the thesis.
#[derive(Subcommand, Debug)]
pub enum ExperimentCommand {}

/// Runs one experiment.
pub fn run(cmd: ExperimentCommand) -> Result<()> {
    match cmd {}
}

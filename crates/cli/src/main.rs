//! `dwslam`: the command-line front of the dwslam visual SLAM system.

use anyhow::Result;
use clap::{Parser, Subcommand};
use std::process::ExitCode;

mod args;
mod ba;
mod demo;
mod eval;
mod experiment;
mod inspect;
mod map;
mod pgo;
mod plot;
mod render;
mod run;
mod run_report;
mod view;
mod vocabulary;

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
    /// Trajectory errors (ATE, RPE) of an estimate against ground truth, as evo computes them.
    Eval(eval::EvalArgs),
    /// Pose-graph optimisation of a g2o file (SE(2), SE(3) or Sim(3)).
    Pgo(pgo::PgoArgs),
    /// Bundle adjustment of a BAL problem or a synthetic scene.
    Ba(ba::BaArgs),
    /// Look at what the visual front-end sees (corners, disparity, flow, tracks, matches).
    #[command(subcommand)]
    Inspect(inspect::InspectCommand),
    /// The live SLAM system on a recorded stereo or RGB-D sequence: every frame's pose, the
    /// keyframes and the map, with a report (and ATE/RPE when the sequence has ground truth).
    Run(run::RunArgs),
    /// Saved maps: what a map file holds.
    #[command(subcommand)]
    Map(map::MapCommand),
    /// Train the bag-of-words vocabulary of place recognition (DBoW2 YAML).
    Vocabulary(vocabulary::VocabularyArgs),
    /// Render an image sequence with exact ground truth (TUM, EuRoC or KITTI layout).
    Render(render::RenderArgs),
    /// The demo: the live system on a furnished room rendered on the fly (RGB-D by default),
    /// with ATE against the exact ground truth; outputs and report in dwslam-demo/. (The
    /// double-loop study of double window optimisation is `dwslam experiment dwo`.)
    Demo(demo::DemoArgs),
}

fn main() -> ExitCode {
    let cli = Cli::parse();
    match run(cli.command) {
        Ok(()) => ExitCode::SUCCESS,
        Err(e) => {
            // One line, each cause once; no backtrace for a user's mistake.
            eprintln!("error: {}", args::describe(&e));
            ExitCode::FAILURE
        }
    }
}

fn run(command: Command) -> Result<()> {
    match command {
        Command::Experiment(cmd) => experiment::run(cmd),
        Command::Eval(args) => eval::run(args),
        Command::Pgo(args) => pgo::run(args),
        Command::Ba(args) => ba::run(args),
        Command::Inspect(cmd) => inspect::run(cmd),
        Command::Run(args) => run::run(args),
        Command::Map(cmd) => map::run(cmd),
        Command::Vocabulary(args) => vocabulary::run(args),
        Command::Render(args) => render::run(args),
        Command::Demo(args) => demo::run(args),
    }
}

//! `dwslam map`: what a saved map holds.

use anyhow::Result;
use clap::{Args, Subcommand};
use runner::map_line;
use std::path::PathBuf;
use system::map_file::{FORMAT_VERSION, MapFile};

/// Subcommands of `dwslam map`.
#[derive(Subcommand, Debug)]
pub enum MapCommand {
    /// What a map file (`dwslam run --save-map`) holds: its camera, vocabulary, sequences,
    /// keyframes, points, edges and features.
    Info(InfoArgs),
}

/// Options of `dwslam map info`.
#[derive(Args, Debug)]
pub struct InfoArgs {
    /// The map file.
    pub file: PathBuf,
    /// Print JSON instead of text.
    #[arg(long)]
    pub json: bool,
}

/// Runs a `dwslam map` subcommand.
pub fn run(command: MapCommand) -> Result<()> {
    match command {
        MapCommand::Info(args) => info(&args),
    }
}

fn info(args: &InfoArgs) -> Result<()> {
    crate::args::input_file(&args.file, "FILE")?;
    let bytes = std::fs::metadata(&args.file)?.len();
    let map = MapFile::read(&args.file)?;
    let summary = map.summary();
    if args.json {
        let value = serde_json::json!({
            "file": args.file, "bytes": bytes, "format_version": FORMAT_VERSION,
            "about": map.about, "holds": summary,
        });
        println!("{}", serde_json::to_string_pretty(&value)?);
        return Ok(());
    }
    let about = &map.about;
    println!(
        "{} ({:.2} MB, format version {FORMAT_VERSION})",
        args.file.display(),
        bytes as f64 / 1e6
    );
    println!("  written by   dwslam {}", about.dwslam);
    println!("  camera       {}", about.camera);
    println!(
        "  vocabulary   {}",
        about
            .vocabulary
            .map_or("none (made with loops.enabled: false)".into(), |v| v
                .to_string())
    );
    for (i, s) in about.sequences.iter().enumerate() {
        println!("  session {}    {s}", i + 1);
    }
    println!("  holds        {}", map_line(&summary));
    println!(
        "               {} observations, {} image pixels kept",
        summary.observations, summary.pixels
    );
    if let Some(b) = summary.bytes {
        let mb = |n: usize| n as f64 / 1e6;
        println!(
            "  bytes        graph {:.2} MB, features {:.2} MB, images {:.2} MB ({:.2}× the features in all)",
            mb(b.graph),
            mb(b.features),
            mb(b.images),
            b.total as f64 / b.features.max(1) as f64
        );
    }
    if !about.config.trim().is_empty() {
        println!("  configuration overrides:");
        for line in about.config.lines() {
            println!("    {line}");
        }
    }
    Ok(())
}

//! `dwslam eval`: absolute trajectory error and relative pose error of an estimate against
//! ground truth, computed as evo computes them (`data::eval`, checked against evo by
//! `bench/eval/compare_evo.sh`), with plots a person reads at a glance.

use crate::plot::{self, Figure, GREY, PALETTE, Series, Style};
use anyhow::{Context, Result, anyhow, bail};
use clap::{Args, ValueEnum};
use data::eval::{Alignment, Statistics, apply_similarity, ate, rpe, rpe_matrices};
use data::output::{GROUND_TRUTH_FILE, TRAJECTORY_FILE, find_run_files};
use data::sequence::{OpenOptions, Sequence};
use data::trajectory::{
    Trajectory, TrajectoryFormat, associate, read_kitti_matrices, read_trajectory,
};
use lie::Se3;
use nalgebra::Vector3;
use std::fmt::Display;
use std::path::{Path, PathBuf};

/// How the estimate is aligned to the ground truth.
#[derive(Clone, Copy, Debug, PartialEq, Eq, ValueEnum)]
pub enum AlignArg {
    /// Rigid motion (evo `--align`).
    Se3,
    /// Similarity, for monocular estimates without scale (evo `--align --correct_scale`).
    Sim3,
    /// None (evo's default).
    None,
}

impl From<AlignArg> for Alignment {
    fn from(a: AlignArg) -> Self {
        match a {
            AlignArg::Se3 => Alignment::Se3,
            AlignArg::Sim3 => Alignment::Sim3,
            AlignArg::None => Alignment::None,
        }
    }
}

/// Options of `dwslam eval`.
#[derive(Args, Debug)]
pub struct EvalArgs {
    /// Ground truth: a trajectory file (TUM, KITTI or EuRoC CSV, told apart by their lines), a
    /// dataset folder (TUM RGB-D, EuRoC, KITTI: its ground truth in the camera frame the run
    /// used), or a run folder (its ground_truth.tum). Given alone, a run folder with both.
    pub ground_truth: PathBuf,
    /// The estimate: a trajectory file or a run folder (its trajectory.tum).
    pub estimate: Option<PathBuf>,
    /// Alignment of the estimate before the errors. The default is SE(3): a run's world frame
    /// is its first camera, the ground truth's is the motion-capture frame, so errors without
    /// alignment measure the frames' offset, not the estimate.
    #[arg(long, value_enum, default_value_t = AlignArg::Se3)]
    pub align: AlignArg,
    /// RPE over pose pairs this many (associated) frames apart.
    #[arg(long, default_value_t = 1)]
    pub rpe_delta: usize,
    /// RPE over every pair (i, i + delta) rather than consecutive multiples of delta.
    #[arg(long)]
    pub rpe_all_pairs: bool,
    /// Largest timestamp difference (s) for two poses to associate (evo's default 0.01).
    #[arg(long, default_value_t = 0.01)]
    pub max_time_difference: f64,
    /// Write plots here (top and side views after alignment, errors over time).
    #[arg(long)]
    pub plot: Option<PathBuf>,
    /// Write the statistics as JSON here.
    #[arg(long)]
    pub json: Option<PathBuf>,
}

/// An error whose message already says everything, without the cause chain repeating it.
fn flat(e: impl Display) -> anyhow::Error {
    anyhow!("{e}")
}

/// A writable output folder: created if absent, probed with a file.
fn check_dir_writable(dir: &Path, what: &str) -> Result<()> {
    if dir.exists() && !dir.is_dir() {
        bail!("{what} {} is a file, not a folder", dir.display());
    }
    std::fs::create_dir_all(dir)
        .map_err(|e| anyhow!("{what} {}: cannot create the folder: {e}", dir.display()))?;
    let probe = dir.join(".dwslam-write-probe");
    std::fs::write(&probe, b"")
        .map_err(|e| anyhow!("{what} {} is not writable: {e}", dir.display()))?;
    let _ = std::fs::remove_file(probe);
    Ok(())
}

/// A writable output file: its folder exists and takes a file, and it is not a folder.
pub fn check_file_writable(file: &Path, what: &str) -> Result<()> {
    if file.is_dir() {
        bail!("{what} {} is a folder, not a file", file.display());
    }
    let parent = match file.parent() {
        Some(p) if !p.as_os_str().is_empty() => p,
        _ => Path::new("."),
    };
    if !parent.is_dir() {
        bail!(
            "{what} {}: the folder {} does not exist",
            file.display(),
            parent.display()
        );
    }
    let probe = parent.join(".dwslam-write-probe");
    std::fs::write(&probe, b"")
        .map_err(|e| anyhow!("{what} {}: the folder is not writable: {e}", file.display()))?;
    let _ = std::fs::remove_file(probe);
    Ok(())
}

/// Where a trajectory comes from.
struct Source {
    path: PathBuf,
    trajectory: Trajectory,
    /// KITTI files carry no timestamps (index = time).
    indexed: bool,
    what: String,
}

#[derive(Clone, Copy, PartialEq)]
enum Role {
    GroundTruth,
    Estimate,
}

fn load(path: &Path, role: Role) -> Result<Source> {
    let name = match role {
        Role::GroundTruth => "ground truth",
        Role::Estimate => "estimate",
    };
    let file = |p: &Path, what: String| -> Result<Source> {
        let (trajectory, format) = read_trajectory(p)
            .map_err(flat)
            .with_context(|| format!("reading the {name}"))?;
        Ok(Source {
            path: p.to_path_buf(),
            trajectory,
            indexed: format == TrajectoryFormat::Kitti,
            what,
        })
    };
    if path.is_file() {
        return file(path, "trajectory file".into());
    }
    if let Some(run) = find_run_files(path) {
        let (found, wanted) = match role {
            Role::GroundTruth => (run.ground_truth, GROUND_TRUTH_FILE),
            Role::Estimate => (run.trajectory, TRAJECTORY_FILE),
        };
        let p = found.ok_or_else(|| {
            anyhow!(
                "the run folder {} has no {wanted}{}",
                path.display(),
                if role == Role::GroundTruth {
                    " (its sequence had no ground truth): give the ground truth first"
                } else {
                    ""
                }
            )
        })?;
        return file(&p, format!("run folder {}", path.display()));
    }
    if role == Role::Estimate {
        bail!(
            "the estimate {} is a folder without {TRAJECTORY_FILE}: expected a trajectory file or a run folder",
            path.display()
        );
    }
    let seq = Sequence::open(path, &OpenOptions::default())
        .map_err(flat)
        .with_context(|| {
            format!(
                "{} is neither a trajectory file nor a run folder; as a dataset folder",
                path.display()
            )
        })?;
    let gt = seq
        .info()
        .ground_truth
        .clone()
        .ok_or_else(|| anyhow!("the dataset {} has no ground truth", path.display()))?;
    Ok(Source {
        path: gt.source.clone(),
        trajectory: gt.trajectory,
        indexed: false,
        what: format!("{:?} dataset {}", seq.info().format, path.display()),
    })
}

fn stats_json(s: &Statistics) -> serde_json::Value {
    serde_json::json!({
        "rmse": s.rmse, "mean": s.mean, "median": s.median, "std": s.std,
        "min": s.min, "max": s.max, "sse": s.sse, "count": s.count,
    })
}

fn row(name: &str, s: &Statistics, scale: f64) -> String {
    format!(
        "{name:<10} {:>10.6} {:>10.6} {:>10.6} {:>10.6} {:>10.6} {:>10.6}",
        s.rmse * scale,
        s.mean * scale,
        s.median * scale,
        s.std * scale,
        s.min * scale,
        s.max * scale
    )
}

/// Runs `dwslam eval`.
pub fn run(args: EvalArgs) -> Result<()> {
    // Validate everything before any work.
    let (gt_arg, est_arg) = match &args.estimate {
        Some(e) => (args.ground_truth.clone(), e.clone()),
        None => {
            if !args.ground_truth.is_dir() || find_run_files(&args.ground_truth).is_none() {
                bail!(
                    "with one argument, {} must be a run folder (with {GROUND_TRUTH_FILE} and {TRAJECTORY_FILE}); otherwise give GROUND_TRUTH ESTIMATE",
                    args.ground_truth.display()
                );
            }
            (args.ground_truth.clone(), args.ground_truth.clone())
        }
    };
    for (p, what) in [(&gt_arg, "ground truth"), (&est_arg, "estimate")] {
        if !p.exists() {
            bail!("the {what} {} does not exist", p.display());
        }
    }
    if args.rpe_delta == 0 {
        bail!("--rpe-delta must be at least 1");
    }
    if !(args.max_time_difference >= 0.0 && args.max_time_difference.is_finite()) {
        bail!("--max-time-difference must be a non-negative number of seconds");
    }
    if let Some(dir) = &args.plot {
        check_dir_writable(dir, "--plot")?;
    }
    if let Some(file) = &args.json {
        check_file_writable(file, "--json")?;
    }

    let reference = load(&gt_arg, Role::GroundTruth)?;
    let estimate = load(&est_arg, Role::Estimate)?;
    if reference.indexed != estimate.indexed {
        bail!(
            "{} has no timestamps (KITTI poses) but {} has: give both as KITTI files (paired by \
             index) or both with timestamps (for KITTI, the dataset folder has times.txt)",
            if reference.indexed {
                &reference.path
            } else {
                &estimate.path
            }
            .display(),
            if reference.indexed {
                &estimate.path
            } else {
                &reference.path
            }
            .display()
        );
    }
    let pairs = associate(
        &reference.trajectory.timestamps,
        &estimate.trajectory.timestamps,
        args.max_time_difference,
        0.0,
    );
    if pairs.len() < 3 {
        bail!(
            "only {} poses of {} and {} are within {} s of each other: the trajectories do not overlap in time",
            pairs.len(),
            reference.path.display(),
            estimate.path.display(),
            args.max_time_difference
        );
    }
    let r: Vec<Se3> = pairs
        .iter()
        .map(|&(i, _)| reference.trajectory.world_from_body[i])
        .collect();
    let e: Vec<Se3> = pairs
        .iter()
        .map(|&(_, j)| estimate.trajectory.world_from_body[j])
        .collect();
    let times: Vec<f64> = pairs
        .iter()
        .map(|&(i, _)| reference.trajectory.timestamps[i])
        .collect();
    let alignment: Alignment = args.align.into();
    let ate = ate(&r, &e, alignment).map_err(flat).context("ATE")?;
    let rpe = if reference.indexed {
        // KITTI files: evo computes RPE on the stored (7-digit, not exactly orthonormal)
        // matrices; so do we, to report the same numbers.
        let mr = read_kitti_matrices(&reference.path).map_err(flat)?;
        let me = read_kitti_matrices(&estimate.path).map_err(flat)?;
        let mr: Vec<_> = pairs.iter().map(|&(i, _)| mr[i]).collect();
        let me: Vec<_> = pairs.iter().map(|&(_, j)| me[j]).collect();
        rpe_matrices(
            &mr,
            &me,
            &ate.reference_from_estimate,
            args.rpe_delta,
            args.rpe_all_pairs,
        )
    } else {
        rpe(&r, &e, args.rpe_delta, args.rpe_all_pairs, alignment)
    }
    .map_err(flat)
    .context("RPE")?;
    let s = &ate.reference_from_estimate;
    let deg = 180.0 / std::f64::consts::PI;

    println!(
        "ground truth  {} ({}, {} poses)",
        reference.path.display(),
        reference.what,
        reference.trajectory.len()
    );
    println!(
        "estimate      {} ({}, {} poses)",
        estimate.path.display(),
        estimate.what,
        estimate.trajectory.len()
    );
    println!(
        "associated    {} pose pairs (|Δt| ≤ {} s); alignment {:?}: scale {:.6}, rotation {:.3}°, translation {:.4} m",
        pairs.len(),
        args.max_time_difference,
        args.align,
        s.scale(),
        s.rotation().angle() * deg,
        s.translation().norm()
    );
    println!(
        "{:<10} {:>10} {:>10} {:>10} {:>10} {:>10} {:>10}",
        "", "rmse", "mean", "median", "std", "min", "max"
    );
    println!("{}", row("ATE [m]", &ate.translation, 1.0));
    println!("{}", row("RPE [m]", &rpe.translation, 1.0));
    println!("{}", row("RPE [deg]", &rpe.rotation_rad, deg));
    println!(
        "RPE over {} pairs {} frames apart{}",
        rpe.pairs.len(),
        args.rpe_delta,
        if args.rpe_all_pairs {
            " (all pairs)"
        } else {
            ""
        }
    );

    if let Some(path) = &args.json {
        let q = s.rotation().unit_quaternion();
        let t = s.translation();
        let rot_deg = rpe.rotation_rad;
        let scaled = Statistics {
            rmse: rot_deg.rmse * deg,
            mean: rot_deg.mean * deg,
            median: rot_deg.median * deg,
            std: rot_deg.std * deg,
            min: rot_deg.min * deg,
            max: rot_deg.max * deg,
            sse: rot_deg.sse * deg * deg,
            count: rot_deg.count,
        };
        let json = serde_json::json!({
            "ground_truth": reference.path, "estimate": estimate.path,
            "pairs": pairs.len(), "max_time_difference": args.max_time_difference,
            "alignment": {
                "mode": format!("{:?}", args.align).to_lowercase(),
                "scale": s.scale(),
                "rotation_xyzw": [q.i, q.j, q.k, q.w],
                "translation": [t.x, t.y, t.z],
            },
            "ate": stats_json(&ate.translation),
            "rpe": {
                "delta": args.rpe_delta, "all_pairs": args.rpe_all_pairs,
                "translation": stats_json(&rpe.translation),
                "rotation_rad": stats_json(&rpe.rotation_rad),
                "rotation_deg": stats_json(&scaled),
            },
        });
        std::fs::write(path, serde_json::to_string_pretty(&json)? + "\n")
            .map_err(|e| anyhow!("--json {}: {e}", path.display()))?;
    }

    if let Some(dir) = &args.plot {
        let aligned: Vec<Vector3<f64>> = e
            .iter()
            .map(|p| *apply_similarity(s, p).translation())
            .collect();
        let truth: Vec<Vector3<f64>> = r.iter().map(|p| *p.translation()).collect();
        let t0 = times[0];
        let time_label = if reference.indexed {
            "frame"
        } else {
            "time [s]"
        };
        plots(
            dir,
            &truth,
            &aligned,
            &times.iter().map(|t| t - t0).collect::<Vec<_>>(),
            time_label,
            &ate.errors,
            &rpe,
            args.align,
        )?;
        println!("plots in {}", dir.display());
    }
    Ok(())
}

/// The coordinate axes ordered by the spread of the ground-truth positions (largest first): the
/// top view shows the two largest, the side view the largest and the smallest — for ground
/// vehicles and hand-held cameras the smallest spread is the vertical, whichever axis a dataset
/// calls up.
fn axes_by_spread(points: &[Vector3<f64>]) -> [usize; 3] {
    let n = points.len() as f64;
    let mean = points.iter().sum::<Vector3<f64>>() / n;
    let var: Vector3<f64> = points
        .iter()
        .map(|p| (p - mean).component_mul(&(p - mean)))
        .sum::<Vector3<f64>>()
        / n;
    let mut axes = [0, 1, 2];
    axes.sort_by(|&a, &b| var[b].total_cmp(&var[a]));
    axes
}

#[allow(clippy::too_many_arguments)]
fn plots(
    dir: &Path,
    truth: &[Vector3<f64>],
    aligned: &[Vector3<f64>],
    times: &[f64],
    time_label: &str,
    ate_errors: &[f64],
    rpe: &data::eval::RpeResult,
    align: AlignArg,
) -> Result<()> {
    const NAMES: [&str; 3] = ["x [m]", "y [m]", "z [m]"];
    let axes = axes_by_spread(truth);
    let view = |a: usize, b: usize| -> Vec<Series> {
        vec![
            Series {
                label: "ground truth".into(),
                points: truth.iter().map(|p| (p[a], p[b])).collect(),
                color: GREY,
                style: Style::Line,
            },
            Series {
                label: format!("estimate ({align:?} aligned)")
                    .to_lowercase()
                    .replace("none aligned", "not aligned"),
                points: aligned.iter().map(|p| (p[a], p[b])).collect(),
                color: PALETTE[0],
                style: Style::Line,
            },
            Series {
                label: "start".into(),
                points: vec![(truth[0][a], truth[0][b])],
                color: PALETTE[2],
                style: Style::Points,
            },
        ]
    };
    let files = [
        (
            "trajectory_top.png",
            "Trajectories, top view",
            axes[0],
            axes[1],
        ),
        (
            "trajectory_side.png",
            "Trajectories, side view",
            axes[0],
            axes[2],
        ),
    ];
    for (name, title, a, b) in files {
        plot::plot(
            &dir.join(name),
            &Figure {
                title,
                x_label: NAMES[a],
                y_label: NAMES[b],
                equal_aspect: true,
                log_y: false,
            },
            &view(a, b),
        )?;
    }
    plot::plot(
        &dir.join("ate_over_time.png"),
        &Figure {
            title: "Absolute trajectory error",
            x_label: time_label,
            y_label: "ATE [m]",
            equal_aspect: false,
            log_y: false,
        },
        &[Series {
            label: String::new(),
            points: times
                .iter()
                .copied()
                .zip(ate_errors.iter().copied())
                .collect(),
            color: PALETTE[1],
            style: Style::Line,
        }],
    )?;
    let t_rpe: Vec<(f64, f64)> = rpe
        .pairs
        .iter()
        .zip(&rpe.translation_errors)
        .map(|(&(_, j), &e)| (times[j], e))
        .collect();
    plot::plot(
        &dir.join("rpe_over_time.png"),
        &Figure {
            title: "Relative pose error (translation)",
            x_label: time_label,
            y_label: "RPE [m]",
            equal_aspect: false,
            log_y: false,
        },
        &[Series {
            label: String::new(),
            points: t_rpe,
            color: PALETTE[3],
            style: Style::Line,
        }],
    )?;
    Ok(())
}

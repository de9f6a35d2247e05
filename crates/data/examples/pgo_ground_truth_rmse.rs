//! Translation RMSE of an optimised pose graph against iSAM's noise-free ground truth, after
//! the rigid (SE(3)) alignment of the positions (thesis eq. 5.11–5.14 with `s = 1`; 2D poses in
//! the plane `z = 0`). Vertex `i` of the g2o file is compared with ground-truth pose `i`.
//!
//! `cargo run --release -p data --example pgo_ground_truth_rmse -- GT.txt RESULT.g2o`
//!
//! Prints `{"translation_rmse": …, "count": …}`.

use data::eval::{Alignment, ate};
use data::g2o::{G2oGraph, read_g2o};
use data::isam::{read_isam_groundtruth, se2_to_se3};
use lie::Se3;

fn run(gt: &str, result: &str) -> Result<(f64, usize), String> {
    let truth = read_isam_groundtruth(gt).map_err(|e| e.to_string())?;
    let truth = truth.world_from_body_3d();
    let file = read_g2o(result).map_err(|e| e.to_string())?;
    let estimate: Vec<(u64, Se3)> = match &file.graph {
        G2oGraph::Se2(g) => g
            .vertices()
            .iter()
            .map(|v| (v.id, se2_to_se3(&v.world_from_body)))
            .collect(),
        G2oGraph::Se3(g) => g
            .vertices()
            .iter()
            .map(|v| (v.id, v.world_from_body))
            .collect(),
    };
    let mut reference = Vec::new();
    let mut estimated = Vec::new();
    for (id, pose) in estimate {
        let Some(t) = truth.get(id as usize) else {
            return Err(format!(
                "{result}: vertex {id} has no ground-truth pose in {gt}"
            ));
        };
        reference.push(*t);
        estimated.push(pose);
    }
    let result = ate(&reference, &estimated, Alignment::Se3).map_err(|e| e.to_string())?;
    Ok((result.translation.rmse, result.translation.count))
}

fn main() {
    let args: Vec<String> = std::env::args().collect();
    if args.len() != 3 {
        eprintln!("usage: pgo_ground_truth_rmse GT.txt RESULT.g2o");
        std::process::exit(2);
    }
    match run(&args[1], &args[2]) {
        Ok((rmse, count)) => println!("{{\"translation_rmse\": {rmse:e}, \"count\": {count}}}"),
        Err(e) => {
            eprintln!("error: {e}");
            std::process::exit(1);
        }
    }
}

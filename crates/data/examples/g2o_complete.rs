//! Reads a g2o file with dwslam's reader and writes it back complete: every vertex with its
//! initial pose (chained along a spanning tree for edges-only files), every edge, FIX lines.
//! Prints a JSON line with the counts and dwslam's initial cost ½χ² (thesis eq. 5.16).
//!
//! `cargo run --release -p data --example g2o_complete -- IN.g2o OUT.g2o`
//!
//! The peer drivers in `bench/pgo` read OUT.g2o so that GTSAM, g2o and dwslam start from the
//! same initial poses.

use data::g2o::{read_g2o, write_g2o_graph};

fn main() {
    let args: Vec<String> = std::env::args().collect();
    if args.len() != 3 {
        eprintln!("usage: g2o_complete IN.g2o OUT.g2o");
        std::process::exit(2);
    }
    let file = match read_g2o(&args[1]) {
        Ok(f) => f,
        Err(e) => {
            eprintln!("error: {e}");
            std::process::exit(1);
        }
    };
    for tag in &file.report.unknown_tags {
        eprintln!(
            "warning: {}: {} lines with unknown tag {} (first on line {})",
            args[1], tag.count, tag.tag, tag.lines[0]
        );
    }
    if let Err(e) = write_g2o_graph(&file.graph, &args[2]) {
        eprintln!("error: {e}");
        std::process::exit(1);
    }
    let chained = file.report.initialisation.map_or("null".to_string(), |i| {
        format!(
            "{{\"root\": {}, \"tree_edges\": {}, \"odometry_tree_edges\": {}, \"components\": {}}}",
            i.root, i.tree_edges, i.odometry_tree_edges, i.components
        )
    });
    println!(
        "{{\"dimension\": {}, \"vertices\": {}, \"edges\": {}, \"initial_cost\": {:e}, \"chained_initialisation\": {}}}",
        file.graph.dimension(),
        file.graph.vertex_count(),
        file.graph.edge_count(),
        file.graph.cost(),
        chained
    );
}

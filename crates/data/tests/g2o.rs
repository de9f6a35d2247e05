//! g2o reader/writer: real datasets, round trip, every malformed case, fuzzing.

use data::g2o::{G2oGraph, parse_g2o, read_g2o, write_g2o};
use data::paths::require;
use data::{DataError, ParseErrorKind, PoseGraph};
use lie::{LieGroup, Se2, Se3};
use proptest::prelude::*;
use std::path::Path;

/// (file, dimension, vertices, edges, edges only) as listed in the dataset's PROVENANCE.md.
const DATASETS: [(&str, usize, usize, usize, bool); 12] = [
    ("sphere2500.g2o", 3, 2500, 4949, false),
    ("parking-garage.g2o", 3, 1661, 6275, false),
    ("torus3D.g2o", 3, 5000, 9048, false),
    ("smallGrid3D.g2o", 3, 125, 297, false),
    ("tinyGrid3D.g2o", 3, 9, 11, false),
    ("intel.g2o", 2, 1728, 2512, false),
    ("city10000.g2o", 2, 10000, 20687, false),
    ("M3500.g2o", 2, 3500, 5453, false),
    ("manhattan.g2o", 2, 3500, 5453, true),
    ("CSAIL.g2o", 2, 1045, 1172, true),
    ("MIT.g2o", 2, 808, 827, false),
    ("kitti_00.g2o", 2, 4541, 4677, true),
];

#[test]
fn reads_every_real_dataset() {
    for (name, dim, vertices, edges, edges_only) in DATASETS {
        let Some(path) = require(Path::new("pose_graph_g2o").join(name)) else {
            return;
        };
        let file = read_g2o(&path).unwrap_or_else(|e| panic!("{e}"));
        assert_eq!(file.graph.dimension(), dim, "{name}");
        assert_eq!(file.graph.edge_count(), edges, "{name}");
        assert_eq!(file.graph.vertex_count(), vertices, "{name}");
        assert!(
            file.report.unknown_tags.is_empty(),
            "{name}: {:?}",
            file.report
        );
        assert!(
            file.graph.cost().is_finite() && file.graph.cost() > 0.0,
            "{name}"
        );
        match (edges_only, file.report.initialisation) {
            (false, None) => {}
            (true, Some(init)) => {
                assert_eq!(init.root, 0, "{name}");
                assert_eq!(init.components, 1, "{name}");
                assert_eq!(init.tree_edges, vertices - 1, "{name}");
                // The ids form an odometry chain 0..n-1, so the tree is the odometry.
                assert_eq!(init.odometry_tree_edges, vertices - 1, "{name}");
            }
            (_, init) => panic!("{name}: unexpected initialisation {init:?}"),
        }
    }
}

/// GTSAM 4.3.0's `graph.error(initial)` (½χ²) on every dataset, recorded by `bench/pgo/run.sh`
/// (`gtsam_pgo.py out/pgo/NAME.init.g2o`, the file completed by the `g2o_complete` example: for
/// files with vertices the same poses as the original). Our cost must be GTSAM's: this pins the
/// information-matrix convention (file order = (v, ω), no quaternion rescaling) and the
/// residual `Log(Z⁻¹·X_from⁻¹·X_to)`.
const GTSAM_INITIAL_COST: [(&str, f64); 12] = [
    ("sphere2500.g2o", 1305657.7118060864),
    ("parking-garage.g2o", 8363.601948120007),
    ("torus3D.g2o", 2400615.1744463556),
    ("smallGrid3D.g2o", 83894.33343553313),
    ("tinyGrid3D.g2o", 143.31787355350403),
    ("intel.g2o", 276.99789778210055),
    ("city10000.g2o", 359231215.6007709),
    ("M3500.g2o", 1317356.2725119137),
    ("manhattan.g2o", 13515460719.76823),
    ("CSAIL.g2o", 1072150.1250268817),
    ("MIT.g2o", 3548660355.520316),
    ("kitti_00.g2o", 37308573.875416785),
];

#[test]
fn initial_cost_equals_gtsams_graph_error() {
    for (name, gtsam) in GTSAM_INITIAL_COST {
        let Some(path) = require(Path::new("pose_graph_g2o").join(name)) else {
            return;
        };
        let ours = read_g2o(&path).unwrap().graph.cost();
        let rel = (ours - gtsam).abs() / gtsam;
        assert!(
            rel < 1e-12,
            "{name}: ours {ours} vs GTSAM {gtsam} (relative {rel:e})"
        );
    }
}

#[test]
fn chained_manhattan_equals_m3500_vertices() {
    // manhattan.g2o has the same measurements as M3500.g2o without vertices; M3500's vertices
    // are its odometry chained, so our spanning-tree initialisation must reproduce them (up to
    // the 6 printed decimals accumulated over 3500 steps).
    let (Some(m), Some(manhattan)) = (
        require("pose_graph_g2o/M3500.g2o"),
        require("pose_graph_g2o/manhattan.g2o"),
    ) else {
        return;
    };
    let (m, _) = data::g2o::read_g2o_se2(m).unwrap();
    let (chained, report) = data::g2o::read_g2o_se2(manhattan).unwrap();
    assert!(report.initialisation.is_some());
    let mut worst: f64 = 0.0;
    for v in m.vertices() {
        let c = chained.pose(v.id).unwrap();
        let d = v.world_from_body.inverse().compose(c).log();
        worst = worst.max(d.norm());
    }
    assert!(worst < 1e-2, "max deviation {worst}");
}

fn assert_graphs_close<G: LieGroup<DOF>, const DOF: usize>(
    a: &PoseGraph<G, DOF>,
    b: &PoseGraph<G, DOF>,
) {
    assert_eq!(a.vertices().len(), b.vertices().len());
    assert_eq!(a.edges().len(), b.edges().len());
    assert_eq!(a.fixed(), b.fixed());
    for (x, y) in a.vertices().iter().zip(b.vertices()) {
        assert_eq!(x.id, y.id);
        let d = x
            .world_from_body
            .inverse()
            .compose(&y.world_from_body)
            .log();
        assert!(d.norm() < 1e-14, "vertex {}: {d}", x.id);
    }
    for (x, y) in a.edges().iter().zip(b.edges()) {
        assert_eq!((x.from, x.to), (y.from, y.to));
        assert_eq!(x.information, y.information);
        let d = x.measurement.inverse().compose(&y.measurement).log();
        assert!(d.norm() < 1e-14, "edge {}->{}: {d}", x.from, x.to);
    }
    let (ca, cb) = (a.cost(), b.cost());
    assert!((ca - cb).abs() <= 1e-12 * ca.abs().max(1.0), "{ca} vs {cb}");
}

fn round_trip(text: &str) {
    let first = parse_g2o(text, Path::new("first")).unwrap();
    let mut written = Vec::new();
    match &first.graph {
        G2oGraph::Se2(g) => write_g2o(g, &mut written).unwrap(),
        G2oGraph::Se3(g) => write_g2o(g, &mut written).unwrap(),
    }
    let written = String::from_utf8(written).unwrap();
    let second = parse_g2o(&written, Path::new("second")).unwrap();
    assert!(
        second.report.initialisation.is_none(),
        "vertices were written"
    );
    match (&first.graph, &second.graph) {
        (G2oGraph::Se2(a), G2oGraph::Se2(b)) => assert_graphs_close(a, b),
        (G2oGraph::Se3(a), G2oGraph::Se3(b)) => assert_graphs_close(a, b),
        _ => panic!("dimension changed"),
    }
    // Writing what was read back and reading it again changes nothing beyond rounding.
    let mut again = Vec::new();
    match &second.graph {
        G2oGraph::Se2(g) => write_g2o(g, &mut again).unwrap(),
        G2oGraph::Se3(g) => write_g2o(g, &mut again).unwrap(),
    }
    let third = parse_g2o(std::str::from_utf8(&again).unwrap(), Path::new("third")).unwrap();
    match (&second.graph, &third.graph) {
        (G2oGraph::Se2(a), G2oGraph::Se2(b)) => assert_graphs_close(a, b),
        (G2oGraph::Se3(a), G2oGraph::Se3(b)) => assert_graphs_close(a, b),
        _ => panic!("dimension changed"),
    }
}

const SMALL_3D: &str = "\
# a comment
VERTEX_SE3:QUAT 0 0 0 0 0 0 0 1
VERTEX_SE3:QUAT 1 1 0.1 -0.2 0.1 0.2 -0.1 0.9
VERTEX_SE3:QUAT 2 2 0.3 -0.1 0 0 0.3 0.95
EDGE_SE3:QUAT 0 1 1 0 0 0 0 0 1 10 1 0 0 0 0 10 0 0 0 0 10 0 0 0 40 2 0 40 0 40
EDGE_SE3:QUAT 1 2 1 0.2 0 0 0 0.2 0.98 10 0 0 0 0 0 10 0 0 0 0 10 0 0 0 40 0 0 40 0 40
EDGE_SE3:QUAT 0 2 2 0.1 0 0 0 0.1 1 5 0 0 0 0 0 5 0 0 0 0 5 0 0 0 20 0 0 20 0 20
FIX 0
";

const SMALL_2D: &str = "\
VERTEX_SE2 0 0 0 0
VERTEX_SE2 1 1.0 0.1 0.3
VERTEX_SE2 2 2.0 -0.1 3.1
EDGE_SE2 0 1 1 0 0.25 50 1 0 50 0 100
EDGE_SE2 1 2 1 0 2.9 50 0 0 50 0 100
EDGE_SE2 2 0 -2 0 -3.1 10 0 0 10 0 20
FIX 0 2
";

#[test]
fn round_trip_small_files() {
    round_trip(SMALL_3D);
    round_trip(SMALL_2D);
}

#[test]
fn round_trip_real_datasets() {
    for name in [
        "sphere2500.g2o",
        "parking-garage.g2o",
        "intel.g2o",
        "CSAIL.g2o",
    ] {
        let Some(path) = require(Path::new("pose_graph_g2o").join(name)) else {
            return;
        };
        round_trip(&std::fs::read_to_string(path).unwrap());
    }
}

#[test]
fn small_file_contents_and_cost() {
    let file = parse_g2o(SMALL_2D, Path::new("small")).unwrap();
    let G2oGraph::Se2(g) = file.graph else {
        panic!("2D")
    };
    assert_eq!(g.fixed(), &[0, 2]);
    let e = &g.edges()[0];
    assert_eq!(e.information[(0, 1)], 1.0);
    assert_eq!(e.information[(1, 0)], 1.0);
    // Independent evaluation of ½ dᵀΛd for the first edge: Z⁻¹·X0⁻¹·X1 with X0 = id.
    let x1 = Se2::from_xy_angle(1.0, 0.1, 0.3);
    let z = Se2::from_xy_angle(1.0, 0.0, 0.25);
    let d = z.inverse().compose(&x1).log();
    assert!((e.residual(&Se2::identity(), &x1) - d).norm() < 1e-15);
    // Edge 1→2: the angles 2.9 and 3.1-0.3 = 2.8 differ by 0.1 — no wrap-around problem.
    let file = parse_g2o(SMALL_3D, Path::new("small")).unwrap();
    let G2oGraph::Se3(g) = file.graph else {
        panic!("3D")
    };
    let e = &g.edges()[0];
    // File order (x y z qx qy qz) is dwslam's (v, ω) without rescaling: Λ[0][1] = 1, Λ[3][4] = 2.
    assert_eq!(e.information[(0, 1)], 1.0);
    assert_eq!(e.information[(3, 4)], 2.0);
    assert_eq!(e.information[(4, 3)], 2.0);
    let x1 = *g.pose(1).unwrap();
    let d = e.residual(&Se3::identity(), &x1);
    let by_hand = 0.5 * (d.transpose() * e.information * d)[(0, 0)];
    assert!((g.edges()[0].chi2(&Se3::identity(), &x1) * 0.5 - by_hand).abs() < 1e-15);
}

#[test]
fn unknown_tags_are_reported_with_lines_and_counts() {
    let text = format!("{SMALL_2D}VERTEX_XY 7 1 2\nPARAMS_SE2OFFSET 0 0 0 0\nVERTEX_XY 8 1 2\n");
    let file = parse_g2o(&text, Path::new("t")).unwrap();
    let tags = &file.report.unknown_tags;
    assert_eq!(tags.len(), 2);
    assert_eq!(tags[0].tag, "VERTEX_XY");
    assert_eq!(tags[0].count, 2);
    assert_eq!(tags[0].lines, vec![8, 10]);
    assert_eq!(tags[1].tag, "PARAMS_SE2OFFSET");
    assert_eq!(tags[1].lines, vec![9]);
}

#[test]
fn edges_only_chains_odometry_and_handles_components() {
    // Odometry 0→1→2, a loop closure 0→2 that disagrees, and a separate pair 5→6.
    let text = "\
EDGE_SE2 0 2 5 5 0 1 0 0 1 0 1
EDGE_SE2 0 1 1 0 1.5707963267948966 1 0 0 1 0 1
EDGE_SE2 1 2 1 0 0 1 0 0 1 0 1
EDGE_SE2 5 6 3 0 0 1 0 0 1 0 1
";
    let file = parse_g2o(text, Path::new("t")).unwrap();
    let init = file.report.initialisation.unwrap();
    assert_eq!(init.root, 0);
    assert_eq!(init.components, 2);
    assert_eq!(init.tree_edges, 3);
    let G2oGraph::Se2(g) = file.graph else {
        panic!()
    };
    let p2 = g.pose(2).unwrap();
    // Chained along the odometry: (0,0,0) → (1,0,π/2) → (1,1,π/2), not the loop closure's (5,5).
    assert!((p2.translation() - nalgebra::Vector2::new(1.0, 1.0)).norm() < 1e-12);
    assert!((g.pose(6).unwrap().translation().x - 3.0).abs() < 1e-12);
    assert_eq!(g.pose(5).unwrap(), &Se2::identity());
}

/// Parses `text` and returns the error's line and kind.
fn error_of(text: &str) -> (Option<usize>, ParseErrorKind) {
    let err: DataError = parse_g2o(text, Path::new("bad.g2o")).expect_err(text);
    let message = err.to_string();
    assert!(message.starts_with("bad.g2o"), "{message}");
    (err.line(), err.kind().unwrap().clone())
}

#[test]
fn malformed_inputs_give_errors_with_file_and_line() {
    let v0 = "VERTEX_SE2 0 0 0 0\n";
    let v1 = "VERTEX_SE2 1 1 0 0\n";
    let e = |s: &str| format!("{v0}{v1}{s}\n");
    let info = "1 0 0 1 0 1";
    type Case = (String, usize, fn(&ParseErrorKind) -> bool);
    let cases: Vec<Case> = vec![
        ("VERTEX_SE2 0 0 0\n".into(), 1, |k| {
            matches!(k, ParseErrorKind::FieldCount { found: 3, .. })
        }),
        (e(&format!("EDGE_SE2 0 1 1 0 0 {info} 7")), 3, |k| {
            matches!(k, ParseErrorKind::FieldCount { found: 12, .. })
        }),
        (e(&format!("EDGE_SE2 0 1 1 x 0 {info}")), 3, |k| {
            matches!(k, ParseErrorKind::NotANumber { .. })
        }),
        (e(&format!("EDGE_SE2 0 1 1 NaN 0 {info}")), 3, |k| {
            matches!(k, ParseErrorKind::NotFinite { .. })
        }),
        (e(&format!("EDGE_SE2 0 1 1 0 inf {info}")), 3, |k| {
            matches!(k, ParseErrorKind::NotFinite { .. })
        }),
        (e("EDGE_SE2 0 1 1 0 0 1 0 0 1 0 1e400"), 3, |k| {
            matches!(k, ParseErrorKind::NotFinite { .. })
        }),
        (e(&format!("EDGE_SE2 -1 1 1 0 0 {info}")), 3, |k| {
            matches!(k, ParseErrorKind::NotAnIndex { .. })
        }),
        (e(&format!("EDGE_SE2 0 1.5 1 0 0 {info}")), 3, |k| {
            matches!(k, ParseErrorKind::NotAnIndex { .. })
        }),
        (e(&format!("EDGE_SE2 0 7 1 0 0 {info}")), 3, |k| {
            matches!(k, ParseErrorKind::UnknownVertex { id: 7 })
        }),
        (e(&format!("EDGE_SE2 1 1 1 0 0 {info}")), 3, |k| {
            matches!(k, ParseErrorKind::SelfLoop { id: 1 })
        }),
        (format!("{v0}{v1}VERTEX_SE2 0 5 5 5\n"), 3, |k| {
            matches!(
                k,
                ParseErrorKind::DuplicateVertex {
                    id: 0,
                    first_line: 1
                }
            )
        }),
        (format!("{v0}VERTEX_SE3:QUAT 1 0 0 0 0 0 0 1\n"), 2, |k| {
            matches!(
                k,
                ParseErrorKind::MixedDimensions {
                    found: 3,
                    expected: 2,
                    ..
                }
            )
        }),
        ("VERTEX_SE3:QUAT 1 0 0 0 0 0 0 0\n".into(), 1, |k| {
            matches!(k, ParseErrorKind::InvalidRotation { .. })
        }),
        (format!("{v0}FIX 4\n"), 2, |k| {
            matches!(k, ParseErrorKind::UnknownVertex { id: 4 })
        }),
        (format!("{v0}FIX\n"), 2, |k| {
            matches!(k, ParseErrorKind::FieldCount { .. })
        }),
        (format!("{v0}FIX a\n"), 2, |k| {
            matches!(k, ParseErrorKind::NotAnIndex { .. })
        }),
    ];
    for (text, line, check) in cases {
        let (got_line, kind) = error_of(&text);
        assert_eq!(got_line, Some(line), "{text}: {kind}");
        assert!(check(&kind), "{text}: unexpected {kind:?}");
    }
    for empty in ["", "\n\n", "# only a comment\n", "FOO 1 2\n"] {
        let (line, kind) = error_of(empty);
        assert_eq!(line, None);
        assert!(matches!(kind, ParseErrorKind::Empty { .. }), "{kind:?}");
    }
    let err = read_g2o("/no/such/file.g2o").unwrap_err();
    assert!(matches!(err, DataError::Io { .. }));
    assert!(err.to_string().contains("/no/such/file.g2o"));
    let err = parse_g2o("VERTEX_SE2 0 0 0 0\n", Path::new("x")).map(|_| ());
    assert!(err.is_ok());
}

#[test]
fn non_utf8_is_an_error_naming_the_line() {
    let dir = std::env::temp_dir().join(format!("dwslam-g2o-utf8-{}", std::process::id()));
    std::fs::create_dir_all(&dir).unwrap();
    let path = dir.join("bad.g2o");
    std::fs::write(&path, b"VERTEX_SE2 0 0 0 0\nVERTEX_SE2 1 \xff 0 0\n").unwrap();
    let err = read_g2o(&path).unwrap_err();
    assert_eq!(err.line(), Some(2), "{err}");
    std::fs::remove_dir_all(&dir).unwrap();
}

fn mutate(text: &str, ops: &[(u8, usize, String)]) -> String {
    let mut lines: Vec<Vec<String>> = text
        .lines()
        .map(|l| l.split_whitespace().map(str::to_string).collect())
        .collect();
    for (op, pos, word) in ops {
        if lines.is_empty() {
            break;
        }
        let li = pos % lines.len();
        let line = &mut lines[li];
        let wi = if line.is_empty() {
            0
        } else {
            pos / 7 % line.len()
        };
        match op % 6 {
            0 if !line.is_empty() => line[wi] = word.clone(),
            1 if !line.is_empty() => {
                line.remove(wi);
            }
            2 => line.insert(wi.min(line.len()), word.clone()),
            3 => {
                let copy = line.clone();
                lines.insert(li, copy);
            }
            4 => {
                lines.remove(li);
            }
            _ => {
                let other = pos / 3 % lines.len();
                lines.swap(li, other);
            }
        }
    }
    lines
        .iter()
        .map(|l| l.join(" "))
        .collect::<Vec<_>>()
        .join("\n")
}

fn token() -> impl Strategy<Value = String> {
    prop_oneof![
        Just("0".to_string()),
        Just("-1".to_string()),
        Just("NaN".to_string()),
        Just("inf".to_string()),
        Just("1e308".to_string()),
        Just("1e400".to_string()),
        Just("18446744073709551616".to_string()),
        Just("VERTEX_SE2".to_string()),
        Just("EDGE_SE3:QUAT".to_string()),
        Just("FIX".to_string()),
        any::<f64>().prop_map(|x| x.to_string()),
        any::<u64>().prop_map(|x| x.to_string()),
        "[ -~]{0,8}",
    ]
}

proptest! {
    #![proptest_config(ProptestConfig { cases: 300, failure_persistence: None, ..ProptestConfig::default() })]

    #[test]
    fn random_bytes_never_panic(bytes in proptest::collection::vec(any::<u8>(), 0..400)) {
        let text = String::from_utf8_lossy(&bytes);
        let _ = parse_g2o(&text, Path::new("fuzz"));
    }

    #[test]
    fn random_records_never_panic(
        lines in proptest::collection::vec(
            (prop_oneof![
                Just("VERTEX_SE2"), Just("EDGE_SE2"), Just("VERTEX_SE3:QUAT"),
                Just("EDGE_SE3:QUAT"), Just("FIX"), Just("XYZ")
            ], proptest::collection::vec(token(), 0..32)),
            0..8)
    ) {
        let text: String = lines
            .iter()
            .map(|(tag, words)| format!("{tag} {}\n", words.join(" ")))
            .collect();
        let _ = parse_g2o(&text, Path::new("fuzz"));
    }

    #[test]
    fn mutated_valid_files_never_panic(
        which in any::<bool>(),
        ops in proptest::collection::vec((any::<u8>(), any::<usize>(), token()), 1..6)
    ) {
        let text = mutate(if which { SMALL_3D } else { SMALL_2D }, &ops);
        if let Ok(file) = parse_g2o(&text, Path::new("fuzz")) {
            // Whatever was accepted can be evaluated without panicking (the cost may overflow
            // to ∞ for finite but huge numbers such as 1e308, which the reader accepts).
            let _ = file.graph.cost();
        }
    }
}

/// Singular and indefinite information matrices load with a warning naming the edge and its
/// line: a singular one is used as is, an indefinite one is replaced by the nearest positive
/// semi-definite matrix; positive definite ones stay exactly as written (see `data::g2o`).
#[test]
fn non_positive_definite_information_loads_with_warnings() {
    use data::g2o::{InformationAction, definiteness, nearest_positive_semidefinite};
    let text = "VERTEX_SE2 0 0 0 0\n\
                VERTEX_SE2 1 1 0 0\n\
                VERTEX_SE2 2 2 0.1 0.1\n\
                EDGE_SE2 0 1 1 0 0 10 0 0 10 0 100\n\
                EDGE_SE2 1 2 1 0 0.1 10 0 0 10 0 0\n\
                EDGE_SE2 0 2 2 0 0.1 1 2 0 1 0 1\n";
    let f = parse_g2o(text, Path::new("constructed.g2o")).unwrap();
    let G2oGraph::Se2(g) = &f.graph else {
        panic!("SE(2)")
    };
    let w = &f.report.information;
    assert_eq!(w.len(), 2, "{w:?}");
    assert_eq!((w[0].line, w[0].from, w[0].to), (5, 1, 2));
    assert_eq!(w[0].action, InformationAction::UsedSingular { rank: 2 });
    assert_eq!(w[0].eigenvalues, vec![0.0, 10.0, 10.0]);
    assert_eq!((w[1].line, w[1].from, w[1].to), (6, 0, 2));
    assert_eq!(w[1].action, InformationAction::ProjectedToSemidefinite);
    for (got, want) in w[1].eigenvalues.iter().zip([-1.0, 1.0, 3.0]) {
        assert!((got - want).abs() < 1e-12, "{:?}", w[1].eigenvalues);
    }
    let msg = w[1].to_string();
    assert!(
        msg.contains("line 6") && msg.contains("0 -> 2") && msg.contains("indefinite"),
        "{msg}"
    );
    // Positive definite and singular matrices are kept exactly; the indefinite one becomes
    // [[1.5, 1.5, 0], [1.5, 1.5, 0], [0, 0, 1]] (eigenvalue −1 dropped).
    let e = g.edges();
    assert_eq!(
        e[0].information,
        nalgebra::Matrix3::new(10.0, 0.0, 0.0, 0.0, 10.0, 0.0, 0.0, 0.0, 100.0)
    );
    assert_eq!(
        e[1].information,
        nalgebra::Matrix3::new(10.0, 0.0, 0.0, 0.0, 10.0, 0.0, 0.0, 0.0, 0.0)
    );
    let want = nalgebra::Matrix3::new(1.5, 1.5, 0.0, 1.5, 1.5, 0.0, 0.0, 0.0, 1.0);
    assert!(
        (e[2].information - want).amax() < 1e-14,
        "{}",
        e[2].information
    );
    assert!(!matches!(
        definiteness(&e[2].information),
        data::g2o::Definiteness::Indefinite { .. }
    ));
    assert_eq!(
        nearest_positive_semidefinite(&e[0].information),
        e[0].information
    );
    assert!(g.cost().is_finite() && g.cost() > 0.0);

    // SE(3): a negative diagonal entry is set to zero.
    let text3 = "VERTEX_SE3:QUAT 0 0 0 0 0 0 0 1\nVERTEX_SE3:QUAT 1 1 0 0 0 0 0 1\n\
                 EDGE_SE3:QUAT 0 1 1 0 0 0 0 0 1 1 0 0 0 0 0 1 0 0 0 0 1 0 0 0 1 0 0 1 0 -1\n";
    let f = parse_g2o(text3, Path::new("constructed3.g2o")).unwrap();
    let G2oGraph::Se3(g) = &f.graph else {
        panic!("SE(3)")
    };
    assert_eq!(f.report.information.len(), 1);
    assert_eq!(f.report.information[0].line, 3);
    let mut want = nalgebra::Matrix6::<f64>::identity();
    want[(5, 5)] = 0.0;
    assert!((g.edges()[0].information - want).amax() < 1e-15);

    // The shared benchmark graphs are all positive definite: no warning, nothing changed.
    for name in ["intel", "sphere2500", "parking-garage", "M3500"] {
        let Some(path) = require(format!("pose_graph_g2o/{name}.g2o")) else {
            continue;
        };
        let f = read_g2o(&path).unwrap();
        assert!(
            f.report.information.is_empty(),
            "{name}: {:?}",
            f.report.information.first()
        );
    }
}

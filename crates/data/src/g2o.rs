//! The g2o pose-graph file format: reader and writer for `VERTEX_SE2`, `EDGE_SE2`,
//! `VERTEX_SE3:QUAT`, `EDGE_SE3:QUAT` and `FIX`.
//!
//! # Records
//!
//! | tag | fields after the tag |
//! |---|---|
//! | `VERTEX_SE2` | `id x y θ` |
//! | `EDGE_SE2` | `from to x y θ` and the 6 upper-triangular entries of `Λ` (row-major) |
//! | `VERTEX_SE3:QUAT` | `id x y z qx qy qz qw` |
//! | `EDGE_SE3:QUAT` | `from to x y z qx qy qz qw` and the 21 upper-triangular entries of `Λ` |
//! | `FIX` | one or more vertex ids |
//!
//! Vertex poses are `world_from_body`; an edge's measurement is
//! `Z = world_from_from⁻¹ · world_from_to` (see [`Edge`]). Blank lines and lines starting with
//! `#` are skipped. Any other tag is *not* silently dropped: it is collected, with its count and
//! line numbers, in [`G2oReport::unknown_tags`] for the caller to report or refuse.
//!
//! # Information matrices: the convention
//!
//! The information matrix is stored exactly as in the file (symmetrised from its upper
//! triangle), in file order, and is interpreted over dwslam's tangent order:
//!
//! * SE(2): g2o's order `(x, y, θ)` is dwslam's `(v₁, v₂, θ)`, as is;
//! * SE(3): g2o's order `(x, y, z, qx, qy, qz)` is taken as dwslam's `(v, ω)` **without**
//!   rescaling the quaternion block. g2o's own SE(3) error uses the quaternion's vector part
//!   (≈ `ω/2`), so g2o's χ² on the same file differs; GTSAM's `readG2o` also does not rescale
//!   (it only permutes the blocks into its `(ω, v)` order), so dwslam's cost on a g2o file is
//!   GTSAM's (see `bench/README.md` for the check against GTSAM).
//!
//! The residual is `d = log(Z⁻¹·X_from⁻¹·X_to)^∨` (thesis eq. 5.15 with `T = X⁻¹`) and the
//! cost `½ Σ dᵀΛd` (half of thesis eq. 5.16).
//!
//! # Files with edges only
//!
//! Some datasets (CSAIL, manhattan, kitti_00) have no `VERTEX` lines. Their vertices are the ids
//! that appear in edges, and their initial poses come from chaining edge measurements along a
//! spanning tree ([`chain_spanning_tree`]): the tree is grown with a union-find, first over the
//! *odometry* edges (ids differing by one) in file order, then over all other edges in file
//! order, each edge that joins two components becoming a tree edge; the smallest id is the root
//! with the identity pose, and poses are propagated from it breadth-first
//! (`X_to = X_from·Z`, or `X_from = X_to·Z⁻¹` when a tree edge is walked backwards). On a file
//! whose ids form an odometry chain this is exactly dead reckoning along the odometry. A
//! vertex not connected to the root starts a component of its own at the identity; the number
//! of components is reported in [`ChainedInitialisation`].
//!
//! # Information matrices that are not positive definite
//!
//! Some published graphs have edges whose information matrix is singular (e.g. zero weight on
//! the unobserved components of a planar edge) or indefinite (rounding of printed values). Such
//! a file loads; every such edge is listed in [`G2oReport::information`] with its line, its
//! vertices and the eigenvalues, for the caller to warn (`dwslam pgo` prints each one):
//!
//! * **singular, positive semi-definite** (smallest eigenvalue within the rounding tolerance
//!   `±64·DOF·ε·max|λ|` of zero): used as it is. The cost `½ dᵀΛd` gives the residual along
//!   the null space no weight. This is what both peers compute: GTSAM's
//!   `noiseModel::Gaussian::Information` turns a zero diagonal precision into σ = ∞ (weight 0;
//!   measured with gtsam 4.3.0's `readG2o` on SE(3) files, cost equal to `½ dᵀΛd`), and g2o
//!   uses `Λ` in `eᵀΛe` directly (its `verifyInformationMatrices` only flags a negative
//!   eigenvalue). GTSAM's `readG2o` refuses an SE(2) edge with a zero diagonal entry ("looks
//!   like this is not G2O matrix order", a format-guessing check), although its noise model
//!   built directly from the matrix handles it.
//! * **indefinite** (an eigenvalue below `−tol`): replaced by the nearest positive
//!   semi-definite matrix in the Frobenius norm (Higham 1988: negative eigenvalues set to zero),
//!   so the cost stays bounded below. The peers give no usable answer here, measured on
//!   constructed files (gtsam 4.3.0, g2o-python 0.0.12): GTSAM's `Information` takes a diagonal
//!   matrix's negative precision to σ = NaN (cost NaN, LM stops at iteration 0) and factors a
//!   full one with Eigen's `LLT` without checking its success, optimising an unrelated matrix
//!   `RᵀR` built from the partial factor; g2o optimises `eᵀΛe` with the indefinite `Λ` as
//!   written (unbounded below along the negative direction) and warns only if
//!   `verifyInformationMatrices` is called.
//!
//! A positive definite matrix is stored exactly as written, so files with well-formed
//! information give the same graph as before.
//!
//! # Errors
//!
//! Malformed input is a [`DataError`] naming the file, the line and what was expected: a wrong
//! field count, a non-number, NaN or ∞, a zero quaternion, a duplicate vertex id, an edge or `FIX` to an unknown vertex, an edge from
//! a vertex to itself, 2D and 3D records mixed in one file, a file without vertex or edge
//! records, non-UTF-8 text.

use crate::error::{DataError, ParseErrorKind};
pub use crate::pose_graph::{Definiteness, definiteness, nearest_positive_semidefinite};
use crate::pose_graph::{Edge, PoseGraph, PoseGraph2, PoseGraph3};
use crate::text::{At, fmt_f64, read_to_string};
use lie::{LieGroup, Se2, Se3, So3};
use nalgebra::{SMatrix, Vector3};
use std::collections::{BTreeMap, HashMap, VecDeque};
use std::io::Write;
use std::path::{Path, PathBuf};

/// A group whose elements g2o stores as vertex poses and edge measurements.
pub trait G2oPose<const DOF: usize>: LieGroup<DOF> {
    /// 2 or 3.
    const DIMENSION: usize;
    /// The vertex tag, e.g. `VERTEX_SE3:QUAT`.
    const VERTEX_TAG: &'static str;
    /// The edge tag, e.g. `EDGE_SE3:QUAT`.
    const EDGE_TAG: &'static str;
    /// Numbers per pose: 3 (`x y θ`) or 7 (`x y z qx qy qz qw`).
    const POSE_FIELDS: usize;

    /// The pose written as `fields` (length [`POSE_FIELDS`](Self::POSE_FIELDS), all finite).
    fn from_g2o_fields(fields: &[f64]) -> Result<Self, ParseErrorKind>;

    /// The numbers g2o writes for this pose.
    fn g2o_fields(&self) -> Vec<f64>;
}

impl G2oPose<3> for Se2 {
    const DIMENSION: usize = 2;
    const VERTEX_TAG: &'static str = "VERTEX_SE2";
    const EDGE_TAG: &'static str = "EDGE_SE2";
    const POSE_FIELDS: usize = 3;

    fn from_g2o_fields(f: &[f64]) -> Result<Self, ParseErrorKind> {
        Ok(Se2::from_xy_angle(f[0], f[1], f[2]))
    }

    fn g2o_fields(&self) -> Vec<f64> {
        let t = self.translation();
        vec![t.x, t.y, self.angle()]
    }
}

impl G2oPose<6> for Se3 {
    const DIMENSION: usize = 3;
    const VERTEX_TAG: &'static str = "VERTEX_SE3:QUAT";
    const EDGE_TAG: &'static str = "EDGE_SE3:QUAT";
    const POSE_FIELDS: usize = 7;

    fn from_g2o_fields(f: &[f64]) -> Result<Self, ParseErrorKind> {
        let rotation = So3::from_quaternion(f[6], f[3], f[4], f[5]).map_err(|source| {
            ParseErrorKind::InvalidRotation {
                what: "quaternion (qx qy qz qw)".into(),
                source,
            }
        })?;
        Ok(Se3::new(rotation, Vector3::new(f[0], f[1], f[2])))
    }

    fn g2o_fields(&self) -> Vec<f64> {
        let t = self.translation();
        let q = self.rotation().unit_quaternion();
        vec![t.x, t.y, t.z, q.i, q.j, q.k, q.w]
    }
}

/// A tag the reader does not know, with how often and where it occurred.
#[derive(Clone, Debug, PartialEq, Eq)]
pub struct UnknownTag {
    /// The tag (first word of the line).
    pub tag: String,
    /// How many lines carry it.
    pub count: usize,
    /// Their 1-based line numbers.
    pub lines: Vec<usize>,
}

/// How the initial poses of an edges-only file were made (see the [module docs](self)).
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub struct ChainedInitialisation {
    /// The root vertex (smallest id), placed at the identity.
    pub root: u64,
    /// Number of edges in the spanning forest.
    pub tree_edges: usize,
    /// How many of those tree edges are odometry edges (ids differing by one).
    pub odometry_tree_edges: usize,
    /// Number of connected components (1 for a connected graph).
    pub components: usize,
}

/// What the reader did with an information matrix that is not positive definite.
#[derive(Clone, Debug, PartialEq)]
pub enum InformationAction {
    /// Positive semi-definite but singular: used as it is; the residual's component along the
    /// null space carries no weight (as GTSAM and g2o do).
    UsedSingular {
        /// Number of eigenvalues above the rounding tolerance.
        rank: usize,
    },
    /// Indefinite: replaced by the nearest positive semi-definite matrix (negative eigenvalues
    /// set to zero, [`nearest_positive_semidefinite`]).
    ProjectedToSemidefinite,
}

/// An edge whose information matrix is not positive definite (see the [module docs](self)).
#[derive(Clone, Debug, PartialEq)]
pub struct InformationWarning {
    /// 1-based line of the edge.
    pub line: usize,
    /// The edge's `from` vertex id.
    pub from: u64,
    /// The edge's `to` vertex id.
    pub to: u64,
    /// Eigenvalues of the information matrix as written in the file, ascending.
    pub eigenvalues: Vec<f64>,
    /// What was done with it.
    pub action: InformationAction,
}

impl std::fmt::Display for InformationWarning {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        let eig: Vec<String> = self
            .eigenvalues
            .iter()
            .map(|l| format!("{l:.6e}"))
            .collect();
        write!(
            f,
            "line {}: edge {} -> {}: information matrix is not positive definite (eigenvalues {}): ",
            self.line,
            self.from,
            self.to,
            eig.join(", ")
        )?;
        match &self.action {
            InformationAction::UsedSingular { rank } => write!(
                f,
                "singular (rank {rank}); used as is, so the residual along its null space has no weight"
            ),
            InformationAction::ProjectedToSemidefinite => write!(
                f,
                "indefinite; replaced by the nearest positive semi-definite matrix (negative eigenvalues set to 0)"
            ),
        }
    }
}

/// What the reader found besides the graph.
#[derive(Clone, Debug, Default, PartialEq)]
pub struct G2oReport {
    /// Tags that were not understood, in order of first appearance; never silently dropped.
    pub unknown_tags: Vec<UnknownTag>,
    /// Edges whose information matrix is not positive definite, in file order.
    pub information: Vec<InformationWarning>,
    /// `Some` when the file had no `VERTEX` lines and poses were chained from the edges.
    pub initialisation: Option<ChainedInitialisation>,
}

/// A g2o graph of either dimension.
#[derive(Clone, Debug, PartialEq)]
pub enum G2oGraph {
    /// `VERTEX_SE2` / `EDGE_SE2`.
    Se2(PoseGraph2),
    /// `VERTEX_SE3:QUAT` / `EDGE_SE3:QUAT`.
    Se3(PoseGraph3),
}

impl G2oGraph {
    /// 2 or 3.
    pub fn dimension(&self) -> usize {
        match self {
            G2oGraph::Se2(_) => 2,
            G2oGraph::Se3(_) => 3,
        }
    }

    /// Number of vertices.
    pub fn vertex_count(&self) -> usize {
        match self {
            G2oGraph::Se2(g) => g.vertices().len(),
            G2oGraph::Se3(g) => g.vertices().len(),
        }
    }

    /// Number of edges.
    pub fn edge_count(&self) -> usize {
        match self {
            G2oGraph::Se2(g) => g.edges().len(),
            G2oGraph::Se3(g) => g.edges().len(),
        }
    }

    /// `½χ²` at the current poses (see [`PoseGraph::cost`]).
    pub fn cost(&self) -> f64 {
        match self {
            G2oGraph::Se2(g) => g.cost(),
            G2oGraph::Se3(g) => g.cost(),
        }
    }
}

/// A g2o file as read: the graph and the report.
#[derive(Clone, Debug, PartialEq)]
pub struct G2oFile {
    /// The pose graph.
    pub graph: G2oGraph,
    /// Unknown tags and how poses were initialised.
    pub report: G2oReport,
}

/// Reads a g2o file (see the [module docs](self) for the format, conventions and errors).
pub fn read_g2o(path: impl AsRef<Path>) -> Result<G2oFile, DataError> {
    let path = path.as_ref();
    parse_g2o(&read_to_string(path)?, path)
}

/// Reads a g2o file that must be 2D.
pub fn read_g2o_se2(path: impl AsRef<Path>) -> Result<(PoseGraph2, G2oReport), DataError> {
    let path = path.as_ref();
    match read_g2o(path)? {
        G2oFile {
            graph: G2oGraph::Se2(g),
            report,
        } => Ok((g, report)),
        _ => Err(wrong_dimension(path, 2)),
    }
}

/// Reads a g2o file that must be 3D.
pub fn read_g2o_se3(path: impl AsRef<Path>) -> Result<(PoseGraph3, G2oReport), DataError> {
    let path = path.as_ref();
    match read_g2o(path)? {
        G2oFile {
            graph: G2oGraph::Se3(g),
            report,
        } => Ok((g, report)),
        _ => Err(wrong_dimension(path, 3)),
    }
}

fn wrong_dimension(path: &Path, wanted: usize) -> DataError {
    DataError::File {
        path: path.to_path_buf(),
        kind: ParseErrorKind::Expected {
            expected: format!("a {wanted}D pose graph"),
            found: format!("a {}D pose graph", 5 - wanted),
        },
    }
}

struct RawVertex {
    line: usize,
    id: u64,
    pose: Vec<f64>,
}

struct RawEdge {
    line: usize,
    from: u64,
    to: u64,
    measurement: Vec<f64>,
    information_upper: Vec<f64>,
}

/// Parses g2o text; `path` only names the source in errors.
pub fn parse_g2o(text: &str, path: &Path) -> Result<G2oFile, DataError> {
    let mut dimension: Option<(usize, String, usize)> = None; // (dim, tag, line)
    let mut vertices = Vec::new();
    let mut edges = Vec::new();
    let mut fixes: Vec<(usize, u64)> = Vec::new();
    let mut unknown: Vec<UnknownTag> = Vec::new();
    let mut unknown_index: HashMap<String, usize> = HashMap::new();

    for (line_index, line) in text.lines().enumerate() {
        let at = At {
            path,
            line: line_index + 1,
        };
        let mut words = line.split_whitespace();
        let Some(tag) = words.next() else { continue };
        if tag.starts_with('#') {
            continue;
        }
        let fields: Vec<&str> = words.collect();
        let (dim, pose_fields, is_vertex) = match tag {
            "VERTEX_SE2" => (2, 3, true),
            "EDGE_SE2" => (2, 3, false),
            "VERTEX_SE3:QUAT" => (3, 7, true),
            "EDGE_SE3:QUAT" => (3, 7, false),
            "FIX" => {
                if fields.is_empty() {
                    return Err(at.err(ParseErrorKind::FieldCount {
                        record: "FIX".into(),
                        expected: "at least 1".into(),
                        found: 0,
                    }));
                }
                for f in &fields {
                    fixes.push((at.line, at.index(f, "FIX vertex id")?));
                }
                continue;
            }
            _ => {
                let i = *unknown_index.entry(tag.to_string()).or_insert_with(|| {
                    unknown.push(UnknownTag {
                        tag: tag.to_string(),
                        count: 0,
                        lines: Vec::new(),
                    });
                    unknown.len() - 1
                });
                unknown[i].count += 1;
                unknown[i].lines.push(at.line);
                continue;
            }
        };
        match &dimension {
            None => dimension = Some((dim, tag.to_string(), at.line)),
            Some((d, first_tag, first_line)) if *d != dim => {
                return Err(at.err(ParseErrorKind::MixedDimensions {
                    tag: tag.to_string(),
                    found: dim,
                    expected: *d,
                    first_tag: first_tag.clone(),
                    first_line: *first_line,
                }));
            }
            _ => {}
        }
        let dof = if dim == 2 { 3 } else { 6 };
        if is_vertex {
            at.field_count(tag, &fields, 1 + pose_fields)?;
            let id = at.index(fields[0], "vertex id")?;
            let pose = fields[1..]
                .iter()
                .enumerate()
                .map(|(k, f)| at.number(f, &format!("pose field {}", k + 1)))
                .collect::<Result<Vec<_>, _>>()?;
            vertices.push(RawVertex {
                line: at.line,
                id,
                pose,
            });
        } else {
            let info_fields = dof * (dof + 1) / 2;
            at.field_count(tag, &fields, 2 + pose_fields + info_fields)?;
            let from = at.index(fields[0], "edge 'from' vertex id")?;
            let to = at.index(fields[1], "edge 'to' vertex id")?;
            let measurement = fields[2..2 + pose_fields]
                .iter()
                .enumerate()
                .map(|(k, f)| at.number(f, &format!("measurement field {}", k + 1)))
                .collect::<Result<Vec<_>, _>>()?;
            let information_upper = fields[2 + pose_fields..]
                .iter()
                .enumerate()
                .map(|(k, f)| at.number(f, &format!("information entry {}", k + 1)))
                .collect::<Result<Vec<_>, _>>()?;
            edges.push(RawEdge {
                line: at.line,
                from,
                to,
                measurement,
                information_upper,
            });
        }
    }

    let report = G2oReport {
        unknown_tags: unknown,
        information: Vec::new(),
        initialisation: None,
    };
    match dimension {
        None => Err(DataError::File {
            path: path.to_path_buf(),
            kind: ParseErrorKind::Empty {
                expected: "VERTEX_SE2/EDGE_SE2 or VERTEX_SE3:QUAT/EDGE_SE3:QUAT records".into(),
            },
        }),
        Some((2, ..)) => {
            let (graph, report) = build::<Se2, 3>(path, vertices, edges, fixes, report)?;
            Ok(G2oFile {
                graph: G2oGraph::Se2(graph),
                report,
            })
        }
        Some(_) => {
            let (graph, report) = build::<Se3, 6>(path, vertices, edges, fixes, report)?;
            Ok(G2oFile {
                graph: G2oGraph::Se3(graph),
                report,
            })
        }
    }
}

/// The symmetric matrix whose upper triangle (row-major) is `upper`.
fn symmetric_from_upper<const DOF: usize>(upper: &[f64]) -> SMatrix<f64, DOF, DOF> {
    let mut m = SMatrix::<f64, DOF, DOF>::zeros();
    let mut k = 0;
    for i in 0..DOF {
        for j in i..DOF {
            m[(i, j)] = upper[k];
            m[(j, i)] = upper[k];
            k += 1;
        }
    }
    m
}

fn build<G: G2oPose<DOF>, const DOF: usize>(
    path: &Path,
    vertices: Vec<RawVertex>,
    raw_edges: Vec<RawEdge>,
    fixes: Vec<(usize, u64)>,
    mut report: G2oReport,
) -> Result<(PoseGraph<G, DOF>, G2oReport), DataError> {
    let at = |line| At { path, line };
    let mut edges = Vec::with_capacity(raw_edges.len());
    for e in &raw_edges {
        let measurement = G::from_g2o_fields(&e.measurement).map_err(|k| at(e.line).err(k))?;
        let mut information = symmetric_from_upper::<DOF>(&e.information_upper);
        if e.from == e.to {
            return Err(at(e.line).err(ParseErrorKind::SelfLoop { id: e.from }));
        }
        // Finite and symmetric (by construction) first; then the definiteness policy.
        match crate::pose_graph::check_information(&information) {
            Err(ParseErrorKind::InformationNotPositiveDefinite { .. }) => {}
            other => other.map_err(|k| at(e.line).err(k))?,
        }
        let action = match definiteness(&information) {
            Definiteness::PositiveDefinite => None,
            Definiteness::Singular { rank, eigenvalues } => {
                Some((InformationAction::UsedSingular { rank }, eigenvalues))
            }
            Definiteness::Indefinite { eigenvalues } => {
                information = nearest_positive_semidefinite(&information);
                Some((InformationAction::ProjectedToSemidefinite, eigenvalues))
            }
        };
        if let Some((action, eigenvalues)) = action {
            report.information.push(InformationWarning {
                line: e.line,
                from: e.from,
                to: e.to,
                eigenvalues,
                action,
            });
        }
        edges.push(Edge {
            from: e.from,
            to: e.to,
            measurement,
            information,
        });
    }

    let mut graph = PoseGraph::<G, DOF>::new();
    if vertices.is_empty() {
        let (poses, init) = chain_spanning_tree(&edges);
        for (id, pose) in poses {
            graph.add_vertex(id, pose).map_err(|k| DataError::File {
                path: path.to_path_buf(),
                kind: k,
            })?;
        }
        report.initialisation = init;
    } else {
        let mut first_line: HashMap<u64, usize> = HashMap::new();
        for v in &vertices {
            if let Some(&first) = first_line.get(&v.id) {
                return Err(at(v.line).err(ParseErrorKind::DuplicateVertex {
                    id: v.id,
                    first_line: first,
                }));
            }
            first_line.insert(v.id, v.line);
            let pose = G::from_g2o_fields(&v.pose).map_err(|k| at(v.line).err(k))?;
            graph
                .add_vertex(v.id, pose)
                .map_err(|k| at(v.line).err(k))?;
        }
    }
    for (edge, raw) in edges.into_iter().zip(&raw_edges) {
        graph.add_edge(edge).map_err(|k| at(raw.line).err(k))?;
    }
    for (line, id) in fixes {
        graph.fix(id).map_err(|k| at(line).err(k))?;
    }
    Ok((graph, report))
}

/// Initial poses for the vertices of `edges` by chaining measurements along a spanning tree
/// (odometry edges first; see the [module docs](self)). Returns the poses sorted by id and a
/// description of the tree, or `None` for no edges.
pub fn chain_spanning_tree<G: LieGroup<DOF>, const DOF: usize>(
    edges: &[Edge<G, DOF>],
) -> (Vec<(u64, G)>, Option<ChainedInitialisation>) {
    let ids: BTreeMap<u64, usize> = {
        let mut ids: Vec<u64> = edges.iter().flat_map(|e| [e.from, e.to]).collect();
        ids.sort_unstable();
        ids.dedup();
        ids.into_iter().enumerate().map(|(i, id)| (id, i)).collect()
    };
    if ids.is_empty() {
        return (Vec::new(), None);
    }
    let n = ids.len();
    let mut parent: Vec<usize> = (0..n).collect();
    fn find(parent: &mut [usize], mut i: usize) -> usize {
        while parent[i] != i {
            parent[i] = parent[parent[i]];
            i = parent[i];
        }
        i
    }
    let is_odometry = |e: &Edge<G, DOF>| e.from.abs_diff(e.to) == 1;
    // adjacency over tree edges: (neighbour, edge index, forward?)
    let mut adjacency: Vec<Vec<(usize, usize, bool)>> = vec![Vec::new(); n];
    let mut tree_edges = 0;
    let mut odometry_tree_edges = 0;
    for pass_odometry in [true, false] {
        for (k, e) in edges.iter().enumerate() {
            if is_odometry(e) != pass_odometry {
                continue;
            }
            let (a, b) = (ids[&e.from], ids[&e.to]);
            let (ra, rb) = (find(&mut parent, a), find(&mut parent, b));
            if ra != rb {
                parent[ra] = rb;
                adjacency[a].push((b, k, true));
                adjacency[b].push((a, k, false));
                tree_edges += 1;
                if pass_odometry {
                    odometry_tree_edges += 1;
                }
            }
        }
    }
    let mut pose: Vec<Option<G>> = vec![None; n];
    let mut components = 0;
    for start in 0..n {
        if pose[start].is_some() {
            continue;
        }
        components += 1;
        pose[start] = Some(G::identity());
        let mut queue = VecDeque::from([start]);
        while let Some(i) = queue.pop_front() {
            let here = pose[i].expect("visited vertices have poses");
            for &(j, k, forward) in &adjacency[i] {
                if pose[j].is_none() {
                    let z = &edges[k].measurement;
                    pose[j] = Some(if forward {
                        here.compose(z)
                    } else {
                        here.compose(&z.inverse())
                    });
                    queue.push_back(j);
                }
            }
        }
    }
    let root = *ids.keys().next().expect("non-empty");
    let poses = ids
        .keys()
        .zip(pose)
        .map(|(&id, p)| (id, p.expect("every component was visited")))
        .collect();
    (
        poses,
        Some(ChainedInitialisation {
            root,
            tree_edges,
            odometry_tree_edges,
            components,
        }),
    )
}

/// Writes `graph` in g2o format: vertices, then edges (information as its upper triangle,
/// row-major, in the same convention the reader uses), then one `FIX` line per fixed vertex.
/// Numbers are written so that reading them back gives the same `f64`s.
pub fn write_g2o<G: G2oPose<DOF>, const DOF: usize>(
    graph: &PoseGraph<G, DOF>,
    mut out: impl Write,
) -> std::io::Result<()> {
    let join = |v: &[f64]| v.iter().map(|x| fmt_f64(*x)).collect::<Vec<_>>().join(" ");
    for v in graph.vertices() {
        writeln!(
            out,
            "{} {} {}",
            G::VERTEX_TAG,
            v.id,
            join(&v.world_from_body.g2o_fields())
        )?;
    }
    for e in graph.edges() {
        let mut upper = Vec::with_capacity(DOF * (DOF + 1) / 2);
        for i in 0..DOF {
            for j in i..DOF {
                upper.push(e.information[(i, j)]);
            }
        }
        writeln!(
            out,
            "{} {} {} {} {}",
            G::EDGE_TAG,
            e.from,
            e.to,
            join(&e.measurement.g2o_fields()),
            join(&upper)
        )?;
    }
    for id in graph.fixed() {
        writeln!(out, "FIX {id}")?;
    }
    out.flush()
}

/// [`write_g2o`] to a file, naming it in the error.
pub fn write_g2o_file<G: G2oPose<DOF>, const DOF: usize>(
    graph: &PoseGraph<G, DOF>,
    path: impl AsRef<Path>,
) -> Result<(), DataError> {
    let path = path.as_ref();
    let io = |source| DataError::Io {
        path: PathBuf::from(path),
        source,
    };
    let file = std::fs::File::create(path).map_err(io)?;
    write_g2o(graph, std::io::BufWriter::new(file)).map_err(io)
}

/// [`write_g2o_file`] for a graph of either dimension.
pub fn write_g2o_graph(graph: &G2oGraph, path: impl AsRef<Path>) -> Result<(), DataError> {
    match graph {
        G2oGraph::Se2(g) => write_g2o_file(g, path),
        G2oGraph::Se3(g) => write_g2o_file(g, path),
    }
}

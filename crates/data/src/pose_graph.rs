//! A pose graph over a Lie group: vertices with `world_from_body` poses, relative-pose edges
//! with information matrices, and fixed vertices (thesis §5.3.2, eq. 5.15–5.16).

use crate::error::ParseErrorKind;
use lie::{LieGroup, Se2, Se3};
use nalgebra::SMatrix;
use std::collections::HashMap;

/// A 2D pose graph (`SE(2)`, tangent `(x, y, θ)`).
pub type PoseGraph2 = PoseGraph<Se2, 3>;
/// A 3D pose graph (`SE(3)`, tangent `(v, ω)`).
pub type PoseGraph3 = PoseGraph<Se3, 6>;

/// A vertex: an id and the body's pose in the world, `world_from_body` (g2o's convention).
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct Vertex<G> {
    /// The vertex's id as written in the file.
    pub id: u64,
    /// The pose: maps body coordinates into world coordinates.
    pub world_from_body: G,
}

/// A relative-pose constraint between two vertices.
///
/// `measurement` is the measured `Z = world_from_from⁻¹ · world_from_to`, the pose of `to` in
/// the frame of `from` (g2o's `EDGE_SE2` / `EDGE_SE3:QUAT`). The residual is
/// `d = log(Z⁻¹ · X_from⁻¹ · X_to)^∨` with `X = world_from_body`: the thesis's
/// `d_ij = log(T_ji · T_i · T_j⁻¹)^∨` (eq. 5.15) with `T_i = X_from⁻¹` (body_from_world) and
/// `T_ji = Z⁻¹`, and exactly GTSAM's `BetweenFactor` error `Logmap(Z⁻¹ · P_from⁻¹ · P_to)`.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct Edge<G, const DOF: usize> {
    /// Id of the vertex the measurement is expressed in.
    pub from: u64,
    /// Id of the measured vertex.
    pub to: u64,
    /// `Z = world_from_from⁻¹ · world_from_to`.
    pub measurement: G,
    /// The information matrix `Λ` (inverse covariance) over the tangent space of the residual,
    /// in dwslam's tangent order (`(v, ω)` for SE(3), `(x, y, θ)` for SE(2)); symmetric positive
    /// definite.
    pub information: SMatrix<f64, DOF, DOF>,
}

impl<G: LieGroup<DOF>, const DOF: usize> Edge<G, DOF> {
    /// The residual `d = log(Z⁻¹ · X_from⁻¹ · X_to)^∨` (thesis eq. 5.15, see [`Edge`]).
    pub fn residual(&self, world_from_from: &G, world_from_to: &G) -> nalgebra::SVector<f64, DOF> {
        self.measurement
            .inverse()
            .compose(&world_from_from.inverse().compose(world_from_to))
            .log()
    }

    /// `dᵀ Λ d`, this edge's term of χ² (thesis eq. 5.16).
    pub fn chi2(&self, world_from_from: &G, world_from_to: &G) -> f64 {
        let d = self.residual(world_from_from, world_from_to);
        (d.transpose() * self.information * d)[(0, 0)]
    }
}

/// A pose graph: vertices in insertion order, edges, and the ids of fixed vertices.
#[derive(Clone, Debug, PartialEq)]
pub struct PoseGraph<G, const DOF: usize> {
    vertices: Vec<Vertex<G>>,
    index: HashMap<u64, usize>,
    edges: Vec<Edge<G, DOF>>,
    fixed: Vec<u64>,
}

impl<G, const DOF: usize> Default for PoseGraph<G, DOF> {
    fn default() -> Self {
        PoseGraph {
            vertices: Vec::new(),
            index: HashMap::new(),
            edges: Vec::new(),
            fixed: Vec::new(),
        }
    }
}

/// Checks that an information matrix is finite, symmetric (to `1e-9` of its largest entry) and
/// positive semi-definite: its smallest eigenvalue is at least `−tol`,
/// `tol = 64·DOF·ε·max|λ|` (the rounding of a zero eigenvalue; see [`definiteness`]). A singular
/// matrix is accepted: the residual's component along its null space carries no weight in the
/// cost `½ dᵀΛd`, as in GTSAM (a zero precision is an infinite σ) and g2o (which only warns
/// about a negative eigenvalue). An indefinite matrix is an error here; the g2o reader projects
/// it onto the positive semi-definite cone instead, with a warning (see [`crate::g2o`]).
pub fn check_information<const DOF: usize>(
    information: &SMatrix<f64, DOF, DOF>,
) -> Result<(), ParseErrorKind> {
    if !information.iter().all(|v| v.is_finite()) {
        return Err(ParseErrorKind::NotFinite {
            field: "information".into(),
            text: describe_matrix(information),
        });
    }
    let asymmetry = (information - information.transpose()).amax();
    if asymmetry > 1e-9 * information.amax() {
        return Err(ParseErrorKind::InformationNotSymmetric { asymmetry });
    }
    if let Definiteness::Indefinite { .. } = definiteness(information) {
        return Err(ParseErrorKind::InformationNotPositiveDefinite {
            matrix: describe_matrix(information),
        });
    }
    Ok(())
}

/// The matrix row by row, for messages: `[a b c; d e f; …]`.
pub(crate) fn describe_matrix<const DOF: usize>(m: &SMatrix<f64, DOF, DOF>) -> String {
    let rows: Vec<String> = m
        .row_iter()
        .map(|r| {
            let v: Vec<String> = r.iter().map(|x| format!("{x}")).collect();
            v.join(" ")
        })
        .collect();
    format!("[{}]", rows.join("; "))
}

/// The definiteness of a symmetric information matrix, from its eigenvalues `λ` (ascending) with
/// the tolerance `tol = 64·DOF·ε·max|λ|` for rounding.
#[derive(Clone, Debug, PartialEq)]
pub enum Definiteness {
    /// `λ_min > tol`.
    PositiveDefinite,
    /// `−tol ≤ λ_min ≤ tol`: positive semi-definite with `rank` eigenvalues above `tol`.
    Singular {
        /// Number of eigenvalues above the tolerance.
        rank: usize,
        /// All eigenvalues, ascending.
        eigenvalues: Vec<f64>,
    },
    /// `λ_min < −tol`.
    Indefinite {
        /// All eigenvalues, ascending.
        eigenvalues: Vec<f64>,
    },
}

/// Classifies a symmetric matrix (see [`Definiteness`]); the symmetric part is used.
pub fn definiteness<const DOF: usize>(m: &SMatrix<f64, DOF, DOF>) -> Definiteness {
    let sym = (m + m.transpose()) * 0.5;
    // Dynamic storage: nalgebra's eigen-solver needs `DimSub` bounds a const generic lacks.
    let dynamic = nalgebra::DMatrix::from_column_slice(DOF, DOF, sym.as_slice());
    let mut eigenvalues: Vec<f64> = dynamic.symmetric_eigenvalues().iter().copied().collect();
    eigenvalues.sort_by(f64::total_cmp);
    let tol =
        64.0 * DOF as f64 * f64::EPSILON * eigenvalues.iter().fold(0.0f64, |a, l| a.max(l.abs()));
    let min = eigenvalues[0];
    if min > tol {
        Definiteness::PositiveDefinite
    } else if min >= -tol {
        let rank = eigenvalues.iter().filter(|&&l| l > tol).count();
        Definiteness::Singular { rank, eigenvalues }
    } else {
        Definiteness::Indefinite { eigenvalues }
    }
}

/// The positive semi-definite matrix nearest to the symmetric `m` in the Frobenius norm
/// (Higham 1988): `Q·max(D, 0)·Qᵀ` for `m = Q·D·Qᵀ`, symmetrised. Its eigenvalues are those of
/// `m` with the negative ones set to zero (up to rounding, within [`definiteness`]'s tolerance).
pub fn nearest_positive_semidefinite<const DOF: usize>(
    m: &SMatrix<f64, DOF, DOF>,
) -> SMatrix<f64, DOF, DOF> {
    let sym = (m + m.transpose()) * 0.5;
    let eig = nalgebra::DMatrix::from_column_slice(DOF, DOF, sym.as_slice()).symmetric_eigen();
    let d = nalgebra::DMatrix::from_diagonal(&eig.eigenvalues.map(|l| l.max(0.0)));
    let p = &eig.eigenvectors * d * eig.eigenvectors.transpose();
    let p = SMatrix::<f64, DOF, DOF>::from_column_slice(p.as_slice());
    (p + p.transpose()) * 0.5
}

impl<G: LieGroup<DOF>, const DOF: usize> PoseGraph<G, DOF> {
    /// An empty graph.
    pub fn new() -> Self {
        Self::default()
    }

    /// Adds a vertex; a duplicate id or a non-finite pose is an error.
    pub fn add_vertex(&mut self, id: u64, world_from_body: G) -> Result<(), ParseErrorKind> {
        if !world_from_body.is_finite() {
            return Err(ParseErrorKind::NotFinite {
                field: format!("pose of vertex {id}"),
                text: format!("{world_from_body:?}"),
            });
        }
        if self.index.contains_key(&id) {
            return Err(ParseErrorKind::DuplicateVertex { id, first_line: 0 });
        }
        self.index.insert(id, self.vertices.len());
        self.vertices.push(Vertex {
            id,
            world_from_body,
        });
        Ok(())
    }

    /// Adds an edge between existing vertices; the information matrix is checked with
    /// [`check_information`], self-loops and unknown vertices are errors.
    pub fn add_edge(&mut self, edge: Edge<G, DOF>) -> Result<(), ParseErrorKind> {
        for id in [edge.from, edge.to] {
            if !self.index.contains_key(&id) {
                return Err(ParseErrorKind::UnknownVertex { id });
            }
        }
        if edge.from == edge.to {
            return Err(ParseErrorKind::SelfLoop { id: edge.from });
        }
        if !edge.measurement.is_finite() {
            return Err(ParseErrorKind::NotFinite {
                field: "measurement".into(),
                text: format!("{:?}", edge.measurement),
            });
        }
        check_information(&edge.information)?;
        self.edges.push(edge);
        Ok(())
    }

    /// Marks an existing vertex as fixed (held constant by an optimiser). Fixing twice is a
    /// no-op.
    pub fn fix(&mut self, id: u64) -> Result<(), ParseErrorKind> {
        if !self.index.contains_key(&id) {
            return Err(ParseErrorKind::UnknownVertex { id });
        }
        if !self.fixed.contains(&id) {
            self.fixed.push(id);
        }
        Ok(())
    }

    /// The vertices in insertion (file) order.
    pub fn vertices(&self) -> &[Vertex<G>] {
        &self.vertices
    }

    /// The edges in insertion (file) order.
    pub fn edges(&self) -> &[Edge<G, DOF>] {
        &self.edges
    }

    /// The ids of the fixed vertices, in the order they were fixed.
    pub fn fixed(&self) -> &[u64] {
        &self.fixed
    }

    /// The position of vertex `id` in [`vertices`](Self::vertices).
    pub fn vertex_index(&self, id: u64) -> Option<usize> {
        self.index.get(&id).copied()
    }

    /// The pose `world_from_body` of vertex `id`.
    pub fn pose(&self, id: u64) -> Option<&G> {
        self.vertex_index(id)
            .map(|i| &self.vertices[i].world_from_body)
    }

    /// Replaces the pose of vertex `id`; returns `false` if there is no such vertex.
    pub fn set_pose(&mut self, id: u64, world_from_body: G) -> bool {
        match self.vertex_index(id) {
            Some(i) => {
                self.vertices[i].world_from_body = world_from_body;
                true
            }
            None => false,
        }
    }

    /// `χ² = Σ dᵀΛd` over all edges at the current poses (thesis eq. 5.16). g2o prints this
    /// number (for SE(3) with its own quaternion residual, so not the same value).
    pub fn chi2(&self) -> f64 {
        self.edges
            .iter()
            .map(|e| {
                let from = &self.vertices[self.index[&e.from]].world_from_body;
                let to = &self.vertices[self.index[&e.to]].world_from_body;
                e.chi2(from, to)
            })
            .sum()
    }

    /// The cost `½χ²`, as GTSAM's `graph.error` and Ceres report it.
    pub fn cost(&self) -> f64 {
        0.5 * self.chi2()
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use nalgebra::Matrix3;

    fn edge(from: u64, to: u64, information: Matrix3<f64>) -> Edge<Se2, 3> {
        Edge {
            from,
            to,
            measurement: Se2::from_xy_angle(1.0, 0.0, 0.1),
            information,
        }
    }

    #[test]
    fn building_a_graph_checks_everything() {
        let mut g = PoseGraph2::new();
        g.add_vertex(0, Se2::identity()).unwrap();
        g.add_vertex(1, Se2::from_xy_angle(1.0, 0.0, 0.0)).unwrap();
        assert_eq!(
            g.add_vertex(1, Se2::identity()),
            Err(ParseErrorKind::DuplicateVertex {
                id: 1,
                first_line: 0
            })
        );
        assert!(matches!(
            g.add_vertex(2, Se2::from_xy_angle(f64::NAN, 0.0, 0.0)),
            Err(ParseErrorKind::NotFinite { .. })
        ));
        let mut asymmetric = Matrix3::identity();
        asymmetric[(0, 1)] = 0.5;
        assert!(matches!(
            g.add_edge(edge(0, 1, asymmetric)),
            Err(ParseErrorKind::InformationNotSymmetric { .. })
        ));
        assert!(matches!(
            g.add_edge(edge(0, 1, -Matrix3::identity())),
            Err(ParseErrorKind::InformationNotPositiveDefinite { .. })
        ));
        assert_eq!(
            g.add_edge(edge(0, 5, Matrix3::identity())),
            Err(ParseErrorKind::UnknownVertex { id: 5 })
        );
        assert_eq!(
            g.add_edge(edge(1, 1, Matrix3::identity())),
            Err(ParseErrorKind::SelfLoop { id: 1 })
        );
        // Singular positive semi-definite information is accepted (no weight on θ here).
        let singular = Matrix3::from_diagonal(&nalgebra::Vector3::new(1.0, 1.0, 0.0));
        g.add_edge(edge(0, 1, singular)).unwrap();
        g.edges.clear();
        g.add_edge(edge(0, 1, Matrix3::identity() * 2.0)).unwrap();
        assert_eq!(g.fix(7), Err(ParseErrorKind::UnknownVertex { id: 7 }));
        g.fix(0).unwrap();
        g.fix(0).unwrap();
        assert_eq!(g.fixed(), &[0]);
        // d = log(Z⁻¹·X1) = log((1,0,0.1)⁻¹·(1,0,0)): only the angle −0.1 and a translation
        // from rotating back; ½χ² = ½·2·|d|².
        let d = Se2::from_xy_angle(1.0, 0.0, 0.1)
            .inverse()
            .compose(&Se2::from_xy_angle(1.0, 0.0, 0.0))
            .log();
        assert!((g.cost() - d.norm_squared()).abs() < 1e-15);
        assert!(g.set_pose(1, Se2::from_xy_angle(1.0, 0.0, 0.1)));
        assert!(g.cost() < 1e-30);
        assert!(!g.set_pose(9, Se2::identity()));
    }
}

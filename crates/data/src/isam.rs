//! The noise-free ground truth of iSAM's pose-graph datasets (`../shared/data/
//! pose_graph_groundtruth_isam/`): `EDGE2` / `EDGE3` lines chained into poses.
//!
//! Format (iSAM's `data/README`): `EDGE2 i j dx dy dθ` followed by the 6 upper-triangular
//! entries of the *square root* information matrix, and `EDGE3 i j dx dy dz roll pitch yaw`
//! followed by 21. A measurement is the pose of `j` in the frame of `i`,
//! `Z = world_from_i⁻¹ · world_from_j` (as in g2o). The 3D rotation is
//! `R = R_z(yaw) · R_y(pitch) · R_x(roll)` (iSAM's `Rot3d(yaw, pitch, roll)`; this convention is
//! the one under which the noise-free loop closures agree with the chained odometry, which the
//! tests check). The square-root information is parsed (and must be finite) but not kept: the
//! files are ground truth.
//!
//! Ground-truth poses come from chaining the odometry edges `i → i+1` from pose 0 at the
//! identity: `world_from_{i+1} = world_from_i · Z_{i,i+1}`. Every id `0..n` must have its
//! odometry edge.

use crate::error::{DataError, ParseErrorKind};
use crate::text::{At, read_to_string};
use lie::{LieGroup, Se2, Se3, So3};
use nalgebra::Vector3;
use std::path::Path;

/// An iSAM edge: `from`, `to` and `Z = world_from_from⁻¹ · world_from_to`.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct IsamEdge<G> {
    /// The vertex the measurement is expressed in.
    pub from: u64,
    /// The measured vertex.
    pub to: u64,
    /// `Z = world_from_from⁻¹ · world_from_to`.
    pub measurement: G,
}

/// An iSAM ground-truth file: all its edges and the poses chained from its odometry.
#[derive(Clone, Debug, PartialEq)]
pub struct IsamGraph<G> {
    /// Every edge in file order (odometry and loop closures).
    pub edges: Vec<IsamEdge<G>>,
    /// `world_from_body` of vertex `i` at index `i`, chained from the odometry.
    pub world_from_body: Vec<G>,
}

/// A ground-truth file of either dimension.
#[derive(Clone, Debug, PartialEq)]
pub enum IsamGroundTruth {
    /// `EDGE2` records.
    Se2(IsamGraph<Se2>),
    /// `EDGE3` records.
    Se3(IsamGraph<Se3>),
}

impl IsamGroundTruth {
    /// The poses as 3D rigid motions (2D poses embedded in the plane `z = 0`, rotation about z).
    pub fn world_from_body_3d(&self) -> Vec<Se3> {
        match self {
            IsamGroundTruth::Se3(g) => g.world_from_body.clone(),
            IsamGroundTruth::Se2(g) => g.world_from_body.iter().map(se2_to_se3).collect(),
        }
    }
}

/// The 3D rigid motion of a planar one: rotation by θ about z, translation `(x, y, 0)`.
pub fn se2_to_se3(pose: &Se2) -> Se3 {
    let t = pose.translation();
    Se3::new(So3::rot_z(pose.angle()), Vector3::new(t.x, t.y, 0.0))
}

/// `R_z(yaw)·R_y(pitch)·R_x(roll)`.
pub fn rotation_from_roll_pitch_yaw(roll: f64, pitch: f64, yaw: f64) -> So3 {
    So3::rot_z(yaw)
        .compose(&So3::rot_y(pitch))
        .compose(&So3::rot_x(roll))
}

/// Reads an iSAM ground-truth file (see the [module docs](self)).
pub fn read_isam_groundtruth(path: impl AsRef<Path>) -> Result<IsamGroundTruth, DataError> {
    let path = path.as_ref();
    parse_isam_groundtruth(&read_to_string(path)?, path)
}

/// Parses iSAM ground-truth text; `path` only names the source in errors.
pub fn parse_isam_groundtruth(text: &str, path: &Path) -> Result<IsamGroundTruth, DataError> {
    let mut edges2 = Vec::new();
    let mut edges3 = Vec::new();
    let mut first: Option<(usize, &str)> = None;
    for (index, line) in text.lines().enumerate() {
        let at = At {
            path,
            line: index + 1,
        };
        let mut words = line.split_whitespace();
        let Some(tag) = words.next() else { continue };
        if tag.starts_with('#') {
            continue;
        }
        let fields: Vec<&str> = words.collect();
        let (dim, measurement_fields, sqrt_fields) = match tag {
            "EDGE2" => (2, 3, 6),
            "EDGE3" => (3, 6, 21),
            _ => {
                return Err(at.err(ParseErrorKind::Expected {
                    expected: "EDGE2 or EDGE3".into(),
                    found: format!("{tag:?}"),
                }));
            }
        };
        match first {
            None => first = Some((at.line, tag)),
            Some((first_line, first_tag)) if first_tag != tag => {
                return Err(at.err(ParseErrorKind::MixedDimensions {
                    tag: tag.into(),
                    found: dim,
                    expected: 5 - dim,
                    first_tag: first_tag.into(),
                    first_line,
                }));
            }
            _ => {}
        }
        at.field_count(tag, &fields, 2 + measurement_fields + sqrt_fields)?;
        let from = at.index(fields[0], "from id")?;
        let to = at.index(fields[1], "to id")?;
        let mut v = Vec::with_capacity(fields.len() - 2);
        for (k, f) in fields[2..].iter().enumerate() {
            v.push(at.number(f, &format!("field {}", k + 3))?);
        }
        if dim == 2 {
            edges2.push((
                at.line,
                IsamEdge {
                    from,
                    to,
                    measurement: Se2::from_xy_angle(v[0], v[1], v[2]),
                },
            ));
        } else {
            let rotation = rotation_from_roll_pitch_yaw(v[3], v[4], v[5]);
            edges3.push((
                at.line,
                IsamEdge {
                    from,
                    to,
                    measurement: Se3::new(rotation, Vector3::new(v[0], v[1], v[2])),
                },
            ));
        }
    }
    match first {
        None => Err(DataError::File {
            path: path.to_path_buf(),
            kind: ParseErrorKind::Empty {
                expected: "EDGE2 or EDGE3 records".into(),
            },
        }),
        Some((_, "EDGE2")) => Ok(IsamGroundTruth::Se2(chain(path, edges2)?)),
        Some(_) => Ok(IsamGroundTruth::Se3(chain(path, edges3)?)),
    }
}

fn chain<G: LieGroup<DOF>, const DOF: usize>(
    path: &Path,
    edges: Vec<(usize, IsamEdge<G>)>,
) -> Result<IsamGraph<G>, DataError> {
    let n = edges
        .iter()
        .map(|(_, e)| e.from.max(e.to) as usize + 1)
        .max()
        .unwrap_or(0);
    if n > 10 * edges.len() + 10 {
        let (line, e) = edges.iter().max_by_key(|(_, e)| e.from.max(e.to)).unwrap();
        return Err(
            At { path, line: *line }.err(ParseErrorKind::IndexOutOfRange {
                what: "vertex".into(),
                index: e.from.max(e.to),
                count: edges.len() + 1,
            }),
        );
    }
    let mut odometry: Vec<Option<G>> = vec![None; n.saturating_sub(1)];
    for (_, e) in &edges {
        if e.to == e.from + 1 && odometry[e.from as usize].is_none() {
            odometry[e.from as usize] = Some(e.measurement);
        }
    }
    let mut poses = Vec::with_capacity(n);
    poses.push(G::identity());
    for (i, z) in odometry.iter().enumerate() {
        let z = z.ok_or_else(|| DataError::File {
            path: path.to_path_buf(),
            kind: ParseErrorKind::Expected {
                expected: format!("an odometry edge {i} → {}", i + 1),
                found: "none".into(),
            },
        })?;
        let next = poses[i].compose(&z);
        poses.push(next);
    }
    Ok(IsamGraph {
        edges: edges.into_iter().map(|(_, e)| e).collect(),
        world_from_body: poses,
    })
}

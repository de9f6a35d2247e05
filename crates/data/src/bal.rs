//! "Bundle Adjustment in the Large" problems (Agarwal et al., ECCV 2010): `problem-*.txt`,
//! plain or bzip2-compressed (`.bz2`, or any file starting with the bzip2 magic `BZh`).
//!
//! Format, whitespace-separated:
//!
//! ```text
//! <num_cameras> <num_points> <num_observations>
//! <camera index> <point index> <x> <y>          (num_observations lines)
//! <9 camera parameters, one per line>            (num_cameras times)
//! <3 point coordinates, one per line>            (num_points times)
//! ```
//!
//! Camera parameters are a Rodrigues rotation vector `ω`, a translation `t`, the focal length
//! `f` and the radial distortion `k₁, k₂`: a world point `X` is mapped to the camera frame by
//! `P = R(ω)·X + t` (so `camera_from_world = (exp(ω), t)`), and projected by
//! [`geom::BalCamera`] (which looks down `−z`; measurements have their origin at the image centre
//! with `y` up).
//!
//! Errors name the line of the offending token: a header that is not three positive integers, a
//! non-number, NaN or ∞, an index out of range, a file that ends before the header's counts are
//! met (reported at its last line), or trailing numbers after them.

use crate::error::{DataError, ParseErrorKind};
use crate::text::{At, bytes_to_string};
use geom::BalCamera;
use lie::{LieGroup, Se3, So3};
use nalgebra::{Vector2, Vector3};
use std::io::Read;
use std::path::Path;

/// One BAL camera: its pose and intrinsics.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct BalCameraParameters {
    /// `P = camera_from_world · X`, with rotation `exp(ω)` of the file's Rodrigues vector.
    pub camera_from_world: Se3,
    /// The file's Rodrigues vector `ω` (axis × angle), kept exactly as read.
    pub rotation_vector: Vector3<f64>,
    /// `(f, k₁, k₂)`.
    pub intrinsics: BalCamera,
}

/// One observation: camera `camera` sees point `point` at `measurement` (BAL image coordinates).
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct BalObservation {
    /// Index into [`BalProblem::cameras`].
    pub camera: usize,
    /// Index into [`BalProblem::points_world`].
    pub point: usize,
    /// `(x, y)`, origin at the image centre, `y` up.
    pub measurement: Vector2<f64>,
}

/// A BAL problem.
#[derive(Clone, Debug, PartialEq)]
pub struct BalProblem {
    /// The cameras in file order.
    pub cameras: Vec<BalCameraParameters>,
    /// The points in world coordinates, in file order.
    pub points_world: Vec<Vector3<f64>>,
    /// The observations in file order.
    pub observations: Vec<BalObservation>,
}

impl BalProblem {
    /// The reprojection residual `ẑ − z` of observation `k` (pixels), or `None` if the point is
    /// behind the camera.
    pub fn residual(&self, k: usize) -> Option<Vector2<f64>> {
        let o = &self.observations[k];
        let camera = &self.cameras[o.camera];
        let p = camera.camera_from_world.act(&self.points_world[o.point]);
        camera
            .intrinsics
            .project(&p)
            .ok()
            .map(|z| z - o.measurement)
    }
}

/// Reads a BAL problem, decompressing bzip2 (by extension `.bz2` or the `BZh` magic).
pub fn read_bal(path: impl AsRef<Path>) -> Result<BalProblem, DataError> {
    let path = path.as_ref();
    let bytes = std::fs::read(path).map_err(|source| DataError::Io {
        path: path.to_path_buf(),
        source,
    })?;
    let compressed = path.extension().is_some_and(|e| e == "bz2") || bytes.starts_with(b"BZh");
    let bytes = if compressed {
        let mut out = Vec::new();
        bzip2::read::BzDecoder::new(bytes.as_slice())
            .read_to_end(&mut out)
            .map_err(|e| DataError::File {
                path: path.to_path_buf(),
                kind: ParseErrorKind::Expected {
                    expected: "bzip2-compressed data".into(),
                    found: format!("a decompression error: {e}"),
                },
            })?;
        out
    } else {
        bytes
    };
    parse_bal(&bytes_to_string(path, bytes)?, path)
}

struct Tokens<'a> {
    path: &'a Path,
    lines: std::iter::Enumerate<std::str::Lines<'a>>,
    current: std::vec::IntoIter<&'a str>,
    line: usize,
    last_line: usize,
}

impl<'a> Tokens<'a> {
    fn new(text: &'a str, path: &'a Path) -> Self {
        Tokens {
            path,
            lines: text.lines().enumerate(),
            current: Vec::new().into_iter(),
            line: 0,
            last_line: text.lines().count().max(1),
        }
    }

    fn next_token(&mut self) -> Option<&'a str> {
        loop {
            if let Some(t) = self.current.next() {
                return Some(t);
            }
            let (i, line) = self.lines.next()?;
            self.line = i + 1;
            self.current = line.split_whitespace().collect::<Vec<_>>().into_iter();
        }
    }

    fn at(&self) -> At<'a> {
        At {
            path: self.path,
            line: self.line,
        }
    }

    fn eof(&self, what: &str) -> DataError {
        At {
            path: self.path,
            line: self.last_line,
        }
        .err(ParseErrorKind::Expected {
            expected: what.to_string(),
            found: "end of file".into(),
        })
    }

    fn number(&mut self, what: impl Fn() -> String) -> Result<f64, DataError> {
        let token = self.next_token().ok_or_else(|| self.eof(&what()))?;
        self.at().number(token, &what())
    }

    fn index(&mut self, what: impl Fn() -> String) -> Result<u64, DataError> {
        let token = self.next_token().ok_or_else(|| self.eof(&what()))?;
        self.at().index(token, &what())
    }
}

/// Parses BAL text; `path` only names the source in errors.
pub fn parse_bal(text: &str, path: &Path) -> Result<BalProblem, DataError> {
    let mut tokens = Tokens::new(text, path);
    let mut header = [0usize; 3];
    for (k, name) in [
        "number of cameras",
        "number of points",
        "number of observations",
    ]
    .iter()
    .enumerate()
    {
        let value = tokens.index(|| format!("header: {name}"))?;
        if value == 0 {
            return Err(tokens.at().err(ParseErrorKind::Expected {
                expected: format!("a positive {name}"),
                found: "0".into(),
            }));
        }
        header[k] = usize::try_from(value).map_err(|_| {
            tokens.at().err(ParseErrorKind::NotAnIndex {
                field: (*name).into(),
                text: value.to_string(),
            })
        })?;
    }
    if tokens.line != 1 {
        return Err(tokens.at().err(ParseErrorKind::Expected {
            expected: "the three header counts on the first line".into(),
            found: format!("the header continuing on line {}", tokens.line),
        }));
    }
    let [num_cameras, num_points, num_observations] = header;
    // Never trust the header for allocation: a corrupt count must not exhaust memory.
    let cap = |n: usize| n.min(text.len() / 2 + 1);
    let mut observations = Vec::with_capacity(cap(num_observations));
    for k in 0..num_observations {
        let camera = tokens.index(|| format!("observation {k}: camera index"))?;
        if camera >= num_cameras as u64 {
            return Err(tokens.at().err(ParseErrorKind::IndexOutOfRange {
                what: format!("observation {k}: camera"),
                index: camera,
                count: num_cameras,
            }));
        }
        let point = tokens.index(|| format!("observation {k}: point index"))?;
        if point >= num_points as u64 {
            return Err(tokens.at().err(ParseErrorKind::IndexOutOfRange {
                what: format!("observation {k}: point"),
                index: point,
                count: num_points,
            }));
        }
        let x = tokens.number(|| format!("observation {k}: x"))?;
        let y = tokens.number(|| format!("observation {k}: y"))?;
        observations.push(BalObservation {
            camera: camera as usize,
            point: point as usize,
            measurement: Vector2::new(x, y),
        });
    }
    const CAMERA_FIELDS: [&str; 9] = ["ω₁", "ω₂", "ω₃", "t₁", "t₂", "t₃", "f", "k₁", "k₂"];
    let mut cameras = Vec::with_capacity(cap(num_cameras));
    for c in 0..num_cameras {
        let mut v = [0.0; 9];
        for (k, name) in CAMERA_FIELDS.iter().enumerate() {
            v[k] = tokens.number(|| format!("camera {c}: parameter {name}"))?;
        }
        let rotation_vector = Vector3::new(v[0], v[1], v[2]);
        cameras.push(BalCameraParameters {
            camera_from_world: Se3::new(So3::exp(&rotation_vector), Vector3::new(v[3], v[4], v[5])),
            rotation_vector,
            intrinsics: BalCamera::new(v[6], v[7], v[8]),
        });
    }
    let mut points_world = Vec::with_capacity(cap(num_points));
    for p in 0..num_points {
        let mut v = [0.0; 3];
        for (k, name) in ["x", "y", "z"].iter().enumerate() {
            v[k] = tokens.number(|| format!("point {p}: {name}"))?;
        }
        points_world.push(Vector3::new(v[0], v[1], v[2]));
    }
    if let Some(extra) = tokens.next_token() {
        return Err(tokens.at().err(ParseErrorKind::Expected {
            expected: format!(
                "end of file after {num_observations} observations, {num_cameras} cameras and \
                 {num_points} points (the header's counts)"
            ),
            found: format!("{extra:?}"),
        }));
    }
    Ok(BalProblem {
        cameras,
        points_world,
        observations,
    })
}

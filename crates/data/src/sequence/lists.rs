//! The text files of the sequence layouts: TUM `rgb.txt`/`depth.txt` lists, EuRoC `data.csv`
//! and `sensor.yaml`, KITTI `calib.txt`, the 7-Scenes `camera-intrinsics.txt`. Every parser
//! takes the text and the path that names it in errors, so that it can be fuzzed without files;
//! none panics on any input.

use crate::camera::LensDistortion;
use crate::camera_file::{distortion_from, from_yaml, se3_from_matrix, strip_yaml_directive};
use crate::error::{DataError, ParseErrorKind};
use crate::text::At;
use geom::PinholeCamera;
use lie::Se3;
use nalgebra::Matrix4;
use serde::Deserialize;
use std::path::Path;

/// One row of a list: the line it came from, the timestamp and the file named.
#[derive(Clone, Debug, PartialEq)]
pub struct ListEntry {
    /// 1-based line number in the list file.
    pub line: usize,
    /// Seconds.
    pub timestamp: f64,
    /// The file, relative to the sequence folder (TUM) or the `data/` folder (EuRoC).
    pub file: String,
}

fn content(line: &str) -> Option<&str> {
    let t = line.trim();
    (!t.is_empty() && !t.starts_with('#')).then_some(t)
}

fn empty(path: &Path, what: &str) -> DataError {
    DataError::File {
        path: path.to_path_buf(),
        kind: ParseErrorKind::Empty {
            expected: what.into(),
        },
    }
}

/// Parses a TUM list (`rgb.txt`, `depth.txt`): `timestamp filename` per line, `#` comments.
pub fn parse_tum_list(text: &str, path: &Path) -> Result<Vec<ListEntry>, DataError> {
    let mut out = Vec::new();
    for (i, line) in text.lines().enumerate() {
        let at = At { path, line: i + 1 };
        let Some(t) = content(line) else { continue };
        let w: Vec<&str> = t.split_whitespace().collect();
        at.field_count("TUM list entry (timestamp filename)", &w, 2)?;
        out.push(ListEntry {
            line: i + 1,
            timestamp: at.number(w[0], "timestamp")?,
            file: w[1].to_string(),
        });
    }
    if out.is_empty() {
        return Err(empty(path, "`timestamp filename` lines"));
    }
    Ok(out)
}

/// Parses a EuRoC camera `data.csv`: `timestamp [ns],filename` per line (header `#…`);
/// timestamps become seconds (`ns/1e9`, as evo does).
pub fn parse_euroc_image_list(text: &str, path: &Path) -> Result<Vec<ListEntry>, DataError> {
    let mut out = Vec::new();
    for (i, line) in text.lines().enumerate() {
        let at = At { path, line: i + 1 };
        let Some(t) = content(line) else { continue };
        let w: Vec<&str> = t.split(',').map(str::trim).collect();
        at.field_count("EuRoC image row (timestamp [ns],filename)", &w, 2)?;
        let ns = at.index(w[0], "timestamp [ns]")?;
        if w[1].is_empty() {
            return Err(at.err(ParseErrorKind::Expected {
                expected: "a file name after the comma".into(),
                found: "nothing".into(),
            }));
        }
        out.push(ListEntry {
            line: i + 1,
            timestamp: ns as f64 / 1e9,
            file: w[1].to_string(),
        });
    }
    if out.is_empty() {
        return Err(empty(path, "`timestamp,filename` rows"));
    }
    Ok(out)
}

/// Checks that timestamps increase strictly; returns the index of the first entry that does
/// not, with a ready error.
pub fn check_increasing(entries: &[ListEntry], path: &Path) -> Result<(), (usize, DataError)> {
    for k in 1..entries.len() {
        let (a, b) = (&entries[k - 1], &entries[k]);
        if b.timestamp <= a.timestamp {
            return Err((
                k,
                DataError::Parse {
                    path: path.to_path_buf(),
                    line: b.line,
                    kind: ParseErrorKind::Expected {
                        expected: format!("a timestamp after {} (line {})", a.timestamp, a.line),
                        found: format!("{} (timestamps must increase)", b.timestamp),
                    },
                },
            ));
        }
    }
    Ok(())
}

/// A EuRoC `sensor.yaml` of a camera.
#[derive(Clone, Debug, PartialEq)]
pub struct EurocCameraYaml {
    /// `T_BS`: `body_from_sensor`.
    pub body_from_sensor: Se3,
    /// `(width, height)`.
    pub resolution: (usize, usize),
    /// `fu, fv, cu, cv`.
    pub pinhole: PinholeCamera,
    /// `radial-tangential` or `equidistant`.
    pub distortion: LensDistortion,
    /// `rate_hz`.
    pub rate_hz: Option<f64>,
}

#[derive(Deserialize)]
struct EurocMatrix {
    rows: usize,
    cols: usize,
    data: Vec<f64>,
}

#[derive(Deserialize)]
struct EurocSensorYaml {
    #[serde(rename = "T_BS")]
    t_bs: EurocMatrix,
    rate_hz: Option<f64>,
    resolution: Option<Vec<usize>>,
    camera_model: Option<String>,
    intrinsics: Option<Vec<f64>>,
    distortion_model: Option<String>,
    distortion_coefficients: Option<Vec<f64>>,
}

fn expected(path: &Path, expected: impl Into<String>, found: impl Into<String>) -> DataError {
    DataError::File {
        path: path.to_path_buf(),
        kind: ParseErrorKind::Expected {
            expected: expected.into(),
            found: found.into(),
        },
    }
}

fn t_bs(path: &Path, m: &EurocMatrix) -> Result<Se3, DataError> {
    if m.rows != 4 || m.cols != 4 || m.data.len() != 16 {
        return Err(expected(
            path,
            "T_BS: rows 4, cols 4 and 16 data entries",
            format!("rows {}, cols {}, {} entries", m.rows, m.cols, m.data.len()),
        ));
    }
    se3_from_matrix(path, "T_BS", &Matrix4::from_row_slice(&m.data))
}

/// Parses the `T_BS` of any EuRoC `sensor.yaml` (`body_from_sensor`).
pub fn parse_euroc_body_from_sensor(text: &str, path: &Path) -> Result<Se3, DataError> {
    #[derive(Deserialize)]
    struct Only {
        #[serde(rename = "T_BS")]
        t_bs: EurocMatrix,
    }
    let y: Only = from_yaml(&strip_yaml_directive(text), path)?;
    t_bs(path, &y.t_bs)
}

/// Parses a EuRoC camera `sensor.yaml` (`%YAML:1.0` header allowed).
pub fn parse_euroc_camera_yaml(text: &str, path: &Path) -> Result<EurocCameraYaml, DataError> {
    let y: EurocSensorYaml = from_yaml(&strip_yaml_directive(text), path)?;
    let body_from_sensor = t_bs(path, &y.t_bs)?;
    let missing = |key: &str| {
        expected(
            path,
            format!("the key `{key}` of a camera sensor.yaml"),
            "none",
        )
    };
    if let Some(m) = &y.camera_model
        && m != "pinhole"
    {
        return Err(expected(path, "camera_model: pinhole", m.clone()));
    }
    let res = y.resolution.ok_or_else(|| missing("resolution"))?;
    if res.len() != 2 || res[0] == 0 || res[1] == 0 {
        return Err(expected(
            path,
            "resolution: [width, height], both > 0",
            format!("{res:?}"),
        ));
    }
    let k = y.intrinsics.ok_or_else(|| missing("intrinsics"))?;
    if k.len() != 4 || !k.iter().all(|v| v.is_finite()) || k[0] <= 0.0 || k[1] <= 0.0 {
        return Err(expected(
            path,
            "intrinsics: [fu, fv, cu, cv], finite, fu and fv > 0",
            format!("{k:?}"),
        ));
    }
    let model = y
        .distortion_model
        .ok_or_else(|| missing("distortion_model"))?;
    let coefficients = y
        .distortion_coefficients
        .ok_or_else(|| missing("distortion_coefficients"))?;
    let distortion = distortion_from(path, &model, &coefficients)?;
    if let Some(r) = y.rate_hz
        && !(r.is_finite() && r > 0.0)
    {
        return Err(expected(path, "rate_hz > 0", r.to_string()));
    }
    Ok(EurocCameraYaml {
        body_from_sensor,
        resolution: (res[0], res[1]),
        pinhole: PinholeCamera::new(k[0], k[1], k[2], k[3]),
        distortion,
        rate_hz: y.rate_hz,
    })
}

/// The projection matrices of a KITTI `calib.txt`, in file order (`P0`, `P1`, …), each
/// row-major 3×4; lines may carry labels (`P0: …`, as KITTI writes them) or not (as the shared
/// snippet); labelled lines other than `P<n>:` (e.g. `Tr:`) are skipped.
pub fn parse_kitti_calib(text: &str, path: &Path) -> Result<Vec<[f64; 12]>, DataError> {
    let mut out = Vec::new();
    for (i, line) in text.lines().enumerate() {
        let at = At { path, line: i + 1 };
        let Some(t) = content(line) else { continue };
        let mut w: Vec<&str> = t.split_whitespace().collect();
        if let Some(label) = w.first().and_then(|f| f.strip_suffix(':')) {
            let is_p = label.len() >= 2
                && label.starts_with('P')
                && label[1..].chars().all(|c| c.is_ascii_digit());
            if !is_p {
                continue;
            }
            let n: usize = label[1..].parse().unwrap_or(usize::MAX);
            if n != out.len() {
                return Err(at.err(ParseErrorKind::Expected {
                    expected: format!("P{}:", out.len()),
                    found: format!("{label}:"),
                }));
            }
            w.remove(0);
        }
        at.field_count("KITTI projection matrix (3×4, row-major)", &w, 12)?;
        let mut p = [0.0; 12];
        for k in 0..12 {
            p[k] = at.number(
                w[k],
                &format!("P{} entry ({}, {})", out.len(), k / 4 + 1, k % 4 + 1),
            )?;
        }
        out.push(p);
    }
    if out.len() < 2 {
        return Err(expected(
            path,
            "at least two projection matrices (P0 left, P1 right)",
            format!("{}", out.len()),
        ));
    }
    Ok(out)
}

/// The rectified stereo camera of KITTI's `P0`, `P1`: `K` from `P0`, and the baseline
/// `b = (P0[0,3] − P1[0,3])/f_x` (`P_i = K·[I | t_i]` with `t_i = (−b_i, 0, 0)` scaled by
/// `f_x`).
pub fn kitti_stereo(p: &[[f64; 12]], path: &Path) -> Result<(PinholeCamera, f64), DataError> {
    let (p0, p1) = (&p[0], &p[1]);
    let fx = p0[0];
    if !(fx > 0.0 && p0[5] > 0.0) {
        return Err(expected(
            path,
            "P0 with positive focal lengths",
            format!("fx {fx}, fy {}", p0[5]),
        ));
    }
    if (p1[0] - fx).abs() > 1e-9 * fx
        || (p1[2] - p0[2]).abs() > 1e-6
        || (p1[6] - p0[6]).abs() > 1e-6
    {
        return Err(expected(
            path,
            "rectified projection matrices (P1 with the intrinsics of P0)",
            format!(
                "P0 fx {} cx {} cy {}, P1 fx {} cx {} cy {}",
                p0[0], p0[2], p0[6], p1[0], p1[2], p1[6]
            ),
        ));
    }
    let baseline = (p0[3] - p1[3]) / fx;
    if baseline.is_nan() || baseline <= 0.0 {
        return Err(expected(
            path,
            "P1 to the right of P0 (P1[0,3] < P0[0,3])",
            format!("baseline {baseline}"),
        ));
    }
    Ok((PinholeCamera::new(fx, p0[5], p0[2], p0[6]), baseline))
}

/// Parses a 3×3 calibration matrix `K` (three rows of three numbers, the 7-Scenes /
/// tsdf-fusion `camera-intrinsics.txt`).
pub fn parse_intrinsics_matrix(text: &str, path: &Path) -> Result<PinholeCamera, DataError> {
    let mut rows = Vec::new();
    for (i, line) in text.lines().enumerate() {
        let at = At { path, line: i + 1 };
        let Some(t) = content(line) else { continue };
        let w: Vec<&str> = t.split_whitespace().collect();
        at.field_count("row of the 3×3 camera matrix K", &w, 3)?;
        let mut r = [0.0; 3];
        for k in 0..3 {
            r[k] = at.number(w[k], &format!("K entry ({}, {})", rows.len() + 1, k + 1))?;
        }
        rows.push(r);
    }
    if rows.len() != 3 {
        return Err(expected(path, "3 rows of K", rows.len().to_string()));
    }
    let (fx, fy, cx, cy) = (rows[0][0], rows[1][1], rows[0][2], rows[1][2]);
    let zeros = [rows[0][1], rows[1][0], rows[2][0], rows[2][1]];
    if !(fx > 0.0 && fy > 0.0) || zeros.iter().any(|z| *z != 0.0) || rows[2][2] != 1.0 {
        return Err(expected(
            path,
            "K = [fx 0 cx; 0 fy cy; 0 0 1] with fx, fy > 0",
            format!("{rows:?}"),
        ));
    }
    Ok(PinholeCamera::new(fx, fy, cx, cy))
}

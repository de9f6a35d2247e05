//! numpy in and out: poses as `(N, 4, 4)` matrices (NaN where a frame has none), a run's
//! result as the dict `dwslam.Result` is made from, images from `(H, W)` / `(H, W, 3)` arrays.

use crate::errors::py_err;
use data::output::{RunRecord, Summary};
use data::sequence::luma;
use data::trajectory::Trajectory;
use lie::{Se3, So3};
use nalgebra::{Matrix3, Rotation3, UnitQuaternion, Vector3};
use numpy::{
    PyArray1, PyArrayMethods, PyReadonlyArrayDyn, PyUntypedArrayMethods, ndarray::ArrayViewD,
};
use pyo3::exceptions::PyValueError;
use pyo3::prelude::*;
use pyo3::types::{PyDict, PyList};
use system::RunResult;
use vision::image::{GrayImage, Image};

/// The 4×4 matrix of a pose, row-major.
pub(crate) fn matrix_of(p: &Se3) -> [f64; 16] {
    let r = p.rotation().rotation_matrix();
    let t = p.translation();
    [
        r[(0, 0)],
        r[(0, 1)],
        r[(0, 2)],
        t.x,
        r[(1, 0)],
        r[(1, 1)],
        r[(1, 2)],
        t.y,
        r[(2, 0)],
        r[(2, 1)],
        r[(2, 2)],
        t.z,
        0.0,
        0.0,
        0.0,
        1.0,
    ]
}

/// Poses as an `(N, 4, 4)` array, NaN where a frame has none.
pub(crate) fn poses_array<'py>(
    py: Python<'py>,
    poses: impl ExactSizeIterator<Item = Option<Se3>>,
) -> PyResult<Bound<'py, PyAny>> {
    let n = poses.len();
    let mut flat = Vec::with_capacity(16 * n);
    for p in poses {
        flat.extend_from_slice(&p.map_or([f64::NAN; 16], |p| matrix_of(&p)));
    }
    Ok(PyArray1::from_vec(py, flat).reshape([n, 4, 4])?.into_any())
}

/// `(timestamps, poses)` of a trajectory.
pub(crate) fn trajectory_tuple<'py>(
    py: Python<'py>,
    t: &Trajectory,
) -> PyResult<(Bound<'py, PyAny>, Bound<'py, PyAny>)> {
    Ok((
        PyArray1::from_slice(py, &t.timestamps).into_any(),
        poses_array(py, t.world_from_body.iter().copied().map(Some))?,
    ))
}

/// Everything a run produced, as the dict `dwslam.Result` is made from.
pub(crate) fn result_dict<'py>(
    py: Python<'py>,
    record: &RunRecord,
    result: &RunResult,
    summary: &Summary,
) -> PyResult<Bound<'py, PyDict>> {
    let d = PyDict::new(py);
    let frames = &record.frames;
    let index: Vec<i64> = frames.iter().map(|f| f.index as i64).collect();
    let stamps: Vec<f64> = frames.iter().map(|f| f.timestamp).collect();
    d.set_item("frame_index", PyArray1::from_vec(py, index))?;
    d.set_item("timestamps", PyArray1::from_vec(py, stamps))?;
    d.set_item(
        "poses",
        poses_array(py, frames.iter().map(|f| f.world_from_camera))?,
    )?;
    let states: Vec<&str> = frames.iter().map(|f| f.state.name()).collect();
    let reasons: Vec<Option<&str>> = frames.iter().map(|f| f.state.reason()).collect();
    d.set_item("states", PyList::new(py, states)?)?;
    d.set_item("reasons", PyList::new(py, reasons)?)?;
    let (t, p) = trajectory_tuple(py, &result.final_trajectory)?;
    d.set_item("final_timestamps", t)?;
    d.set_item("final_poses", p)?;
    let kfs = &record.keyframes;
    d.set_item(
        "keyframe_ids",
        PyArray1::from_vec(py, kfs.iter().map(|k| k.id as i64).collect()),
    )?;
    d.set_item(
        "keyframe_frames",
        PyArray1::from_vec(py, kfs.iter().map(|k| k.frame_index as i64).collect()),
    )?;
    d.set_item(
        "keyframe_timestamps",
        PyArray1::from_vec(py, kfs.iter().map(|k| k.timestamp).collect()),
    )?;
    d.set_item(
        "keyframe_poses",
        poses_array(py, kfs.iter().map(|k| Some(k.world_from_camera)))?,
    )?;
    let points = &record.points;
    let xyz: Vec<f64> = points
        .iter()
        .flat_map(|p| [p.position.x, p.position.y, p.position.z])
        .collect();
    // Grey for points without a colour, as in map.ply.
    let rgb: Vec<u8> = points
        .iter()
        .flat_map(|p| p.colour.unwrap_or([128; 3]))
        .collect();
    d.set_item(
        "points",
        PyArray1::from_vec(py, xyz).reshape([points.len(), 3])?,
    )?;
    d.set_item(
        "colours",
        PyArray1::from_vec(py, rgb).reshape([points.len(), 3])?,
    )?;
    d.set_item(
        "summary_json",
        serde_json::to_string(summary).map_err(|e| py_err(e.into()))?,
    )?;
    Ok(d)
}

/// An `(H, W)` array as an image, named `what` in errors.
pub(crate) fn image_of<T: Copy + Default>(what: &str, a: &ArrayViewD<'_, T>) -> PyResult<Image<T>> {
    let &[h, w] = a.shape() else {
        return Err(PyValueError::new_err(format!(
            "{what}: expected an (H, W) array, got shape {:?}",
            a.shape()
        )));
    };
    Image::from_vec(w, h, w, a.iter().copied().collect())
        .map_err(|e| PyValueError::new_err(format!("{what}: {e}")))
}

/// The grey image tracking uses and the colour planes of an `(H, W)` grey or `(H, W, 3)` RGB
/// array (the grey image of a colour one is its luma, as the readers compute it).
pub(crate) fn intensity(
    what: &str,
    a: &PyReadonlyArrayDyn<'_, u8>,
) -> PyResult<(GrayImage, Option<[GrayImage; 3]>)> {
    let view = a.as_array();
    match a.shape() {
        [_, _] => Ok((image_of(what, &view)?, None)),
        &[h, w, 3] => {
            let plane = |c: usize| {
                Image::from_vec(w, h, w, view.iter().skip(c).step_by(3).copied().collect())
                    .map_err(|e| PyValueError::new_err(format!("{what}: {e}")))
            };
            let planes = [plane(0)?, plane(1)?, plane(2)?];
            Ok((luma(&planes), Some(planes)))
        }
        shape => Err(PyValueError::new_err(format!(
            "{what}: expected an (H, W) grey or (H, W, 3) RGB uint8 array, got shape {shape:?}"
        ))),
    }
}

/// Poses from an `(N, 4, 4)` array of matrices or an `(N, 7)` array of TUM rows
/// (`tx ty tz qx qy qz qw`).
pub(crate) fn poses_of(what: &str, a: &PyReadonlyArrayDyn<'_, f64>) -> PyResult<Vec<Se3>> {
    let view = a.as_array();
    let flat: Vec<f64> = view.iter().copied().collect();
    let bad = |why: String| PyValueError::new_err(format!("{what}: {why}"));
    match a.shape() {
        &[_, 4, 4] => flat
            .chunks_exact(16)
            .map(|m| {
                let r = Matrix3::new(m[0], m[1], m[2], m[4], m[5], m[6], m[8], m[9], m[10]);
                if !r.iter().all(|v| v.is_finite()) || (r.determinant() - 1.0).abs() > 1e-3 {
                    return Err(bad(format!("a pose's rotation is not a rotation: {r}")));
                }
                let q = UnitQuaternion::from_rotation_matrix(&Rotation3::from_matrix(&r));
                Ok(Se3::new(
                    So3::from_unit_quaternion(q),
                    Vector3::new(m[3], m[7], m[11]),
                ))
            })
            .collect(),
        &[_, 7] => flat
            .chunks_exact(7)
            .map(|r| {
                Se3::from_quaternion_translation(
                    r[6],
                    r[3],
                    r[4],
                    r[5],
                    Vector3::new(r[0], r[1], r[2]),
                )
                .map_err(|e| bad(format!("{e}")))
            })
            .collect(),
        shape => Err(bad(format!(
            "expected (N, 4, 4) matrices or (N, 7) TUM rows, got shape {shape:?}"
        ))),
    }
}

//! `dwslam.eval`: trajectory errors as `dwslam eval` computes them; trajectory files read.

use crate::arrays::{poses_of, trajectory_tuple};
use crate::errors::{DwslamError, py_err};
use data::eval::Alignment;
use lie::Se3;
use numpy::{PyArray1, PyReadonlyArrayDyn, PyUntypedArrayMethods};
use pyo3::exceptions::PyValueError;
use pyo3::prelude::*;
use pyo3::types::PyDict;
use std::path::PathBuf;

/// `(timestamps, (N, 4, 4) poses)` of a trajectory file (TUM, KITTI or EuRoC CSV).
#[pyfunction]
pub(crate) fn read_trajectory<'py>(
    py: Python<'py>,
    path: PathBuf,
) -> PyResult<(Bound<'py, PyAny>, Bound<'py, PyAny>)> {
    let (t, _) = data::trajectory::read_trajectory(&path).map_err(|e| py_err(e.into()))?;
    trajectory_tuple(py, &t)
}

/// ATE and RPE of an estimate against a ground truth (as `dwslam eval` and evo compute
/// them), after associating their timestamps.
#[pyfunction]
#[pyo3(signature = (gt_timestamps, gt_poses, est_timestamps, est_poses, *, align="se3",
    max_time_difference=0.01, rpe_delta=1))]
#[allow(clippy::too_many_arguments)]
pub(crate) fn eval_arrays<'py>(
    py: Python<'py>,
    gt_timestamps: PyReadonlyArrayDyn<'py, f64>,
    gt_poses: PyReadonlyArrayDyn<'py, f64>,
    est_timestamps: PyReadonlyArrayDyn<'py, f64>,
    est_poses: PyReadonlyArrayDyn<'py, f64>,
    align: &str,
    max_time_difference: f64,
    rpe_delta: usize,
) -> PyResult<Bound<'py, PyDict>> {
    let alignment = match align {
        "se3" => Alignment::Se3,
        "sim3" => Alignment::Sim3,
        "none" => Alignment::None,
        other => {
            return Err(PyValueError::new_err(format!(
                "align {other:?}: expected \"se3\", \"sim3\" or \"none\""
            )));
        }
    };
    let stamps = |what: &str, a: &PyReadonlyArrayDyn<'_, f64>| -> PyResult<Vec<f64>> {
        match a.shape() {
            [_] => Ok(a.as_array().iter().copied().collect()),
            shape => Err(PyValueError::new_err(format!(
                "{what}: expected an (N,) array, got shape {shape:?}"
            ))),
        }
    };
    let (gt_t, est_t) = (
        stamps("ground truth timestamps", &gt_timestamps)?,
        stamps("estimate timestamps", &est_timestamps)?,
    );
    let (gt, est) = (
        poses_of("ground truth poses", &gt_poses)?,
        poses_of("estimate poses", &est_poses)?,
    );
    for (what, t, p) in [("ground truth", &gt_t, &gt), ("estimate", &est_t, &est)] {
        if t.len() != p.len() {
            return Err(PyValueError::new_err(format!(
                "{what}: {} timestamps for {} poses",
                t.len(),
                p.len()
            )));
        }
    }
    let pairs = data::trajectory::associate(&gt_t, &est_t, max_time_difference, 0.0);
    let r: Vec<Se3> = pairs.iter().map(|&(i, _)| gt[i]).collect();
    let e: Vec<Se3> = pairs.iter().map(|&(_, j)| est[j]).collect();
    let min = if alignment == Alignment::None { 1 } else { 3 };
    if r.len() < min {
        return Err(DwslamError::new_err(format!(
            "{} poses associate within {max_time_difference} s: too few to evaluate",
            r.len()
        )));
    }
    let ate = data::eval::ate(&r, &e, alignment).map_err(|e| py_err(e.into()))?;
    let d = PyDict::new(py);
    d.set_item("poses", r.len())?;
    d.set_item("align", align)?;
    let stats = |s: &data::eval::Statistics| -> PyResult<Bound<'py, PyDict>> {
        let d = PyDict::new(py);
        for (k, v) in [
            ("rmse", s.rmse),
            ("mean", s.mean),
            ("median", s.median),
            ("std", s.std),
            ("min", s.min),
            ("max", s.max),
            ("sse", s.sse),
        ] {
            d.set_item(k, v)?;
        }
        Ok(d)
    };
    d.set_item("ate", stats(&ate.translation)?)?;
    d.set_item("ate_errors", PyArray1::from_vec(py, ate.errors.clone()))?;
    d.set_item("scale", ate.reference_from_estimate.scale())?;
    if r.len() > rpe_delta {
        let rpe =
            data::eval::rpe(&r, &e, rpe_delta, false, alignment).map_err(|e| py_err(e.into()))?;
        d.set_item("rpe_translation", stats(&rpe.translation)?)?;
        let mut deg = rpe.rotation_rad;
        for v in [
            &mut deg.rmse,
            &mut deg.mean,
            &mut deg.median,
            &mut deg.std,
            &mut deg.min,
            &mut deg.max,
        ] {
            *v = v.to_degrees();
        }
        deg.sse = rpe
            .rotation_errors_rad
            .iter()
            .map(|e| e.to_degrees().powi(2))
            .sum();
        d.set_item("rpe_rotation_deg", stats(&deg)?)?;
    }
    Ok(d)
}

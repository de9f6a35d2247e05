//! Cameras as the dicts Python sees (`Sequence.camera`, `System(camera)`).

use data::camera::{DepthCalibration, SensorKind, SensorModel};
use geom::{PinholeCamera, RgbdCamera, StereoCamera};
use pyo3::exceptions::PyValueError;
use pyo3::prelude::*;
use pyo3::types::PyDict;

use crate::args::sensor_kind;

/// A camera as the dict Python sees: `sensor`, `fx`, `fy`, `cx`, `cy`, `baseline` (stereo:
/// metres between the rectified cameras; RGB-D: the virtual baseline), and for RGB-D how the
/// depth images encode depth.
pub(crate) fn camera_dict<'py>(
    py: Python<'py>,
    sensor: &SensorModel,
    depth: Option<DepthCalibration>,
) -> PyResult<Bound<'py, PyDict>> {
    let d = PyDict::new(py);
    let p = sensor.pinhole();
    d.set_item("sensor", sensor.kind().to_string())?;
    for (k, v) in [("fx", p.fx), ("fy", p.fy), ("cx", p.cx), ("cy", p.cy)] {
        d.set_item(k, v)?;
    }
    match sensor {
        SensorModel::Mono(_) => {}
        SensorModel::Stereo(s) => d.set_item("baseline", s.baseline)?,
        SensorModel::Rgbd(r) => d.set_item("baseline", r.stereo.baseline)?,
    }
    if let (SensorModel::Rgbd(_), Some(depth)) = (sensor, depth) {
        d.set_item("depth_metres_per_unit", depth.metres_per_unit)?;
        d.set_item("depth_max_valid_raw", depth.max_valid_raw)?;
    }
    Ok(d)
}

/// Millimetres: the depth unit of most Kinect and RealSense recordings (and 7-Scenes), the
/// default of a camera dict without `depth_metres_per_unit`.
pub(crate) const DEFAULT_METRES_PER_UNIT: f64 = 1e-3;

/// The camera of a camera dict (as [`camera_dict`] writes it), run as `sensor` (default: the
/// dict's own; a stereo or RGB-D camera can run monocular).
pub(crate) fn camera_of(
    camera: &Bound<'_, PyDict>,
    sensor: Option<SensorKind>,
) -> PyResult<(SensorModel, Option<DepthCalibration>)> {
    let get = |key: &str| -> PyResult<Option<Bound<'_, PyAny>>> { camera.get_item(key) };
    let number = |key: &str| -> PyResult<f64> {
        get(key)?
            .ok_or_else(|| PyValueError::new_err(format!("camera: no {key:?}")))?
            .extract()
            .map_err(|_| PyValueError::new_err(format!("camera[{key:?}]: expected a number")))
    };
    let own: Option<String> = get("sensor")?.map(|s| s.extract()).transpose()?;
    let own = sensor_kind(own.as_deref())?;
    let pinhole = PinholeCamera::new(number("fx")?, number("fy")?, number("cx")?, number("cy")?);
    let kind = sensor.or(own).unwrap_or(SensorKind::Mono);
    if sensor.is_some() && own.is_some() && sensor != own && sensor != Some(SensorKind::Mono) {
        return Err(PyValueError::new_err(format!(
            "sensor={:?}: the camera is a {} camera",
            kind.to_string(),
            own.map_or(String::new(), |k| k.to_string())
        )));
    }
    Ok(match kind {
        SensorKind::Mono => (SensorModel::Mono(pinhole), None),
        SensorKind::Stereo => (
            SensorModel::Stereo(StereoCamera::new(pinhole, number("baseline")?)),
            None,
        ),
        SensorKind::Rgbd => {
            let baseline = match get("baseline")? {
                Some(_) => number("baseline")?,
                None => data::camera::DEFAULT_VIRTUAL_BASELINE,
            };
            let metres_per_unit = match get("depth_metres_per_unit")? {
                Some(_) => number("depth_metres_per_unit")?,
                None => DEFAULT_METRES_PER_UNIT,
            };
            let max_valid_raw: u16 = match get("depth_max_valid_raw")? {
                Some(v) => v.extract().map_err(|_| {
                    PyValueError::new_err("camera[\"depth_max_valid_raw\"]: expected 0–65535")
                })?,
                None => u16::MAX,
            };
            (
                SensorModel::Rgbd(RgbdCamera::new(pinhole, baseline)),
                Some(DepthCalibration {
                    metres_per_unit,
                    max_valid_raw,
                    virtual_baseline: baseline,
                }),
            )
        }
    })
}

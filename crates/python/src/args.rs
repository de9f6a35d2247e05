//! Arguments from Python: a configuration (a YAML file or a dict), a sensor's name, and the
//! errors of a sequence request named as Python names the argument.

use crate::errors::{DwslamError, py_err};
use data::camera::SensorKind;
use data::sequence::SequenceFormat;
use pyo3::exceptions::PyValueError;
use pyo3::prelude::*;
use pyo3::types::PyDict;
use runner::SequenceRequest;
use std::path::PathBuf;
use system::SystemConfig;

/// `config`: `None` (the defaults), a path to a YAML file, or a dict of overrides (the YAML
/// file's structure; JSON is YAML). Returns the configuration and its text (kept in a saved
/// map).
pub(crate) fn config_of(config: Option<&Bound<'_, PyAny>>) -> PyResult<(SystemConfig, String)> {
    let Some(config) = config.filter(|c| !c.is_none()) else {
        return Ok((SystemConfig::default(), String::new()));
    };
    if config.is_instance_of::<PyDict>() {
        let json = config
            .py()
            .import("json")?
            .call_method1("dumps", (config,))?;
        let text: String = json.extract()?;
        let parsed = SystemConfig::from_yaml(&text)
            .map_err(|e| PyValueError::new_err(format!("config: {e}")))?;
        return Ok((parsed, text));
    }
    let path: PathBuf = config.extract().map_err(|_| {
        PyValueError::new_err("config: expected None, a dict of overrides or a YAML file's path")
    })?;
    let text = std::fs::read_to_string(&path)
        .map_err(|e| DwslamError::new_err(format!("config {}: {e}", path.display())))?;
    let parsed = SystemConfig::from_file(&path).map_err(|e| py_err(e.into()))?;
    Ok((parsed, text))
}

pub(crate) fn sensor_kind(sensor: Option<&str>) -> PyResult<Option<SensorKind>> {
    match sensor {
        None => Ok(None),
        Some("mono") => Ok(Some(SensorKind::Mono)),
        Some("stereo") => Ok(Some(SensorKind::Stereo)),
        Some("rgbd") => Ok(Some(SensorKind::Rgbd)),
        Some(other) => Err(PyValueError::new_err(format!(
            "sensor {other:?}: expected \"mono\", \"stereo\" or \"rgbd\""
        ))),
    }
}

/// A sequence request's error, naming the Python argument at fault.
pub(crate) fn request_err(e: anyhow::Error, request: &SequenceRequest) -> PyErr {
    match e.downcast_ref::<runner::RequestError>() {
        Some(runner::RequestError::Sensor { want, .. }) => {
            PyValueError::new_err(format!("sensor='{want}': {e}"))
        }
        Some(runner::RequestError::StartFrame(_)) => {
            PyValueError::new_err(format!("start_frame={}: {e}", request.start_frame))
        }
        Some(runner::RequestError::NoFrames) => PyValueError::new_err(format!("max_frames: {e}")),
        None => py_err(e),
    }
}

/// A sequence format's name (`"tum"`, `"euroc"`, `"kitti"`, `"folder"`), if given.
pub(crate) fn format_of(format: Option<&str>) -> PyResult<Option<SequenceFormat>> {
    format
        .map(str::parse::<SequenceFormat>)
        .transpose()
        .map_err(|e| PyValueError::new_err(format!("format: {e}")))
}

/// `localise=True` needs a map to localise in.
pub(crate) fn check_localise(localise: bool, load_map: Option<&PathBuf>) -> PyResult<()> {
    if localise && load_map.is_none() {
        return Err(PyValueError::new_err(
            "localise=True needs load_map: a map to localise in",
        ));
    }
    Ok(())
}

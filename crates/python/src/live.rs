//! `dwslam.System`: the live system driven frame by frame from Python.

use crate::args::{check_localise, config_of, sensor_kind};
use crate::arrays::{image_of, intensity, matrix_of, result_dict};
use crate::camera::{camera_dict, camera_of};
use crate::errors::{DwslamError, py_err};
use data::camera::{DepthCalibration, SensorModel};
use data::sequence::{DepthImage, Frame, FrameImages};
use numpy::{PyArray1, PyArrayMethods, PyReadonlyArrayDyn};
use pyo3::exceptions::PyValueError;
use pyo3::prelude::*;
use pyo3::types::PyDict;
use runner::{MapOptions, SystemSetup};
use std::path::PathBuf;
use std::time::Instant;
use system::{LiveRun, Mode};

/// The live system driven frame by frame from Python (`dwslam.System`).
#[pyclass(unsendable, module = "dwslam._dwslam")]
pub(crate) struct System {
    system: Option<system::System>,
    sensor: SensorModel,
    depth: Option<DepthCalibration>,
    mode: Mode,
    frames: usize,
    started: Instant,
}

impl System {
    fn live(&mut self) -> PyResult<&mut system::System> {
        self.system
            .as_mut()
            .ok_or_else(|| DwslamError::new_err("the system has finished: make a new one"))
    }
}

#[pymethods]
impl System {
    #[new]
    #[pyo3(signature = (camera, *, sensor=None, config=None, deterministic=false,
        load_map=None, localise=false, save_map=None, name="python"))]
    #[allow(clippy::too_many_arguments)]
    fn new(
        py: Python<'_>,
        camera: &Bound<'_, PyDict>,
        sensor: Option<&str>,
        config: Option<&Bound<'_, PyAny>>,
        deterministic: bool,
        load_map: Option<PathBuf>,
        localise: bool,
        save_map: Option<PathBuf>,
        name: &str,
    ) -> PyResult<Self> {
        let (sensor, depth) = camera_of(camera, sensor_kind(sensor)?)?;
        let (config, config_text) = config_of(config)?;
        check_localise(localise, load_map.as_ref())?;
        let mode = if deterministic {
            Mode::Deterministic
        } else {
            Mode::Threaded
        };
        let name = name.to_string();
        let system = py.detach(move || -> anyhow::Result<system::System> {
            let load = load_map.as_deref().map(runner::load_map).transpose()?;
            runner::new_system(
                &sensor,
                config,
                SystemSetup {
                    mode,
                    name,
                    maps: MapOptions {
                        save: save_map,
                        load,
                        localise,
                        config_text,
                    },
                    keyframe_depth: false,
                    observe: false,
                    faults: Default::default(),
                },
            )
        });
        Ok(System {
            system: Some(system.map_err(py_err)?),
            sensor,
            depth,
            mode,
            frames: 0,
            started: Instant::now(),
        })
    }

    /// Tracks one frame; returns the dict `dwslam.Tracked` is made from.
    #[pyo3(signature = (image, timestamp, right=None, depth=None, index=None))]
    fn track<'py>(
        &mut self,
        py: Python<'py>,
        image: PyReadonlyArrayDyn<'py, u8>,
        timestamp: f64,
        right: Option<PyReadonlyArrayDyn<'py, u8>>,
        depth: Option<PyReadonlyArrayDyn<'py, u16>>,
        index: Option<usize>,
    ) -> PyResult<Bound<'py, PyDict>> {
        let (gray, colour) = intensity("image", &image)?;
        let images = match self.sensor {
            SensorModel::Mono(_) => FrameImages::Mono {
                image: gray,
                colour,
            },
            SensorModel::Stereo(_) => {
                let right = right.ok_or_else(|| {
                    PyValueError::new_err("right: a stereo system needs the right image")
                })?;
                FrameImages::Stereo {
                    left: gray,
                    right: intensity("right", &right)?.0,
                }
            }
            SensorModel::Rgbd(_) => {
                let calibration = self.depth.expect("an RGB-D camera has its depth encoding");
                let depth = depth
                    .map(|d| image_of("depth", &d.as_array()))
                    .transpose()?
                    .map(|raw| DepthImage {
                        raw,
                        metres_per_unit: calibration.metres_per_unit,
                        max_valid_raw: calibration.max_valid_raw,
                    });
                FrameImages::Rgbd {
                    image: gray,
                    colour,
                    depth,
                }
            }
        };
        let frame = Frame {
            index: index.unwrap_or(self.frames),
            timestamp,
            images,
            world_from_camera: None,
        };
        let system = self.live()?;
        let report = py
            .detach(|| system.process(frame))
            .map_err(|e| py_err(e.into()))?;
        self.frames += 1;
        let pose = self
            .live()?
            .record()
            .frames
            .last()
            .and_then(|f| f.world_from_camera);
        let d = PyDict::new(py);
        d.set_item("index", report.index)?;
        d.set_item(
            "pose",
            match pose {
                Some(p) => Some(PyArray1::from_vec(py, matrix_of(&p).to_vec()).reshape([4, 4])?),
                None => None,
            },
        )?;
        d.set_item("state", report.state.name())?;
        d.set_item("reason", report.state.reason())?;
        d.set_item("keyframe", report.keyframe.map(|(k, _)| k.index()))?;
        Ok(d)
    }

    /// The map's size and the loops so far.
    fn progress<'py>(&self, py: Python<'py>) -> PyResult<Bound<'py, PyDict>> {
        let d = PyDict::new(py);
        if let Some(s) = &self.system {
            let p = s.progress();
            d.set_item("keyframes", p.keyframes)?;
            d.set_item("points", p.points)?;
            d.set_item("loops", p.loops)?;
        }
        Ok(d)
    }

    /// Ends the run (the final optimisation; the map saved if `save_map` was given); returns
    /// the dict `dwslam.Result` is made from.
    fn finish<'py>(&mut self, py: Python<'py>) -> PyResult<Bound<'py, PyDict>> {
        let system = self.system.take().ok_or_else(|| {
            DwslamError::new_err("the system has finished already: make a new one")
        })?;
        let result = py
            .detach(|| system.finish(false))
            .map_err(|e| py_err(e.into()))?;
        if let Some(Err(e)) = &result.saved_map {
            return Err(DwslamError::new_err(format!("the map is not saved: {e}")));
        }
        let summary = runner::summary_of(&result, self.mode, self.started.elapsed().as_secs_f64());
        result_dict(py, &result.record, &result, &summary)
    }

    /// The camera (a dict as `Sequence.camera`).
    #[getter]
    fn camera<'py>(&self, py: Python<'py>) -> PyResult<Bound<'py, PyDict>> {
        camera_dict(py, &self.sensor, self.depth)
    }

    /// Whether the map's scale is free (a monocular camera).
    #[getter]
    fn free_scale(&self) -> bool {
        matches!(self.sensor, SensorModel::Mono(_))
    }
}

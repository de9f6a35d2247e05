//! `dwslam._dwslam`: the native half of dwslam's Python package (PyO3, abi3).
//!
//! It holds no algorithm and no loop of its own: [`run`] is `runner::execute` (the loop of
//! `dwslam run`), [`System`] makes its system with `runner::new_system` and drives it frame
//! by frame, [`Sequence`] reads frames with `runner::open_sequence`, [`eval_arrays`] calls
//! `data::eval`. What it adds is the crossing: numpy arrays in and out, Python exceptions with
//! the Rust message, and the interpreter released while frames are processed. The Python
//! half (`python/dwslam`) wraps the dicts returned here into typed results.

use numpy::{
    PyArray1, PyArrayMethods, PyReadonlyArrayDyn, PyUntypedArrayMethods, ndarray::ArrayViewD,
};
use pyo3::exceptions::{PyRuntimeError, PyValueError};
use pyo3::prelude::*;
use pyo3::types::{PyDict, PyList};

use data::camera::{DepthCalibration, SensorKind, SensorModel};
use data::eval::Alignment;
use data::output::{RunRecord, Summary};
use data::sequence::{DepthImage, Frame, FrameImages, SequenceFormat, luma};
use data::trajectory::Trajectory;
use geom::{PinholeCamera, RgbdCamera, StereoCamera};
use lie::{Se3, So3};
use nalgebra::{Matrix3, Rotation3, UnitQuaternion, Vector3};
use runner::{MapOptions, SequenceRequest, Settings, SystemSetup};
use std::path::PathBuf;
use std::sync::atomic::{AtomicBool, AtomicUsize, Ordering};
use std::sync::{Arc, Mutex};
use std::time::Instant;
use system::{LiveRun, Mode, RunResult, SystemConfig};
use vision::image::{GrayImage, Image};

pyo3::create_exception!(
    _dwslam,
    DwslamError,
    PyRuntimeError,
    "An error of dwslam (a file it cannot read, a map it cannot load, a run that failed); the \
     message is the one `dwslam` prints."
);

/// An error of the Rust side as a Python exception, with its whole chain of causes.
fn py_err(e: anyhow::Error) -> PyErr {
    DwslamError::new_err(format!("{e:#}"))
}

/// `config`: `None` (the defaults), a path to a YAML file, or a dict of overrides (the YAML
/// file's structure; JSON is YAML). Returns the configuration and its text (kept in a saved
/// map).
fn config_of(config: Option<&Bound<'_, PyAny>>) -> PyResult<(SystemConfig, String)> {
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

fn sensor_kind(sensor: Option<&str>) -> PyResult<Option<SensorKind>> {
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
fn request_err(e: anyhow::Error, request: &SequenceRequest) -> PyErr {
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

/// The 4×4 matrix of a pose, row-major.
fn matrix_of(p: &Se3) -> [f64; 16] {
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
fn poses_array<'py>(
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
fn trajectory_tuple<'py>(
    py: Python<'py>,
    t: &Trajectory,
) -> PyResult<(Bound<'py, PyAny>, Bound<'py, PyAny>)> {
    Ok((
        PyArray1::from_slice(py, &t.timestamps).into_any(),
        poses_array(py, t.world_from_body.iter().copied().map(Some))?,
    ))
}

/// Everything a run produced, as the dict `dwslam.Result` is made from.
fn result_dict<'py>(
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

/// The frames of a run with a check for Ctrl-C before each one: the interpreter runs its
/// signal handlers (`KeyboardInterrupt`), the run stops after the frame in hand and writes its
/// outputs, and the exception is raised once it has.
struct Interruptible {
    frames: runner::Frames,
    stop: Arc<AtomicBool>,
    raised: Arc<Mutex<Option<PyErr>>>,
}

impl Iterator for Interruptible {
    type Item = anyhow::Result<Frame>;

    fn next(&mut self) -> Option<Self::Item> {
        if let Err(e) = Python::attach(|py| py.check_signals()) {
            self.stop.store(true, Ordering::SeqCst);
            *self.raised.lock().unwrap_or_else(|p| p.into_inner()) = Some(e);
        }
        self.frames.next()
    }
}

/// Run folders made for runs without `out`, numbered within the process.
static TEMPORARY_RUNS: AtomicUsize = AtomicUsize::new(0);

/// Runs the live system on a recorded sequence, as `dwslam run` does; returns the dict
/// `dwslam.run` makes its `Result` from.
#[pyfunction]
#[pyo3(signature = (path, *, sensor=None, config=None, out=None, deterministic=false,
    max_frames=None, start_frame=0, depth_frames_only=false, camera=None, format=None,
    skip_bad_frames=false, save_map=None, load_map=None, localise=false, quiet=true))]
#[allow(clippy::too_many_arguments)]
fn run<'py>(
    py: Python<'py>,
    path: PathBuf,
    sensor: Option<&str>,
    config: Option<&Bound<'py, PyAny>>,
    out: Option<PathBuf>,
    deterministic: bool,
    max_frames: Option<usize>,
    start_frame: usize,
    depth_frames_only: bool,
    camera: Option<PathBuf>,
    format: Option<&str>,
    skip_bad_frames: bool,
    save_map: Option<PathBuf>,
    load_map: Option<PathBuf>,
    localise: bool,
    quiet: bool,
) -> PyResult<Bound<'py, PyDict>> {
    let (config, config_text) = config_of(config)?;
    if localise && load_map.is_none() {
        return Err(PyValueError::new_err(
            "localise=True needs load_map: a map to localise in",
        ));
    }
    let request = SequenceRequest {
        path,
        sensor: sensor_kind(sensor)?,
        format: format
            .map(str::parse::<SequenceFormat>)
            .transpose()
            .map_err(|e| PyValueError::new_err(format!("format: {e}")))?,
        camera,
        skip_bad_frames,
        depth_frames_only,
        start_frame,
        max_frames,
    };
    let (temporary, out) = match out {
        Some(out) => (false, out),
        None => (
            true,
            std::env::temp_dir().join(format!(
                "dwslam-run-{}-{}",
                std::process::id(),
                TEMPORARY_RUNS.fetch_add(1, Ordering::SeqCst)
            )),
        ),
    };
    let stop = Arc::new(AtomicBool::new(false));
    let raised = Arc::new(Mutex::new(None));
    let finished = {
        let (stop, raised) = (stop.clone(), raised.clone());
        py.detach(move || -> Result<runner::Finished, PyErr> {
            let load = load_map
                .as_deref()
                .map(runner::load_map)
                .transpose()
                .map_err(py_err)?;
            let mut source =
                runner::open_sequence(&request).map_err(|e| request_err(e, &request))?;
            source.stream = Box::new(Interruptible {
                frames: source.stream,
                stop: stop.clone(),
                raised,
            });
            std::fs::create_dir_all(&out).map_err(|e| {
                DwslamError::new_err(format!(
                    "out {}: cannot create the folder ({e})",
                    out.display()
                ))
            })?;
            let settings = Settings {
                out: out.clone(),
                config,
                mode: if deterministic {
                    Mode::Deterministic
                } else {
                    Mode::Threaded
                },
                kitti: false,
                dense_ply: false,
                quiet,
                maps: MapOptions {
                    save: save_map,
                    load,
                    localise,
                    config_text,
                },
                stop,
            };
            let finished = runner::execute(source, &settings, &|_, _, _, _| Ok(()), None);
            if temporary {
                let _ = std::fs::remove_dir_all(&out);
            }
            finished.map_err(py_err)
        })
    };
    if let Some(e) = raised.lock().unwrap_or_else(|p| p.into_inner()).take() {
        return Err(e);
    }
    let finished = finished?;
    result_dict(
        py,
        &finished.result.record,
        &finished.result,
        &finished.summary,
    )
}

/// A camera as the dict Python sees: `sensor`, `fx`, `fy`, `cx`, `cy`, `baseline` (stereo:
/// metres between the rectified cameras; RGB-D: the virtual baseline), and for RGB-D how the
/// depth images encode depth.
fn camera_dict<'py>(
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
const DEFAULT_METRES_PER_UNIT: f64 = 1e-3;

/// The camera of a camera dict (as [`camera_dict`] writes it), run as `sensor` (default: the
/// dict's own; a stereo or RGB-D camera can run monocular).
fn camera_of(
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

/// An `(H, W)` array as an image, named `what` in errors.
fn image_of<T: Copy + Default>(what: &str, a: &ArrayViewD<'_, T>) -> PyResult<Image<T>> {
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
fn intensity(
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

/// The live system driven frame by frame from Python (`dwslam.System`).
#[pyclass(unsendable, module = "dwslam._dwslam")]
struct System {
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
        if localise && load_map.is_none() {
            return Err(PyValueError::new_err(
                "localise=True needs load_map: a map to localise in",
            ));
        }
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

/// A recorded sequence's frames as numpy arrays (`dwslam.Sequence`).
#[pyclass(unsendable, module = "dwslam._dwslam")]
struct Sequence {
    source: runner::Source,
    remaining: usize,
}

#[pymethods]
impl Sequence {
    #[new]
    #[pyo3(signature = (path, *, sensor=None, max_frames=None, start_frame=0,
        depth_frames_only=false, camera=None, format=None))]
    fn new(
        path: PathBuf,
        sensor: Option<&str>,
        max_frames: Option<usize>,
        start_frame: usize,
        depth_frames_only: bool,
        camera: Option<PathBuf>,
        format: Option<&str>,
    ) -> PyResult<Self> {
        let request = SequenceRequest {
            path,
            sensor: sensor_kind(sensor)?,
            format: format
                .map(str::parse::<SequenceFormat>)
                .transpose()
                .map_err(|e| PyValueError::new_err(format!("format: {e}")))?,
            camera,
            skip_bad_frames: false,
            depth_frames_only,
            start_frame,
            max_frames,
        };
        let source = runner::open_sequence(&request).map_err(|e| request_err(e, &request))?;
        Ok(Sequence {
            remaining: source.frames,
            source,
        })
    }

    /// The camera of the delivered (undistorted, rectified) images.
    #[getter]
    fn camera<'py>(&self, py: Python<'py>) -> PyResult<Bound<'py, PyDict>> {
        camera_dict(py, &self.source.sensor, self.source.depth)
    }

    /// `(timestamps, poses)` of the ground truth, if the sequence has one.
    #[getter]
    fn ground_truth<'py>(
        &self,
        py: Python<'py>,
    ) -> PyResult<Option<(Bound<'py, PyAny>, Bound<'py, PyAny>)>> {
        self.source
            .ground_truth
            .as_ref()
            .map(|g| trajectory_tuple(py, g))
            .transpose()
    }

    fn __len__(&self) -> usize {
        self.source.frames
    }

    fn __iter__(slf: PyRef<'_, Self>) -> PyRef<'_, Self> {
        slf
    }

    /// The next frame: `index`, `timestamp`, `image` (`(H, W, 3)` RGB where the sequence has
    /// colour, else `(H, W)` grey), `right`, `depth` (raw `uint16`), `world_from_camera`.
    fn __next__<'py>(&mut self, py: Python<'py>) -> PyResult<Option<Bound<'py, PyDict>>> {
        if self.remaining == 0 {
            return Ok(None);
        }
        let stream = &mut self.source.stream;
        let Some(frame) = py.detach(|| stream.next()) else {
            return Ok(None);
        };
        self.remaining -= 1;
        let frame = frame.map_err(py_err)?;
        let d = PyDict::new(py);
        d.set_item("index", frame.index)?;
        d.set_item("timestamp", frame.timestamp)?;
        let grey = |i: &GrayImage| -> PyResult<Bound<'py, PyAny>> {
            Ok(PyArray1::from_slice(py, i.data())
                .reshape([i.height(), i.width()])?
                .into_any())
        };
        let rgb = |planes: &[GrayImage; 3]| -> PyResult<Bound<'py, PyAny>> {
            let (w, h) = (planes[0].width(), planes[0].height());
            let mut flat = Vec::with_capacity(3 * w * h);
            for ((r, g), b) in planes[0]
                .data()
                .iter()
                .zip(planes[1].data())
                .zip(planes[2].data())
            {
                flat.extend_from_slice(&[*r, *g, *b]);
            }
            Ok(PyArray1::from_vec(py, flat).reshape([h, w, 3])?.into_any())
        };
        let none = py.None().into_bound(py);
        let (image, right, depth) = match &frame.images {
            FrameImages::Mono { image, colour } => (
                colour.as_ref().map_or_else(|| grey(image), rgb)?,
                none.clone(),
                none,
            ),
            FrameImages::Stereo { left, right } => (grey(left)?, grey(right)?, none),
            FrameImages::Rgbd {
                image,
                colour,
                depth,
            } => (
                colour.as_ref().map_or_else(|| grey(image), rgb)?,
                none.clone(),
                match depth {
                    Some(d) => PyArray1::from_slice(py, d.raw.data())
                        .reshape([d.raw.height(), d.raw.width()])?
                        .into_any(),
                    None => none,
                },
            ),
        };
        d.set_item("image", image)?;
        d.set_item("right", right)?;
        d.set_item("depth", depth)?;
        d.set_item(
            "world_from_camera",
            match frame.world_from_camera {
                Some(p) => Some(PyArray1::from_vec(py, matrix_of(&p).to_vec()).reshape([4, 4])?),
                None => None,
            },
        )?;
        Ok(Some(d))
    }
}

/// Poses from an `(N, 4, 4)` array of matrices or an `(N, 7)` array of TUM rows
/// (`tx ty tz qx qy qz qw`).
fn poses_of(what: &str, a: &PyReadonlyArrayDyn<'_, f64>) -> PyResult<Vec<Se3>> {
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

/// `(timestamps, (N, 4, 4) poses)` of a trajectory file (TUM, KITTI or EuRoC CSV).
#[pyfunction]
fn read_trajectory<'py>(
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
fn eval_arrays<'py>(
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

/// The native module.
#[pymodule]
fn _dwslam(m: &Bound<'_, PyModule>) -> PyResult<()> {
    m.add("DwslamError", m.py().get_type::<DwslamError>())?;
    m.add("__version__", env!("CARGO_PKG_VERSION"))?;
    m.add_function(wrap_pyfunction!(run, m)?)?;
    m.add_function(wrap_pyfunction!(read_trajectory, m)?)?;
    m.add_function(wrap_pyfunction!(eval_arrays, m)?)?;
    m.add_class::<System>()?;
    m.add_class::<Sequence>()?;
    Ok(())
}

//! `dwslam.run`: `runner::execute` on a recorded sequence, the interpreter released, Ctrl-C
//! seen between frames.

use crate::args::{check_localise, config_of, format_of, request_err, sensor_kind};
use crate::arrays::result_dict;
use crate::errors::{DwslamError, py_err};
use data::sequence::Frame;
use pyo3::prelude::*;
use pyo3::types::PyDict;
use runner::{MapOptions, SequenceRequest, Settings};
use std::path::PathBuf;
use std::sync::atomic::{AtomicBool, AtomicUsize, Ordering};
use std::sync::{Arc, Mutex};
use system::Mode;

/// The frames of a run with a check for Ctrl-C before each one: the interpreter runs its
/// signal handlers (`KeyboardInterrupt`), the run stops after the frame in hand and writes its
/// outputs, and the exception is raised once it has.
pub(crate) struct Interruptible {
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
pub(crate) fn run<'py>(
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
    check_localise(localise, load_map.as_ref())?;
    let request = SequenceRequest {
        path,
        sensor: sensor_kind(sensor)?,
        format: format_of(format)?,
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

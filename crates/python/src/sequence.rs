//! `dwslam.Sequence`: a recorded sequence's frames as numpy arrays.

use crate::args::{format_of, request_err, sensor_kind};
use crate::arrays::{matrix_of, trajectory_tuple};
use crate::camera::camera_dict;
use crate::errors::py_err;
use data::sequence::FrameImages;
use numpy::{PyArray1, PyArrayMethods};
use pyo3::prelude::*;
use pyo3::types::PyDict;
use runner::SequenceRequest;
use std::path::PathBuf;
use vision::image::GrayImage;

/// A recorded sequence's frames as numpy arrays (`dwslam.Sequence`).
#[pyclass(unsendable, module = "dwslam._dwslam")]
pub(crate) struct Sequence {
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
            format: format_of(format)?,
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

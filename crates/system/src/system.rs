//! [`System`]: the live system, one type for every camera (stereo, RGB-D, monocular).

use crate::config::SystemConfig;
use crate::depth::DepthSensor;
use crate::frame::SensorFrontEnd;
use crate::keyframes::KeyframeStore;
use crate::mono::MonoSensor;
use crate::result::{FrameReport, LiveRun, Mode, Progress, RunResult, SystemError};
use crate::session::backend::Worker;
use crate::session::sensor::Faults;
use crate::session::{Backend, Optimise, Session};
use data::camera::SensorModel;
use data::output::RunRecord;
use slam::map::{SharedGraph, SlamGraph};
use std::sync::{Arc, RwLock};
use std::time::Duration;
use vision::bow::Vocabulary;

/// How a [`System`] is set up beside its sensor and configuration.
#[derive(Clone, Debug)]
pub struct Options {
    /// How the back-end runs.
    pub mode: Mode,
    /// The input's name, for the outputs.
    pub sequence: String,
    /// The vocabulary of loop closure by appearance and relocalisation (`None`: neither, as
    /// with `loops.enabled: false`).
    pub vocabulary: Option<Arc<Vocabulary>>,
    /// Keep each keyframe's depth image (stereo and RGB-D; the default): only the dense model
    /// fuses it (`crate::dense_model::fuse`, `dwslam run --dense-ply`), and at 4 bytes a pixel
    /// it is half of what a keyframe's images take (a 640×480 RGB-D keyframe: 1.2 of 2.4 MB),
    /// which a long exploration holds for every keyframe.
    pub keyframe_depth: bool,
    /// Faults for the back-end's threads (tests).
    #[doc(hidden)]
    pub faults: Faults,
}

impl Default for Options {
    fn default() -> Self {
        Options {
            mode: Mode::Threaded,
            sequence: String::new(),
            vocabulary: None,
            keyframe_depth: true,
            faults: Faults::default(),
        }
    }
}

/// The live visual SLAM system (thesis §6.3–6.5): a sensor's frames in
/// ([`LiveRun::process`]), every frame's pose and the map out ([`LiveRun::finish`]). One
/// session for every camera (`crate::session`); the camera decides the front-end it plugs in
/// (stereo and RGB-D: depth from the images; monocular: corner tracks, a bootstrap, feature
/// initialisation) and whether the map's scale is free.
pub struct System(Inner);

enum Inner {
    Depth(Session<DepthSensor, 3>),
    Mono(Session<MonoSensor, 2>),
}

impl System {
    /// A system for `sensor` with `config`, set up by `options`.
    pub fn new(
        sensor: &SensorModel,
        config: SystemConfig,
        options: Options,
    ) -> Result<Self, SystemError> {
        config.validate()?;
        let record = RunRecord {
            sequence: options.sequence.clone(),
            sensor: match sensor {
                SensorModel::Stereo(_) => "stereo",
                SensorModel::Rgbd(_) => "rgbd",
                SensorModel::Mono(_) => "mono",
            }
            .to_string(),
            ..RunRecord::default()
        };
        let store = Arc::new(RwLock::new(KeyframeStore::new()));
        let threaded = options.mode == Mode::Threaded;
        let vocabulary = options.vocabulary.clone().filter(|_| config.loops.enabled);
        Ok(System(match sensor {
            SensorModel::Mono(camera) => {
                let graph = Arc::new(SharedGraph::new(SlamGraph::new()));
                let mut mono = MonoSensor::new(*camera, &config);
                let loops = vocabulary.map(|vocabulary| {
                    let stage = mono.loop_stage(vocabulary, &config, store.clone());
                    let template = stage.again();
                    loop_worker(&graph, stage, move || template.again(), &config, &options)
                });
                let backend = Backend {
                    optimiser: None,
                    loops,
                };
                Inner::Mono(Session::new(config, graph, store, mono, backend, record))
            }
            SensorModel::Stereo(_) | SensorModel::Rgbd(_) => {
                let graph = Arc::new(SharedGraph::new(SlamGraph::new()));
                let front = SensorFrontEnd::new(sensor, &config)?;
                let camera = *front.camera();
                let mut depth = DepthSensor::new(front, &config, options.keyframe_depth);
                let params = depth.dwo_params().clone();
                let optimiser = Worker::new(
                    "double window optimisation",
                    graph.clone(),
                    Optimise::new(params.clone(), camera),
                    Box::new(move || Optimise::new(params.clone(), camera)),
                    threaded,
                    1,
                    true,
                    options.faults.optimiser,
                );
                let loops = match vocabulary {
                    Some(vocabulary) => {
                        let closer = depth
                            .loop_closer(vocabulary, &config, store.clone())?
                            .waking(optimiser.sender());
                        let template = closer.again();
                        Some(loop_worker(
                            &graph,
                            closer,
                            move || template.again(),
                            &config,
                            &options,
                        ))
                    }
                    None => None,
                };
                let backend = Backend {
                    optimiser: Some(optimiser),
                    loops,
                };
                Inner::Depth(Session::new(config, graph, store, depth, backend, record))
            }
        }))
    }

    /// Whether the map's scale is free (a monocular camera): trajectories compare with the
    /// ground truth after a similarity, not a rigid, alignment.
    pub fn free_scale(&self) -> bool {
        matches!(self.0, Inner::Mono(_))
    }
}

/// The loop closer's worker on `graph`: `stage` in its thread (threaded mode) with a queue of
/// `loops.queue` keyframes, or inline; `again` makes the stage anew if its thread dies with it.
fn loop_worker<S: crate::session::backend::Stage<N>, const N: usize>(
    graph: &Arc<SharedGraph<N>>,
    stage: S,
    again: impl Fn() -> S + Send + 'static,
    config: &SystemConfig,
    options: &Options,
) -> Worker<S, N> {
    Worker::new(
        "loop closure",
        graph.clone(),
        stage,
        Box::new(again),
        options.mode == Mode::Threaded,
        config.loops.queue,
        false,
        options.faults.loops,
    )
}

impl LiveRun for System {
    fn process(&mut self, frame: data::sequence::Frame) -> Result<FrameReport, SystemError> {
        match &mut self.0 {
            Inner::Depth(s) => s.process(frame),
            Inner::Mono(s) => s.process(frame),
        }
    }

    fn skip_frame(&mut self, index: usize, timestamp: f64, reason: String) {
        match &mut self.0 {
            Inner::Depth(s) => s.skip_frame(index, timestamp, reason),
            Inner::Mono(s) => s.skip_frame(index, timestamp, reason),
        }
    }

    fn record(&self) -> &RunRecord {
        match &self.0 {
            Inner::Depth(s) => s.record(),
            Inner::Mono(s) => s.record(),
        }
    }

    fn record_timing(&mut self, stage: &str, d: Duration) {
        match &mut self.0 {
            Inner::Depth(s) => s.record_timing(stage, d),
            Inner::Mono(s) => s.record_timing(stage, d),
        }
    }

    fn finish(self, interrupted: bool) -> Result<RunResult, SystemError> {
        match self.0 {
            Inner::Depth(s) => s.finish(interrupted),
            Inner::Mono(s) => s.finish(interrupted),
        }
    }

    fn progress(&self) -> Progress {
        match &self.0 {
            Inner::Depth(s) => s.progress(),
            Inner::Mono(s) => s.progress(),
        }
    }
}

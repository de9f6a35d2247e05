//! [`System`]: the live system, one type for every camera (stereo, RGB-D, monocular).

use crate::config::SystemConfig;
use crate::depth::DepthSensor;
use crate::frame::SensorFrontEnd;
use crate::keyframes::KeyframeStore;
use crate::map_file::{MapAbout, MapCamera, MapFile, VocabularyId};
use crate::mono::MonoSensor;
use crate::mono::window::MonoWindow;
use crate::result::RunGraph;
use crate::result::{FrameReport, LiveRun, MapSnapshot, Mode, Progress, RunResult, SystemError};
use crate::session::backend::Worker;
use crate::session::sensor::Faults;
use crate::session::{Backend, Optimise, Session};
use data::camera::SensorModel;
use data::output::RunRecord;
use slam::map::shared::write_lock;
use slam::map::{SharedGraph, SlamGraph};
use std::path::PathBuf;
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
    /// Save the map at the end of the run to this file (`crate::map_file`; atomically).
    pub save_map: Option<PathBuf>,
    /// Go on in this map (`MapFile::read`): the frames are found in it by relocalisation,
    /// then tracked in it; checked against the camera and the vocabulary.
    pub load_map: Option<Arc<MapFile>>,
    /// With `load_map`: only localise in the map, add nothing to it.
    pub localise: bool,
    /// The configuration overrides the run was given (YAML), kept in a saved map.
    pub config_text: String,
    /// Report each frame's observed points ([`FrameReport::observed`]), for a live view.
    pub observe: bool,
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
            save_map: None,
            load_map: None,
            localise: false,
            config_text: String::new(),
            observe: false,
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

/// The session of the run's sensor (boxed: sessions are kilobytes, and of different sizes).
enum Inner {
    Depth(Box<Session<DepthSensor, 3>>),
    Mono(Box<Session<MonoSensor, 2>>),
}

impl System {
    /// A system for `sensor` with `config`, set up by `options`.
    pub fn new(
        sensor: &SensorModel,
        config: SystemConfig,
        options: Options,
    ) -> Result<Self, SystemError> {
        config.validate()?;
        if options.localise && options.load_map.is_none() {
            return Err(SystemError::Unsupported(
                "localisation only needs a map to localise in (load one)".into(),
            ));
        }
        if let Some(map) = &options.load_map {
            map.check(&map.path, sensor, options.vocabulary.as_deref())?;
        }
        let save = options.save_map.clone().map(|path| {
            let mut sequences = options
                .load_map
                .as_ref()
                .map_or_else(Vec::new, |m| m.about.sequences.clone());
            sequences.push(options.sequence.clone());
            let about = MapAbout {
                dwslam: env!("CARGO_PKG_VERSION").to_string(),
                camera: MapCamera::of(sensor),
                vocabulary: options.vocabulary.as_deref().map(VocabularyId::of),
                config: options.config_text.clone(),
                sequences,
            };
            (path, about)
        });
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
        if options.load_map.is_some() && vocabulary.is_none() {
            return Err(SystemError::map_without_vocabulary());
        }
        Ok(System(match sensor {
            SensorModel::Mono(camera) => {
                let graph = match options.load_map.as_deref() {
                    Some(MapFile {
                        graph: RunGraph::Mono(g),
                        keyframes,
                        ..
                    }) => {
                        *write_lock(&store) = keyframes.clone();
                        g.clone()
                    }
                    _ => SlamGraph::new(),
                };
                let graph = Arc::new(SharedGraph::new(graph));
                let mut mono = MonoSensor::new(*camera, &config);
                mono.observe(options.observe);
                let loops = vocabulary.map(|vocabulary| {
                    let stage = mono.loop_stage(vocabulary, &config, store.clone());
                    let template = stage.again();
                    loop_worker(&graph, stage, move || template.again(), &config, &options)
                });
                // One keyframe window at a time: the tracking thread waits for it before the
                // next frame reads the map (`mono::window`).
                let optimiser = Worker::new(
                    "keyframe window",
                    graph.clone(),
                    MonoWindow,
                    Box::new(|| MonoWindow),
                    threaded,
                    1,
                    false,
                    options.faults.optimiser,
                );
                let backend = Backend {
                    optimiser: Some(optimiser),
                    loops,
                };
                let mut session =
                    Session::new(config, graph, store, mono, backend, record).saving(save);
                if let Some(map) = &options.load_map {
                    session.restore(map.features.clone(), options.localise)?;
                }
                Inner::Mono(Box::new(session))
            }
            SensorModel::Stereo(_) | SensorModel::Rgbd(_) => {
                let graph = match options.load_map.as_deref() {
                    Some(MapFile {
                        graph: RunGraph::Depth(g),
                        keyframes,
                        ..
                    }) => {
                        *write_lock(&store) = keyframes.clone();
                        g.clone()
                    }
                    _ => SlamGraph::new(),
                };
                let graph = Arc::new(SharedGraph::new(graph));
                let front = SensorFrontEnd::new(sensor, &config)?;
                let camera = *front.camera();
                let mut depth = DepthSensor::new(front, &config, options.keyframe_depth);
                depth.observe(options.observe);
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
                let mut session =
                    Session::new(config, graph, store, depth, backend, record).saving(save);
                if let Some(map) = &options.load_map {
                    session.restore(map.features.clone(), options.localise)?;
                }
                Inner::Depth(Box::new(session))
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

    fn snapshot(&self) -> MapSnapshot {
        match &self.0 {
            Inner::Depth(s) => s.snapshot(),
            Inner::Mono(s) => s.snapshot(),
        }
    }
}

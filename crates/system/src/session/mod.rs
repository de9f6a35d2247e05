//! The one live system (thesis §6.5.2) for every sensor: frames in, every frame's pose and the
//! map out.
//!
//! A [`Session`] owns, once for every sensor, what a run is made of beside the sensor's
//! front-end: the shared graph (every map of the run in one [`SlamGraph`]), the keyframes'
//! images, the back-end's workers (double window optimisation and loop closure, in threads or
//! inline: [`backend`]), the frames' poses and states ([`log`]), what happens when the camera
//! is lost — relocalisation, and after `tracker.new_map_after` seconds a new map — and the
//! outputs ([`outputs`]). A sensor plugs in through the [`Sensor`] trait: the stereo and
//! RGB-D front-end ([`crate::depth`]) and the monocular one ([`crate::mono`]). [`System`]
//! is the one public type over both.
//!
//! Per frame: the sensor prepares and tracks it ([`Sensor::track`]; a keyframe goes through
//! the keyframe pipeline and is handed to the back-end there); a frame the sensor lost is
//! looked for in the map ([`Sensor::relocalise`]); a camera lost for `tracker.new_map_after`
//! seconds (or one nothing can find again, [`Sensor::can_recover`]) starts a new map
//! ([`Sensor::start_map`]); the back-end's outputs are collected; the frame is recorded.

pub(crate) mod backend;
pub(crate) mod log;
pub(crate) mod outputs;
pub(crate) mod sensor;

use backend::LockWaitLog;

pub(crate) use sensor::{
    Backend, Context, Finished, Found, LoopOutput, Optimise, Optimised, Sensor, Step, StepState,
};

use crate::config::SystemConfig;
use crate::keyframes::KeyframeStore;
use crate::map_file::MapAbout;
use crate::result::{
    FrameReport, LoopEvent, MapSnapshot, Progress, RefusedLoop, Relocalisation, RunResult,
    SavedMap, SystemError,
};
use data::output::{RunRecord, StageTimings};
use slam::dwo::DwoStats;
use slam::map::SharedGraph;
use slam::map::shared::{read_lock, record_lock_waits, take_lock_waits};
use slam::mapping::culling::Retired;
use std::sync::{Arc, RwLock};
use std::time::{Duration, Instant};

/// The one live system, generic in its sensor (see the [module docs](self)).
pub(crate) struct Session<S: Sensor<N>, const N: usize> {
    config: SystemConfig,
    graph: Arc<SharedGraph<N>>,
    store: Arc<RwLock<KeyframeStore>>,
    sensor: S,
    backend: Backend<S::Loops, S::Optimiser, N>,
    log: log::FrameLog,
    /// The timestamp of the first of the lost frames up to now (`None` while tracked).
    lost_since: Option<f64>,
    /// The maps started after a loss: `(frame, seconds lost before it, map)`.
    new_maps: Vec<(usize, f64, usize)>,
    relocalisations: Vec<Relocalisation>,
    loops: Vec<LoopEvent>,
    refused: Vec<RefusedLoop>,
    optimisations: Vec<DwoStats>,
    warnings: Vec<String>,
    /// Keyframes culled in the frame being processed.
    retired: Vec<Retired>,
    /// The loop closer's stage times (threaded: measured in its thread).
    loop_timings: StageTimings,
    /// How long the tracking thread waited for the locks it shares.
    lock_waits: LockWaitLog,
    /// The back-end threads' lock waits, per thread (collected when they stop).
    backend_lock_waits: Vec<(&'static str, crate::result::LockWaits)>,
    /// Keyframes that found the loop closer's queue full (they waited), and the most that
    /// waited at once.
    loop_queue_full: (usize, usize),
    /// Where the map is saved at the end, and what it says about itself.
    save: Option<(std::path::PathBuf, MapAbout)>,
}

/// Writes the map of a run's `result` (its whole final graph, its keyframes' images and
/// `features`) to `path`; a failure is the result's, the run's outputs are written anyway.
fn save_map(
    path: &std::path::Path,
    about: &MapAbout,
    result: &RunResult,
    features: &[(
        slam::map::KeyframeId,
        crate::place_recognition::KeyframeFeatures,
    )],
) -> Result<SavedMap, String> {
    let t = Instant::now();
    let bytes = crate::map_file::encode(about, &result.graph, &result.keyframes, features);
    let size = crate::map_file::write_bytes(path, &bytes).map_err(|e| e.to_string())?;
    let seconds = t.elapsed().as_secs_f64();
    let map = crate::map_file::MapFile::from_bytes(&bytes, path).map_err(|e| e.to_string())?;
    Ok(SavedMap {
        path: path.to_path_buf(),
        bytes: size,
        seconds,
        summary: map.summary(),
    })
}

impl<S: Sensor<N>, const N: usize> Session<S, N> {
    /// A session of `sensor` on `graph` (shared with the sensor's stages) with `backend`.
    #[allow(clippy::too_many_arguments)]
    pub fn new(
        config: SystemConfig,
        graph: Arc<SharedGraph<N>>,
        store: Arc<RwLock<KeyframeStore>>,
        sensor: S,
        backend: Backend<S::Loops, S::Optimiser, N>,
        record: RunRecord,
    ) -> Self {
        Session {
            config,
            graph,
            store,
            sensor,
            backend,
            log: log::FrameLog {
                record,
                ..Default::default()
            },
            lost_since: None,
            new_maps: Vec::new(),
            relocalisations: Vec::new(),
            loops: Vec::new(),
            refused: Vec::new(),
            optimisations: Vec::new(),
            warnings: Vec::new(),
            retired: Vec::new(),
            loop_timings: StageTimings::default(),
            lock_waits: LockWaitLog::default(),
            backend_lock_waits: Vec::new(),
            loop_queue_full: (0, 0),
            save: None,
        }
    }

    /// Saves the map to `path` at the end of the run ([`crate::map_file`]).
    pub fn saving(mut self, save: Option<(std::path::PathBuf, MapAbout)>) -> Self {
        self.save = save;
        self
    }

    /// Goes on in a loaded map (the session's graph and store hold it): its keyframes'
    /// `features` into the sensor's database; with `localise`, only localises in it.
    pub fn restore(
        &mut self,
        features: Vec<(
            slam::map::KeyframeId,
            crate::place_recognition::KeyframeFeatures,
        )>,
        localise: bool,
    ) -> Result<(), SystemError> {
        let (sensor, mut ctx) = self.split();
        sensor.restore(&mut ctx, features, localise)
    }

    /// The sensor, and what it reads and writes of the session.
    fn split(&mut self) -> (&mut S, Context<'_, S::Loops, S::Optimiser, N>) {
        (
            &mut self.sensor,
            Context {
                config: &self.config,
                graph: &self.graph,
                store: &self.store,
                timings: &mut self.log.record.timings,
                backend: &mut self.backend,
                loops: &mut self.loops,
                warnings: &mut self.warnings,
                retired: &mut self.retired,
                optimisations: &mut self.optimisations,
            },
        )
    }

    /// Processes one frame (see the [module docs](self)).
    pub fn process(&mut self, frame: data::sequence::Frame) -> Result<FrameReport, SystemError> {
        let start = Instant::now();
        // Every lock this thread takes for the frame is timed (the tracking thread never waits
        // long for the others: thesis §6.5.2).
        record_lock_waits(true);
        take_lock_waits();
        let (index, timestamp) = (frame.index, frame.timestamp);
        let (sensor, mut ctx) = self.split();
        let frame = sensor.prepare(&mut ctx, frame)?;
        let step = sensor.track(&mut ctx, &frame)?;
        let step = self.recover(&frame, index, timestamp, step)?;
        for r in self.retired.drain(..) {
            self.log.reanchor(&r);
        }
        self.collect_backend();
        let report = FrameReport {
            index,
            state: step.tracking_state(),
            keyframe: step.keyframe.clone(),
            stats: step.stats.clone(),
            time: start.elapsed(),
            time_tracking: step.time_tracking,
            observed: Vec::new(),
        };
        self.log
            .record
            .timings
            .record("track: total", step.time_tracking);
        let anchor = step.anchor.filter(|_| step.tracked());
        let pose = step.camera_from_world.filter(|_| step.tracked());
        if let Some((frame, keyframe)) = step.earlier_keyframe {
            self.log.anchor_earlier(frame, keyframe);
        }
        let mut report = {
            let graph = self.graph.read();
            self.log.push(&graph, timestamp, pose, anchor, report)
        };
        // The observed points go to the caller only: the run's reports keep none.
        report.observed = step.observed;
        self.lock_waits.frame(take_lock_waits());
        Ok(report)
    }

    /// A frame the sensor did not track: looked for in the map by appearance; if not found
    /// and lost for `tracker.new_map_after` seconds (or unrecoverable), a new map.
    fn recover(
        &mut self,
        frame: &S::Frame,
        index: usize,
        timestamp: f64,
        mut step: Step,
    ) -> Result<Step, SystemError> {
        match &step.state {
            StepState::Good | StepState::Weak(_) => {
                self.lost_since = None;
                return Ok(step);
            }
            StepState::Initialising(_) => return Ok(step),
            StepState::Waiting(_) | StepState::Lost(_) => {}
        }
        let t = Instant::now();
        let (sensor, mut ctx) = self.split();
        let found = sensor.relocalise(&mut ctx, frame)?;
        ctx.timings.record("track: relocalise", t.elapsed());
        step.time_tracking += t.elapsed();
        match found {
            Found::Place(found) => {
                let elapsed = step.time_tracking;
                step = Step {
                    time_tracking: elapsed + found.time_tracking,
                    ..*found
                };
                if let Some(r) = step.relocalised.clone() {
                    self.relocalisations.push(r);
                }
                if step.tracked() {
                    self.lost_since = None;
                    return Ok(step);
                }
            }
            Found::Nothing(why) => {
                let add = |reason: &mut String| {
                    if !why.is_empty() {
                        reason.push_str(&format!("; relocalisation: {why}"));
                    }
                };
                match &mut step.state {
                    StepState::Waiting(reason) => {
                        add(reason);
                        return Ok(step);
                    }
                    StepState::Lost(reason) => add(reason),
                    _ => {}
                }
            }
        }
        let since = *self.lost_since.get_or_insert(timestamp);
        let lost_for = timestamp - since;
        if lost_for >= self.config.tracker.new_map_after || !self.sensor.can_recover() {
            let t = Instant::now();
            let before = self.graph.read().current_map();
            let (sensor, mut ctx) = self.split();
            if let Some(started) = sensor.start_map(&mut ctx, frame, lost_for)? {
                let map = self.graph.read().current_map();
                if map != before {
                    self.new_maps.push((index, lost_for, map));
                }
                self.lost_since = None;
                return Ok(Step {
                    time_tracking: step.time_tracking + t.elapsed(),
                    ..started
                });
            }
        }
        Ok(step)
    }

    /// The back-end's outputs so far, into the run's record (and the sensor's).
    fn collect_backend(&mut self) {
        if let Some(optimiser) = &mut self.backend.optimiser {
            let threaded = optimiser.threaded();
            let outputs = optimiser.poll();
            self.take_optimised(outputs, threaded);
        }
        if let Some(loops) = &mut self.backend.loops {
            let outputs = loops.poll();
            self.take_loop_outputs(outputs);
        }
    }

    fn take_optimised(&mut self, outputs: Vec<Optimised<S::OptimiserData>>, threaded: bool) {
        for out in outputs {
            match out {
                Optimised::Stats(s) => {
                    // Inline, the optimisation is a stage of the tracking thread's time.
                    if !threaded {
                        self.log
                            .record
                            .timings
                            .record("optimise: double window", s.total());
                    }
                    self.optimisations.push(s);
                }
                Optimised::Failed(e) => self.warnings.push(e),
                Optimised::Sensor(data) => {
                    let (sensor, mut ctx) = self.split();
                    sensor.optimised(&mut ctx, data);
                }
            }
        }
    }

    fn take_loop_outputs(&mut self, outputs: Vec<LoopOutput<S::LoopData>>) {
        for out in outputs {
            match out {
                LoopOutput::Loop(event) => self.loops.push(event),
                LoopOutput::Refused(r) => self.refused.push(r),
                LoopOutput::Warning(w) => self.warnings.push(w),
                LoopOutput::Timing(stage, d) => self.loop_timings.record(stage, d),
                LoopOutput::Sensor(data) => {
                    let (sensor, mut ctx) = self.split();
                    sensor.loop_data(&mut ctx, data);
                }
            }
        }
    }

    /// Records a frame that could not be read.
    pub fn skip_frame(&mut self, index: usize, timestamp: f64, reason: String) {
        self.log.skip(index, timestamp, reason);
    }

    /// The record so far.
    pub fn record(&self) -> &RunRecord {
        &self.log.record
    }

    /// Records a stage's time measured outside.
    pub fn record_timing(&mut self, stage: &str, d: Duration) {
        self.log.record.timings.record(stage, d);
    }

    /// The map's size and the loops so far.
    pub fn progress(&self) -> Progress {
        let graph = self.graph.read();
        Progress {
            keyframes: graph.num_keyframes(),
            points: graph.num_points(),
            loops: self.loops.len(),
        }
    }

    /// The map as it is now, for a live view.
    pub fn snapshot(&self) -> MapSnapshot {
        let graph = self.graph.read();
        let store = read_lock(&self.store);
        outputs::snapshot(&graph, &store, &self.loops)
    }

    /// Ends the run: the back-end's workers finish their queues, the sensor's final
    /// optimisation runs, and the outputs are collected ([`outputs`]).
    pub fn finish(mut self, interrupted: bool) -> Result<RunResult, SystemError> {
        self.stop_backend();
        let (sensor, mut ctx) = self.split();
        let finished = sensor.finish(&mut ctx, interrupted)?;
        let save = self.save.take().map(|s| (s, self.sensor.place_features()));
        self.log.record.interrupted = interrupted;
        self.log.record.timings.extend(&self.loop_timings);
        let ended = outputs::Ended {
            store: read_lock(&self.store).clone(),
            log: self.log,
            new_maps: self.new_maps,
            relocalisations: self.relocalisations,
            loops: self.loops,
            refused: self.refused,
            optimisations: self.optimisations,
            warnings: self.warnings,
            loop_queue_full: (
                self.loop_queue_full.0,
                self.config.loops.queue,
                self.loop_queue_full.1,
            ),
            lock_waits: self.lock_waits.summary(),
            backend_lock_waits: self.backend_lock_waits,
        };
        let mut result = outputs::assemble(ended, finished, S::run_graph);
        if let Some(((path, about), features)) = save {
            result.saved_map = Some(save_map(&path, &about, &result, &features));
        }
        Ok(result)
    }

    /// Stops the workers (the loop closer first: it may still wake the optimiser), collecting
    /// what they still give and what became of them.
    fn stop_backend(&mut self) {
        // The optimiser's jobs answered first: what they give back may give the loop closer
        // more work (a monocular keyframe's loop job waits for its window).
        if let Some(optimiser) = &mut self.backend.optimiser {
            let threaded = optimiser.threaded();
            let outputs = optimiser.wait();
            self.take_optimised(outputs, threaded);
        }
        if let Some(loops) = self.backend.loops.take() {
            self.loop_queue_full = (loops.queue_full, loops.max_waiting);
            let threaded = loops.threaded();
            let (outputs, _, deaths, waits) = loops.finish();
            self.warnings.extend(deaths);
            if threaded {
                self.backend_lock_waits
                    .push(("loop closure", waits.summary()));
            }
            self.take_loop_outputs(outputs);
        }
        if let Some(optimiser) = self.backend.optimiser.take() {
            let (threaded, name) = (optimiser.threaded(), optimiser.name());
            let (outputs, _, deaths, waits) = optimiser.finish();
            self.warnings.extend(deaths);
            if threaded {
                self.backend_lock_waits.push((name, waits.summary()));
            }
            self.take_optimised(outputs, threaded);
        }
    }
}

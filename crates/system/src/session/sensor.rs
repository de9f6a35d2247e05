//! The interface between the session and a sensor: the [`Sensor`] trait a front-end
//! implements, what it gives back per frame ([`Step`]) and at the end ([`Finished`]), what it
//! may use of the session meanwhile ([`Context`]: the graph, the keyframes' images, the
//! back-end), and the back-end's stages the session runs for every sensor
//! ([`Optimise`] and what an optimiser stage gives back, [`Optimised`]; the loop stage's
//! [`LoopOutput`]).

use super::backend::{Fault, Stage, Worker};
use crate::config::SystemConfig;
use crate::keyframes::{KeyframeReason, KeyframeStore};
use crate::observed::Observed;
use crate::place_recognition::KeyframeFeatures;
use crate::result::{LoopEvent, RefusedLoop, Relocalisation, RunGraph, SystemError};
use crate::tracker::TrackerStats;
use data::output::{StageTimings, TrackingState};
use lie::Sim3;
use slam::dwo::{DoubleWindowOptimiser, DwoError, DwoParams, DwoStats};
use slam::map::shared::read_lock;
use slam::map::{KeyframeId, SharedGraph, SlamGraph};
use slam::mapping::culling::Retired;
use std::sync::{Arc, RwLock};
use std::time::Duration;

/// What a sensor's front-end made of one frame.
#[derive(Clone, Debug)]
pub(crate) struct Step {
    /// How it went.
    pub state: StepState,
    /// The pose, in its map (`None` where not tracked).
    pub camera_from_world: Option<Sim3>,
    /// The keyframe the pose is kept relative to for the trajectory after the run, and
    /// whether the frame is that keyframe's own.
    pub anchor: Option<(KeyframeId, bool)>,
    /// The keyframe the frame became, and why.
    pub keyframe: Option<(KeyframeId, KeyframeReason)>,
    /// The tracker's counts.
    pub stats: Option<TrackerStats>,
    /// Time of the tracking stages (a keyframe's pipeline excluded).
    pub time_tracking: Duration,
    /// The relocalisation that found the frame.
    pub relocalised: Option<Relocalisation>,
    /// An earlier frame (its index) that became a keyframe with this one: a monocular
    /// bootstrap's first frame, a keyframe once the bootstrap succeeds.
    pub earlier_keyframe: Option<(usize, KeyframeId)>,
    /// The points the front-end looked at (when observing, for a live view).
    pub observed: Vec<Observed>,
}

/// How a frame went.
#[derive(Clone, Debug, PartialEq)]
pub(crate) enum StepState {
    /// Tracked well.
    Good,
    /// Tracked, but weakly: why.
    Weak(String),
    /// No map to track in yet (the first frames; a monocular bootstrap): why.
    Initialising(String),
    /// Not tracked, but the camera is not lost yet (a frame the monocular tracks could not
    /// follow into, waited out against the last good one): why.
    Waiting(String),
    /// Lost: why.
    Lost(String),
}

impl Step {
    /// A frame with no pose.
    pub fn untracked(state: StepState, time_tracking: Duration) -> Self {
        Step {
            state,
            camera_from_world: None,
            anchor: None,
            keyframe: None,
            stats: None,
            time_tracking,
            relocalised: None,
            earlier_keyframe: None,
            observed: Vec::new(),
        }
    }

    /// A frame made keyframe `keyframe` (for `reason`) at `camera_from_world`, in `state`.
    pub fn keyframe_made(
        state: StepState,
        camera_from_world: Sim3,
        keyframe: KeyframeId,
        reason: KeyframeReason,
    ) -> Self {
        Step {
            state,
            camera_from_world: Some(camera_from_world),
            anchor: Some((keyframe, true)),
            keyframe: Some((keyframe, reason)),
            stats: None,
            time_tracking: Duration::ZERO,
            relocalised: None,
            earlier_keyframe: None,
            observed: Vec::new(),
        }
    }

    pub(super) fn tracked(&self) -> bool {
        matches!(self.state, StepState::Good | StepState::Weak(_))
    }

    pub(super) fn tracking_state(&self) -> TrackingState {
        match &self.state {
            StepState::Good => TrackingState::Good,
            StepState::Weak(r) => TrackingState::Weak(r.clone()),
            StepState::Initialising(r) | StepState::Waiting(r) | StepState::Lost(r) => {
                TrackingState::Lost(r.clone())
            }
        }
    }
}

/// What [`Sensor::relocalise`] found.
pub(crate) enum Found {
    /// The frame's place, and the frame tracked from there (tracked, or lost again).
    Place(Box<Step>),
    /// Nothing: why.
    Nothing(String),
}

/// What a loop-closure stage gives back to the session, whatever the sensor.
#[derive(Debug)]
pub(crate) enum LoopOutput<D> {
    /// A loop closed, or two maps merged or joined.
    Loop(LoopEvent),
    /// A loop refused for the correction it needed.
    Refused(RefusedLoop),
    /// Something that failed without stopping the run.
    Warning(String),
    /// A stage's time.
    Timing(&'static str, Duration),
    /// What only the sensor reads.
    Sensor(D),
}

/// The double window optimisation as a back-end stage: woken after a keyframe (or a loop), it
/// optimises the shared graph (plan under a read lock, solve without, write back briefly); a
/// result superseded by a change to the window's poses meanwhile is re-planned.
pub(crate) struct Optimise<C> {
    optimiser: DoubleWindowOptimiser,
    camera: C,
}

/// What an optimisation stage gives back.
#[derive(Debug)]
pub(crate) enum Optimised<D> {
    /// A double window optimisation's statistics.
    Stats(DwoStats),
    /// Why it failed.
    Failed(String),
    /// What only the sensor reads (the monocular keyframe's solved window).
    Sensor(D),
}

/// A camera the double window optimisation can run with, in its own thread.
pub(crate) trait DwoCamera<const N: usize>:
    slam::factors::InverseDepthCamera<N> + Clone + Send + Sync + 'static
{
}

impl<C, const N: usize> DwoCamera<N> for C where
    C: slam::factors::InverseDepthCamera<N> + Clone + Send + Sync + 'static
{
}

impl<C: DwoCamera<N>, const N: usize> Stage<N> for Optimise<C> {
    type Job = ();
    type Output = Optimised<std::convert::Infallible>;

    fn run(&mut self, graph: &SharedGraph<N>, _: &(), out: &mut Vec<Self::Output>) {
        if graph.read().num_keyframes() < 2 {
            return;
        }
        for _attempt in 0..3 {
            match self.optimiser.optimise(graph, &self.camera) {
                Ok(s) => return out.push(Optimised::Stats(s)),
                Err(DwoError::Superseded { .. }) => continue,
                // A new map whose first keyframe failed: nothing to optimise around.
                Err(DwoError::NoReference) => return,
                Err(e) => return out.push(Optimised::Failed(e.to_string())),
            }
        }
    }
}

impl<C> Optimise<C> {
    /// The stage with `params` for `camera`.
    pub fn new(params: DwoParams, camera: C) -> Self {
        Optimise {
            optimiser: DoubleWindowOptimiser::new(params),
            camera,
        }
    }
}

/// Test faults for the back-end's workers (`crate::Options::faults`).
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq)]
pub struct Faults {
    /// For the double window optimisation's thread.
    pub optimiser: Option<Fault>,
    /// For the loop closer's thread.
    pub loops: Option<Fault>,
}

/// The back-end: the optimiser and the loop closer, each in a thread or inline.
pub(crate) struct Backend<L: Stage<N>, O: Stage<N>, const N: usize> {
    /// The keyframes' optimisation: the double window ([`Optimise`]), or the monocular
    /// keyframe's window BA (`crate::mono::window`).
    pub optimiser: Option<Worker<O, N>>,
    /// Large-scale loop closure (`None`: no vocabulary, or loops disabled).
    pub loops: Option<Worker<L, N>>,
}

impl<L: Stage<N>, O: Stage<N>, const N: usize> Backend<L, O, N> {
    /// A new keyframe for the back-end: the loop closer's job, then the optimiser's (inline:
    /// at once, in this order; threaded: queued, the optimiser woken).
    pub fn keyframe(&mut self, job: Option<L::Job>, optimise: Option<O::Job>) {
        if let (Some(loops), Some(job)) = (&mut self.loops, job) {
            loops.submit(job);
        }
        if let (Some(optimiser), Some(job)) = (&mut self.optimiser, optimise) {
            optimiser.submit(job);
        }
    }
}

/// What the sensor reads and writes of the session while it handles a frame.
pub(crate) struct Context<'a, L: Stage<N>, O: Stage<N>, const N: usize> {
    /// The configuration.
    pub config: &'a SystemConfig,
    /// The shared graph.
    pub graph: &'a Arc<SharedGraph<N>>,
    /// The keyframes' images.
    pub store: &'a Arc<RwLock<KeyframeStore>>,
    /// Where stage times go.
    pub timings: &'a mut StageTimings,
    /// The back-end.
    pub backend: &'a mut Backend<L, O, N>,
    /// Loops the keyframe pipeline closed (metric loops).
    pub loops: &'a mut Vec<LoopEvent>,
    /// Things that failed without stopping the run.
    pub warnings: &'a mut Vec<String>,
    /// Keyframes culled (`slam::mapping::culling`): the session moves what it kept relative
    /// to them onto their heirs.
    pub retired: &'a mut Vec<Retired>,
    /// The double window optimisations a sensor ran itself (the monocular exploration's).
    pub optimisations: &'a mut Vec<DwoStats>,
}

impl<L: Stage<N>, O: Stage<N>, const N: usize> Context<'_, L, O, N> {
    /// The frames keyframes `keyframe` and `old` were made from (`usize::MAX` if unknown).
    pub fn frames_of(&self, keyframe: KeyframeId, old: KeyframeId) -> (usize, usize) {
        let store = read_lock(self.store);
        let frame_of = |k: KeyframeId| store.get(k).map_or(usize::MAX, |i| i.frame_index);
        (frame_of(keyframe), frame_of(old))
    }
}

/// What a sensor's run ends with ([`Sensor::finish`]).
pub(crate) struct Finished<const N: usize> {
    /// The graph after the final optimisation (or loop correction).
    pub graph: SlamGraph<N>,
    /// Further graphs whose trajectories are worth comparing, by file stem (monocular: the
    /// loops corrected in SE(3)).
    pub alternatives: Vec<(&'static str, SlamGraph<N>)>,
}

/// A sensor's front-end, plugged into the session (`super::Session`).
pub(crate) trait Sensor<const N: usize>: Sized {
    /// A frame prepared for tracking.
    type Frame;
    /// What the sensor's optimiser stage gives back that only the sensor reads.
    type OptimiserData;
    /// The keyframes' optimisation stage.
    type Optimiser: Stage<N, Output = Optimised<Self::OptimiserData>>;
    /// What the sensor's loop stage gives back that only the sensor reads.
    type LoopData;
    /// The loop-closure stage.
    type Loops: Stage<N, Output = LoopOutput<Self::LoopData>>;

    /// Prepares `frame` (its index and timestamp are kept by the session).
    fn prepare(
        &mut self,
        ctx: &mut Context<'_, Self::Loops, Self::Optimiser, N>,
        frame: data::sequence::Frame,
    ) -> Result<Self::Frame, SystemError>;

    /// Tracks a frame in the map (making it a keyframe if it is one).
    fn track(
        &mut self,
        ctx: &mut Context<'_, Self::Loops, Self::Optimiser, N>,
        frame: &Self::Frame,
    ) -> Result<Step, SystemError>;

    /// Looks for a lost frame (or one waited out) in the map by appearance, and tracks it from
    /// there.
    fn relocalise(
        &mut self,
        ctx: &mut Context<'_, Self::Loops, Self::Optimiser, N>,
        frame: &Self::Frame,
    ) -> Result<Found, SystemError>;

    /// Whether a lost camera can still be found in the map (else a new map starts at once).
    fn can_recover(&self) -> bool;

    /// Starts a new map at a lost frame, lost for `lost_for` seconds; `None` where the frame
    /// cannot start one (a frame too dark to give the next frames anything to track).
    fn start_map(
        &mut self,
        ctx: &mut Context<'_, Self::Loops, Self::Optimiser, N>,
        frame: &Self::Frame,
        lost_for: f64,
    ) -> Result<Option<Step>, SystemError>;

    /// What the optimiser stage gave back for the sensor alone.
    fn optimised(
        &mut self,
        ctx: &mut Context<'_, Self::Loops, Self::Optimiser, N>,
        data: Self::OptimiserData,
    );

    /// What the loop stage gave back for the sensor alone.
    fn loop_data(
        &mut self,
        ctx: &mut Context<'_, Self::Loops, Self::Optimiser, N>,
        data: Self::LoopData,
    );

    /// Ends the run (the back-end has stopped): the final optimisation or loop correction.
    fn finish(
        &mut self,
        ctx: &mut Context<'_, Self::Loops, Self::Optimiser, N>,
        interrupted: bool,
    ) -> Result<Finished<N>, SystemError>;

    /// The graph as the run's result holds it.
    fn run_graph(graph: SlamGraph<N>) -> RunGraph;

    /// The keyframes' place-recognition features (what a map file stores of the databases),
    /// in id order.
    fn place_features(&self) -> Vec<(KeyframeId, KeyframeFeatures)>;

    /// Goes on in a map loaded from a file (the session's graph and keyframe store hold it
    /// already): its keyframes' `features` into the database; with `localise`, the frames are
    /// only localised in it, nothing is added.
    fn restore(
        &mut self,
        ctx: &mut Context<'_, Self::Loops, Self::Optimiser, N>,
        features: Vec<(KeyframeId, KeyframeFeatures)>,
        localise: bool,
    ) -> Result<(), SystemError>;
}

//! The monocular keyframe's window — its BA, or the double window (`mono.double_window`) — as
//! a back-end stage (thesis §6.5.2: the tracking thread hands a keyframe's optimisation to the
//! back-end and goes on).
//!
//! The exploration leaves a new keyframe's window to the sensor
//! (`MonoExplorer::defer_windows`): the job goes to the back-end's optimiser worker
//! ([`MonoWindow`]), which reads its problem from the shared graph under a read lock and
//! solves it with none (the double window writes its optimum back itself, under a write
//! lock: the tracking thread does not touch the map meanwhile), while the tracking thread
//! records the frame and follows the next frame's corner tracks (which need no map). Before
//! anything of the next frame reads the map — its tracks checked against the map points, the
//! points re-found, the exploration — or anything changes the map (a loop correction, a new
//! map, a relocalisation, the end of the run), the tracking thread waits for the answer and
//! writes it back ([`Windows::settle`], `MonoExplorer::apply_window`): the exploration
//! therefore sees the same map as if it had solved the window itself, and a deterministic run
//! (the worker inline) gives the same trajectory as one. A threaded run's keyframe frame is
//! reported at its pose before the window moved it (what the tracking knew then); its loop job
//! goes to the loop stage once the window is written back, so that the loop stage reads the
//! keyframe as optimised, as in a deterministic run.

use super::loops::{MonoLoopJob, MonoLoops};
use crate::session::backend::Stage;
use crate::session::{Context, Optimised};
use lie::Se3;
use slam::exploration::{MonoExplorer, SolvedWindow, WindowJob};
use slam::map::SharedGraph;
use std::time::Instant;

/// The context of the monocular sensor's calls.
pub(super) type Ctx<'a> = Context<'a, MonoLoops, MonoWindow, 2>;

/// The keyframe window stage: solves each job — a keyframe's BA, or the double window — on
/// the shared graph.
#[derive(Clone, Copy, Debug, Default)]
pub(crate) struct MonoWindow;

impl Stage<2> for MonoWindow {
    type Job = WindowJob;
    type Output = Optimised<SolvedWindow>;

    fn run(&mut self, graph: &SharedGraph<2>, job: &WindowJob, out: &mut Vec<Self::Output>) {
        out.push(match job.solve(graph) {
            Ok(solved) => Optimised::Sensor(solved),
            Err(e) => Optimised::Failed(format!(
                "keyframe {}'s window optimisation failed (not written back): {e}",
                job.keyframe().index()
            )),
        });
    }
}

/// The sensor's side of its keyframe windows in the back-end: whether one is being solved, and
/// the loop jobs waiting for it.
#[derive(Default)]
pub(super) struct Windows {
    /// A keyframe's window BA is being solved in the optimiser's thread.
    in_flight: bool,
    /// Loop jobs of keyframes whose window is being solved: given to the loop stage once it
    /// is written back.
    loop_jobs_waiting: Vec<MonoLoopJob>,
}

impl Windows {
    /// Hands keyframe window `job` to the back-end: inline (or with no worker), it is solved
    /// and written back into `explorer`'s map now — the keyframe's new pose; in the worker's
    /// thread, the answer is written back by [`Windows::settle`].
    pub fn solve(
        &mut self,
        ctx: &mut Ctx,
        explorer: &mut MonoExplorer,
        job: WindowJob,
    ) -> Option<Se3> {
        let mut outputs = Vec::new();
        match ctx.backend.optimiser.as_mut() {
            Some(worker) if worker.threaded() => {
                worker.submit(job);
                self.in_flight = true;
                return None;
            }
            Some(worker) => {
                worker.submit(job);
                outputs = worker.poll();
            }
            None => MonoWindow.run(ctx.graph, &job, &mut outputs),
        }
        take(ctx, Some(explorer), outputs)
    }

    /// Waits for the keyframe window the back-end is solving, if any, writes it back and gives
    /// the loop jobs that waited for it to the loop stage: the new pose of the last keyframe
    /// written back.
    pub fn settle(&mut self, ctx: &mut Ctx, explorer: Option<&mut MonoExplorer>) -> Option<Se3> {
        let optimiser = ctx.backend.optimiser.as_mut()?;
        let (threaded, t) = (optimiser.threaded(), Instant::now());
        let outputs = optimiser.wait();
        if threaded && !outputs.is_empty() {
            ctx.timings
                .record("keyframe: window, waited for", t.elapsed());
        }
        let pose = take(ctx, explorer, outputs);
        self.answered(ctx);
        pose
    }

    /// A window the session polled from the optimiser's thread: written back, the loop jobs
    /// that waited for it given to the loop stage.
    pub fn solved(
        &mut self,
        ctx: &mut Ctx,
        explorer: Option<&mut MonoExplorer>,
        solved: SolvedWindow,
    ) {
        take(ctx, explorer, vec![Optimised::Sensor(solved)]);
        self.answered(ctx);
    }

    /// A new keyframe's loop job for the loop stage: given now, or — its window being solved —
    /// once the window is written back, so that the loop stage reads the keyframe as its
    /// window BA leaves it.
    pub fn loop_job(&mut self, ctx: &mut Ctx, job: Option<MonoLoopJob>) {
        match job {
            Some(job) if self.in_flight => self.loop_jobs_waiting.push(job),
            job => ctx.backend.keyframe(job, None),
        }
    }

    /// The window in flight has been answered.
    fn answered(&mut self, ctx: &mut Ctx) {
        self.in_flight = false;
        for job in std::mem::take(&mut self.loop_jobs_waiting) {
            ctx.backend.keyframe(Some(job), None);
        }
    }
}

/// The optimiser's `outputs` written back into `explorer`'s map (windows) or recorded: the new
/// pose of the last keyframe written back.
fn take(
    ctx: &mut Ctx,
    mut explorer: Option<&mut MonoExplorer>,
    outputs: Vec<Optimised<SolvedWindow>>,
) -> Option<Se3> {
    let mut pose = None;
    for out in outputs {
        match out {
            Optimised::Sensor(solved) => match explorer.as_deref_mut() {
                Some(explorer) => pose = apply(ctx, explorer, solved).or(pose),
                None => ctx.warnings.push(format!(
                    "keyframe {}'s window BA came back with no exploration to take it",
                    solved.keyframe().index()
                )),
            },
            Optimised::Failed(e) => ctx.warnings.push(e),
            Optimised::Stats(s) => ctx.optimisations.push(s),
        }
    }
    pose
}

/// Writes a solved window back (`MonoExplorer::apply_window`): the keyframe's new pose, `None`
/// if it was stale or could not be written (a warning).
fn apply(ctx: &mut Ctx, explorer: &mut MonoExplorer, solved: SolvedWindow) -> Option<Se3> {
    let t = Instant::now();
    let (k, solve) = (solved.keyframe(), solved.time);
    let threaded = ctx.backend.optimiser.as_ref().is_some_and(|w| w.threaded());
    let stats = solved.double_window_stats();
    let applied = explorer.apply_window(&mut ctx.graph.write(), solved);
    let (alone, in_thread, written) = if stats.is_some() {
        (
            "keyframe: double window",
            "keyframe: double window in its thread",
            "keyframe: double window, written back",
        )
    } else {
        (
            "keyframe: window BA",
            "keyframe: window BA in its thread",
            "keyframe: window BA, written back",
        )
    };
    if threaded {
        ctx.timings.record(in_thread, solve);
        ctx.timings.record(written, t.elapsed());
    } else {
        ctx.timings.record(alone, solve + t.elapsed());
    }
    ctx.optimisations.extend(stats);
    match applied {
        Ok(Some(pose)) => Some(pose),
        Ok(None) => {
            ctx.warnings.push(format!(
                "keyframe {}'s window BA was stale (its keyframes moved while it was solved): \
                 not written back",
                k.index()
            ));
            None
        }
        Err(e) => {
            ctx.warnings.push(format!(
                "keyframe {}'s window BA could not be written back: {e}",
                k.index()
            ));
            None
        }
    }
}

//! The back-end's workers (thesis §6.5.2): a stage of work fed by the tracking thread — double
//! window optimisation, loop closure — that runs in a thread of its own ([`Mode::Threaded`])
//! or inline, in the calling thread, at the moment its job is given ([`Mode::Deterministic`]).
//!
//! Jobs go to the thread through a bounded queue and its outputs come back through a channel,
//! which the tracking thread drains ([`Worker::poll`]); nothing is shared in vectors behind
//! locks. A worker that dies — a panic in its stage, or a thread that ends — never loses the
//! run: the next time the tracking thread talks to it, it finds the channel disconnected, joins
//! the thread (a panic becomes a warning with its message), and runs the stage inline from then
//! on, starting with the jobs the thread had not answered. A stage's state lives in the stage;
//! a stage lost in a panic is made again ([`Worker::new`]'s `make`).
//!
//! [`Mode::Threaded`]: crate::Mode::Threaded
//! [`Mode::Deterministic`]: crate::Mode::Deterministic

use slam::map::SharedGraph;
use slam::map::shared::{record_lock_waits, take_lock_waits};
use std::collections::VecDeque;
use std::sync::Arc;
use std::sync::mpsc::{Receiver, SyncSender, TryRecvError, TrySendError, sync_channel};
use std::thread::JoinHandle;
use std::time::Duration;

/// A stage of work on the shared graph.
pub(crate) trait Stage<const N: usize>: Send + 'static {
    /// One piece of work.
    type Job: Clone + Send + 'static;
    /// What a job gives back (results, errors as warnings, timings).
    type Output: Send + 'static;
    /// Does `job`, appending what it gives to `out`.
    fn run(&mut self, graph: &SharedGraph<N>, job: &Self::Job, out: &mut Vec<Self::Output>);
}

/// A fault a test makes a worker thread suffer after it has answered `after` jobs.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum Fault {
    /// The stage panics at its next job.
    Panic {
        /// Jobs answered first.
        after: usize,
    },
    /// The thread ends without a word (its channels disconnect).
    Disconnect {
        /// Jobs answered first.
        after: usize,
    },
}

/// A job numbered in the order given.
type Numbered<J> = (u64, J);

/// A thread's answer to job `number`: its outputs and the waits of the locks it took.
type Answer<O> = (u64, Vec<O>, Vec<Duration>);

enum Runner<S: Stage<N>, const N: usize> {
    Inline(Box<S>),
    Thread {
        jobs: SyncSender<Numbered<S::Job>>,
        outputs: Receiver<Answer<S::Output>>,
        handle: JoinHandle<S>,
    },
    /// Only while changing from one to the other.
    Changing,
}

/// A thread's lock waits over a run (`slam::map::shared::record_lock_waits`): the tracking
/// thread's per frame, a back-end thread's per job.
#[derive(Default)]
pub(crate) struct LockWaitLog {
    /// Each lock's wait, nanoseconds.
    waits: Vec<u32>,
    /// Frames (jobs) whose locks waited more than a millisecond together.
    frames_over_1ms: usize,
}

impl LockWaitLog {
    /// The waits of one frame (job).
    pub fn frame(&mut self, waits: Vec<Duration>) {
        let total: Duration = waits.iter().sum();
        if total > Duration::from_millis(1) {
            self.frames_over_1ms += 1;
        }
        self.waits.extend(
            waits
                .into_iter()
                .map(|w| u32::try_from(w.as_nanos()).unwrap_or(u32::MAX)),
        );
    }

    /// Median, 99th percentile and longest wait.
    pub fn summary(&self) -> crate::result::LockWaits {
        let mut sorted = self.waits.clone();
        sorted.sort_unstable();
        let at = |q: f64| {
            let i = ((sorted.len() as f64 * q).ceil() as usize).clamp(1, sorted.len().max(1)) - 1;
            Duration::from_nanos(sorted.get(i).copied().unwrap_or(0).into())
        };
        crate::result::LockWaits {
            count: sorted.len(),
            median: at(0.5),
            p99: at(0.99),
            max: Duration::from_nanos(sorted.last().copied().unwrap_or(0).into()),
            frames_over_1ms: self.frames_over_1ms,
        }
    }
}

/// A stage run in its own thread or inline (see the [module docs](self)).
pub(crate) struct Worker<S: Stage<N>, const N: usize> {
    name: &'static str,
    graph: Arc<SharedGraph<N>>,
    runner: Runner<S, N>,
    make: Box<dyn Fn() -> S + Send>,
    /// Jobs given to the thread and not answered yet, oldest first.
    pending: VecDeque<Numbered<S::Job>>,
    next: u64,
    /// Outputs of inline jobs not polled yet.
    ready: Vec<S::Output>,
    /// A full queue means a job is waiting anyway (a wake-up): the new one is dropped.
    coalesce: bool,
    /// Jobs that found the queue full, oldest first, sent as the thread makes room (a job
    /// that must not be lost, a keyframe for the loop closer: dropped, it would be missing
    /// from the place recognition's database for good).
    waiting: VecDeque<Numbered<S::Job>>,
    /// Jobs that found the queue full and waited (not dropped), and the most that waited at
    /// once.
    pub queue_full: usize,
    pub max_waiting: usize,
    /// What became of the thread, if it died.
    pub deaths: Vec<String>,
    /// The thread's lock waits, per job (inline, they are the calling thread's).
    lock_waits: LockWaitLog,
}

impl<S: Stage<N>, const N: usize> Worker<S, N> {
    /// A worker named `name` running `stage` on `graph`: in a thread of its own with a queue of
    /// `queue` jobs (`threaded`), or inline. `make` makes the stage again if a thread dies with
    /// it. With `coalesce`, a job that finds the queue full is dropped without being counted
    /// (a wake-up: the job waiting will see what this one would have). `fault`: a test's
    /// fault for the thread.
    #[allow(clippy::too_many_arguments)]
    pub fn new(
        name: &'static str,
        graph: Arc<SharedGraph<N>>,
        stage: S,
        make: Box<dyn Fn() -> S + Send>,
        threaded: bool,
        queue: usize,
        coalesce: bool,
        fault: Option<Fault>,
    ) -> Self {
        let runner = if threaded {
            spawn(name, graph.clone(), stage, queue, fault)
        } else {
            Runner::Inline(Box::new(stage))
        };
        Worker {
            name,
            graph,
            runner,
            make,
            pending: VecDeque::new(),
            next: 0,
            ready: Vec::new(),
            coalesce,
            waiting: VecDeque::new(),
            queue_full: 0,
            max_waiting: 0,
            deaths: Vec::new(),
            lock_waits: LockWaitLog::default(),
        }
    }

    /// The worker's name (its thread's).
    pub fn name(&self) -> &'static str {
        self.name
    }

    /// Whether the stage runs in its own thread (it may have died since: then inline).
    pub fn threaded(&self) -> bool {
        matches!(self.runner, Runner::Thread { .. })
    }

    /// A sender of jobs to the thread from another thread (the loop closer wakes the
    /// optimiser after closing a loop); `None` inline. Its jobs are not replayed if the thread
    /// dies.
    pub fn sender(&self) -> Option<SyncSender<Numbered<S::Job>>> {
        match &self.runner {
            Runner::Thread { jobs, .. } => Some(jobs.clone()),
            _ => None,
        }
    }

    /// Gives the worker `job`: queued for the thread, or run now. A job that finds the queue
    /// full waits in the calling thread, without blocking it, and goes to the thread as the
    /// thread makes room ([`Worker::poll`]), after those that waited before it (with
    /// `coalesce`, it is dropped).
    pub fn submit(&mut self, job: S::Job) {
        let number = self.next;
        self.next += 1;
        if !self.threaded() {
            self.run_inline(&job);
            return;
        }
        let before = self.waiting.len();
        self.waiting.push_back((number, job));
        self.send_waiting(false);
        if self.coalesce {
            // A wake-up that found the queue full: the one queued sees what it would have.
            self.waiting.clear();
        } else if self.waiting.len() > before {
            self.queue_full += 1;
            self.max_waiting = self.max_waiting.max(self.waiting.len());
        }
    }

    /// Sends the waiting jobs, oldest first, while the queue has room — or, with `wait`, all
    /// of them, taking the thread's answers while the queue is full, so that it never waits
    /// on a full channel of answers (a thread that has ended: it falls back, and they run
    /// inline).
    fn send_waiting(&mut self, wait: bool) {
        while let Some((number, job)) = self.waiting.front() {
            let Runner::Thread { jobs, handle, .. } = &self.runner else {
                break;
            };
            let (sent, finished) = (jobs.try_send((*number, job.clone())), handle.is_finished());
            match sent {
                Ok(()) => {
                    let sent = self.waiting.pop_front().expect("the front");
                    self.pending.push_back(sent);
                }
                Err(TrySendError::Full(_)) if wait => match self.next_answer(true) {
                    Ok(answer) => self.take(answer),
                    Err(_) => break,
                },
                // A thread that has ended cannot empty its queue.
                Err(TrySendError::Full(_)) if !finished => break,
                Err(_) => {
                    self.fall_back(false);
                    break;
                }
            }
        }
    }

    /// The thread's next answer (`block`: waiting for it); `Disconnected` inline or once the
    /// thread has ended.
    fn next_answer(&self, block: bool) -> Result<Answer<S::Output>, TryRecvError> {
        let Runner::Thread { outputs, .. } = &self.runner else {
            return Err(TryRecvError::Disconnected);
        };
        if block {
            outputs.recv().map_err(|_| TryRecvError::Disconnected)
        } else {
            outputs.try_recv()
        }
    }

    /// The thread's answer to a job: it and the jobs before it are no longer pending, its
    /// outputs are ready, its lock waits recorded.
    fn take(&mut self, (number, out, waits): Answer<S::Output>) {
        while self.pending.front().is_some_and(|(n, _)| *n <= number) {
            self.pending.pop_front();
        }
        self.ready.extend(out);
        self.lock_waits.frame(waits);
    }

    fn run_inline(&mut self, job: &S::Job) {
        if let Runner::Inline(stage) = &mut self.runner {
            stage.run(&self.graph, job, &mut self.ready);
        }
    }

    /// The outputs so far (what inline jobs gave, what the thread sent back).
    pub fn poll(&mut self) -> Vec<S::Output> {
        let mut disconnected = false;
        while self.threaded() {
            match self.next_answer(false) {
                Ok(answer) => self.take(answer),
                Err(TryRecvError::Empty) => break,
                Err(TryRecvError::Disconnected) => {
                    disconnected = true;
                    break;
                }
            }
        }
        if disconnected {
            self.fall_back(false);
        } else {
            self.send_waiting(false);
        }
        std::mem::take(&mut self.ready)
    }

    /// Waits until every job given so far is answered (a thread that died meanwhile: its
    /// jobs run inline) and returns the outputs so far.
    pub fn wait(&mut self) -> Vec<S::Output> {
        self.send_waiting(true);
        while !self.pending.is_empty() && self.threaded() {
            match self.next_answer(true) {
                Ok(answer) => self.take(answer),
                Err(_) => self.fall_back(false),
            }
        }
        std::mem::take(&mut self.ready)
    }

    /// Ends the worker: a thread answers every job queued and ends (or died: its jobs then
    /// run inline). Returns the last outputs, the stage, what became of the thread and the
    /// waits of the locks it took.
    pub fn finish(mut self) -> (Vec<S::Output>, S, Vec<String>, LockWaitLog) {
        // The jobs still waiting go to the thread first.
        self.send_waiting(true);
        if let Runner::Thread { jobs, .. } = &mut self.runner {
            // Dropping our sender ends the thread once the queue is empty (a clone held by
            // another worker's thread is gone once that worker has finished).
            let (closed, _) = sync_channel(1);
            drop(std::mem::replace(jobs, closed));
        }
        while let Ok(answer) = self.next_answer(true) {
            self.take(answer);
        }
        if self.threaded() {
            self.fall_back(true);
        }
        let ready = std::mem::take(&mut self.ready);
        let stage = match std::mem::replace(&mut self.runner, Runner::Changing) {
            Runner::Inline(stage) => *stage,
            _ => (self.make)(),
        };
        (
            ready,
            stage,
            std::mem::take(&mut self.deaths),
            std::mem::take(&mut self.lock_waits),
        )
    }

    /// The thread has ended (`expected`: at the end of the run, else on its own): joins it
    /// and runs the stage inline from now on — the thread's own if it ended cleanly, a new one
    /// if it panicked — starting with the jobs it had not answered. A thread that ended on its
    /// own or panicked leaves a warning.
    fn fall_back(&mut self, expected: bool) {
        let Runner::Thread { handle, .. } = std::mem::replace(&mut self.runner, Runner::Changing)
        else {
            return;
        };
        let stage = match handle.join() {
            Ok(stage) => {
                if !expected || !self.pending.is_empty() {
                    self.deaths.push(format!(
                        "the {} thread ended before the run did, {} jobs unanswered: they ran \
                         in the tracking thread, as did every job after",
                        self.name,
                        self.pending.len()
                    ));
                }
                stage
            }
            Err(panic) => {
                let why = panic
                    .downcast_ref::<&str>()
                    .map(|s| s.to_string())
                    .or_else(|| panic.downcast_ref::<String>().cloned())
                    .unwrap_or_else(|| "no message".into());
                self.deaths.push(format!(
                    "the {} thread panicked ({why}): its work ran in the tracking thread from \
                     then on, its {} unanswered jobs first",
                    self.name,
                    self.pending.len()
                ));
                (self.make)()
            }
        };
        self.runner = Runner::Inline(Box::new(stage));
        let unanswered = std::mem::take(&mut self.pending);
        let waiting = std::mem::take(&mut self.waiting);
        for (_, job) in unanswered.into_iter().chain(waiting) {
            self.run_inline(&job);
        }
    }
}

impl<S: Stage<N>, const N: usize> Drop for Worker<S, N> {
    fn drop(&mut self) {
        // A worker dropped without `finish` (the system dropped mid-run): let its thread end.
        if let Runner::Thread { jobs, .. } = &mut self.runner {
            let (closed, _) = sync_channel(1);
            drop(std::mem::replace(jobs, closed));
        }
    }
}

fn spawn<S: Stage<N>, const N: usize>(
    name: &'static str,
    graph: Arc<SharedGraph<N>>,
    mut stage: S,
    queue: usize,
    fault: Option<Fault>,
) -> Runner<S, N> {
    let (jobs, inbox) = sync_channel::<Numbered<S::Job>>(queue.max(1));
    let (outbox, outputs) = sync_channel::<Answer<S::Output>>(queue.max(1) + 64);
    let handle = std::thread::Builder::new()
        .name(name.into())
        .spawn(move || {
            // The waits for the graph and the databases this thread shares with the tracking
            // thread, per job (`summary.json`: `backend_lock_waits`).
            record_lock_waits(true);
            let mut answered = 0;
            while let Ok((number, job)) = inbox.recv() {
                match fault {
                    Some(Fault::Panic { after }) if answered == after => {
                        panic!("a fault injected after {after} jobs")
                    }
                    Some(Fault::Disconnect { after }) if answered == after => break,
                    _ => {}
                }
                let mut out = Vec::new();
                stage.run(&graph, &job, &mut out);
                answered += 1;
                if outbox.send((number, out, take_lock_waits())).is_err() {
                    break;
                }
            }
            stage
        })
        .expect("a thread can be spawned");
    Runner::Thread {
        jobs,
        outputs,
        handle,
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    /// Adds its jobs up; a job of 0 outputs nothing.
    struct Sum(u64);

    impl Stage<3> for Sum {
        type Job = u64;
        type Output = u64;
        fn run(&mut self, _: &SharedGraph<3>, job: &u64, out: &mut Vec<u64>) {
            self.0 += job;
            if *job > 0 {
                out.push(self.0);
            }
        }
    }

    /// A worker with room in its queue for every job of the tests (a thread that panics may
    /// take milliseconds to end while jobs arrive).
    fn worker(threaded: bool, fault: Option<Fault>) -> Worker<Sum, 3> {
        Worker::new(
            "sum",
            Arc::new(SharedGraph::default()),
            Sum(0),
            Box::new(|| Sum(1000)),
            threaded,
            16,
            false,
            fault,
        )
    }

    fn run(mut w: Worker<Sum, 3>, jobs: u64) -> (Vec<u64>, u64, Vec<String>) {
        let mut out = Vec::new();
        for j in 1..=jobs {
            w.submit(j);
            if w.threaded() {
                std::thread::sleep(std::time::Duration::from_millis(2));
            }
            out.extend(w.poll());
        }
        let (last, stage, deaths, _) = w.finish();
        out.extend(last);
        (out, stage.0, deaths)
    }

    #[test]
    fn a_worker_gives_the_same_outputs_in_its_thread_and_inline() {
        let (inline, sum, deaths) = run(worker(false, None), 10);
        assert_eq!(inline, vec![1, 3, 6, 10, 15, 21, 28, 36, 45, 55]);
        assert_eq!((sum, deaths.len()), (55, 0));
        let (threaded, sum, deaths) = run(worker(true, None), 10);
        assert_eq!((threaded, sum, deaths.len()), (inline, 55, 0));
    }

    #[test]
    fn a_worker_that_panics_falls_back_inline_with_every_job_answered() {
        let (out, sum, deaths) = run(worker(true, Some(Fault::Panic { after: 3 })), 10);
        // Jobs 1–3 in the thread; the stage died with them, the new one starts at 1000 and
        // answers jobs 4–10.
        assert_eq!(out.len(), 10, "{out:?}");
        assert_eq!(&out[..3], &[1, 3, 6]);
        assert_eq!(sum, 1000 + (4..=10).sum::<u64>());
        assert_eq!(deaths.len(), 1);
        assert!(deaths[0].contains("panicked"), "{deaths:?}");
    }

    #[test]
    fn a_worker_whose_thread_ends_falls_back_inline_with_its_own_stage() {
        let (out, sum, deaths) = run(worker(true, Some(Fault::Disconnect { after: 2 })), 10);
        assert_eq!(out.len(), 10, "{out:?}");
        // The thread's stage came back with it: the sums go on from job 2's.
        assert_eq!(sum, 55);
        assert_eq!(out, vec![1, 3, 6, 10, 15, 21, 28, 36, 45, 55]);
        assert_eq!(deaths.len(), 1, "{deaths:?}");
        assert!(deaths[0].contains("ended before the run did"), "{deaths:?}");
    }

    /// [`Sum`], taking a millisecond per job.
    struct SlowSum(Sum);

    impl Stage<3> for SlowSum {
        type Job = u64;
        type Output = u64;
        fn run(&mut self, graph: &SharedGraph<3>, job: &u64, out: &mut Vec<u64>) {
            std::thread::sleep(std::time::Duration::from_millis(1));
            self.0.run(graph, job, out);
        }
    }

    /// A [`SlowSum`] in its thread with a queue of `queue` jobs.
    fn slow_worker(queue: usize, fault: Option<Fault>) -> Worker<SlowSum, 3> {
        Worker::new(
            "slow sum",
            Arc::new(SharedGraph::default()),
            SlowSum(Sum(0)),
            Box::new(|| SlowSum(Sum(0))),
            true,
            queue,
            false,
            fault,
        )
    }

    /// Waiting answers every job given so far, in order — also when the thread dies: its
    /// jobs then run inline.
    #[test]
    fn waiting_answers_every_job_given_even_when_the_thread_dies() {
        for fault in [
            None,
            Some(Fault::Panic { after: 3 }),
            Some(Fault::Disconnect { after: 3 }),
        ] {
            let mut w = slow_worker(1, fault);
            for j in 1..=6u64 {
                w.submit(j);
                let got = w.wait();
                assert_eq!(got.len(), 1, "job {j}, {fault:?}");
                if fault.is_none() || j <= 3 {
                    assert_eq!(got, vec![j * (j + 1) / 2], "{fault:?}");
                }
            }
            assert_eq!(w.threaded(), fault.is_none());
            let (last, _, deaths, _) = w.finish();
            assert!(last.is_empty());
            assert_eq!(deaths.len(), usize::from(fault.is_some()), "{deaths:?}");
        }
    }

    /// Jobs given faster than the thread answers them wait for room, none is dropped, and the
    /// answers come in order — also with more waiting than the channel of answers holds, and
    /// when the thread dies while they wait.
    #[test]
    fn jobs_that_find_the_queue_full_wait_and_none_is_lost() {
        for fault in [None, Some(Fault::Panic { after: 50 })] {
            let mut w = slow_worker(2, fault);
            let mut out = Vec::new();
            for j in 1..=200 {
                w.submit(j);
                out.extend(w.poll());
            }
            assert!(
                w.queue_full > 100 && w.max_waiting > 66,
                "{} {}",
                w.queue_full,
                w.max_waiting
            );
            let (last, stage, deaths, _) = w.finish();
            out.extend(last);
            assert_eq!(out.len(), 200, "{fault:?}");
            match fault {
                None => {
                    assert_eq!(
                        out,
                        (1..=200u64).map(|n| n * (n + 1) / 2).collect::<Vec<_>>()
                    );
                    assert_eq!((stage.0.0, deaths.len()), ((1..=200).sum::<u64>(), 0));
                }
                Some(_) => {
                    // The stage died with jobs 1–50; the new one answered jobs 51–200.
                    assert_eq!(stage.0.0, (51..=200).sum::<u64>());
                    assert_eq!(deaths.len(), 1, "{deaths:?}");
                }
            }
        }
    }
}

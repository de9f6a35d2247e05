//! The prefetching reader: frames decoded on their own thread, ahead of the consumer, through a
//! bounded queue (`std::sync::mpsc::sync_channel`: one producer, one consumer, blocking when
//! full, no dependency needed), so that reading never stalls tracking and memory stays bounded.

use super::decode::Decoder;
use super::types::{BadFramePolicy, Frame, FrameError, FrameSpec, SequenceInfo};
use std::sync::Arc;
use std::sync::atomic::{AtomicBool, AtomicUsize, Ordering};
use std::sync::mpsc::{Receiver, SyncSender, sync_channel};
use std::thread::JoinHandle;

/// Frames decoded ahead by default. A decode takes 3–10 ms (a VGA JPEG + 16-bit PNG, an EuRoC
/// stereo pair with rectification), a frame arrives every 33–100 ms; eight frames absorb a
/// stall of the disk or the decoder of a quarter second at 30 Hz while holding ≤ 15 MB of VGA
/// RGB-D pixels (≈ 6 MB of EuRoC stereo).
pub const DEFAULT_QUEUE_LENGTH: usize = 8;

/// Counters of a [`Reader`], for monitoring and tests.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub struct ReaderStats {
    /// Frames (or errors) the decoding thread has produced.
    pub decoded: usize,
    /// Frames (or errors) handed to the consumer.
    pub delivered: usize,
    /// The queue's capacity.
    pub queue_length: usize,
}

#[derive(Default)]
struct Counters {
    decoded: AtomicUsize,
    stop: AtomicBool,
}

/// Frames in time order, decoded ahead on a thread: an iterator of
/// `Result<Frame, FrameError>`.
///
/// * A bad frame arrives as `Err(FrameError)` naming the frame and the file. Under
///   [`BadFramePolicy::Stop`] it is the last item; under [`BadFramePolicy::Skip`] the reader goes
///   on with the next frame (the consumer reports the error as a warning).
/// * At most `queue_length` decoded frames wait in the queue, plus the one being decoded.
/// * Dropping the reader stops the thread cleanly (it notices at its next frame or its next
///   send, and is joined).
pub struct Reader {
    info: SequenceInfo,
    receiver: Option<Receiver<Result<Frame, FrameError>>>,
    thread: Option<JoinHandle<()>>,
    counters: Arc<Counters>,
    delivered: usize,
    queue_length: usize,
}

impl Reader {
    pub(crate) fn start(
        info: SequenceInfo,
        frames: Vec<FrameSpec>,
        decoder: Arc<Decoder>,
        policy: BadFramePolicy,
        queue_length: usize,
    ) -> Reader {
        let queue_length = queue_length.max(1);
        let (sender, receiver) = sync_channel(queue_length);
        let counters = Arc::new(Counters::default());
        let c = counters.clone();
        let thread = std::thread::Builder::new()
            .name("dwslam-reader".into())
            .spawn(move || produce(frames, decoder, policy, sender, c))
            .expect("spawning the reader thread");
        Reader {
            info,
            receiver: Some(receiver),
            thread: Some(thread),
            counters,
            delivered: 0,
            queue_length,
        }
    }

    /// What the sequence is.
    pub fn info(&self) -> &SequenceInfo {
        &self.info
    }

    /// How far ahead the decoder is.
    pub fn stats(&self) -> ReaderStats {
        ReaderStats {
            decoded: self.counters.decoded.load(Ordering::Acquire),
            delivered: self.delivered,
            queue_length: self.queue_length,
        }
    }
}

fn produce(
    frames: Vec<FrameSpec>,
    decoder: Arc<Decoder>,
    policy: BadFramePolicy,
    sender: SyncSender<Result<Frame, FrameError>>,
    counters: Arc<Counters>,
) {
    for (index, spec) in frames.iter().enumerate() {
        if counters.stop.load(Ordering::Acquire) {
            return;
        }
        let item = decoder.decode(index, spec);
        let bad = item.is_err();
        counters.decoded.fetch_add(1, Ordering::AcqRel);
        if sender.send(item).is_err() {
            return; // the consumer dropped the reader
        }
        if bad && policy == BadFramePolicy::Stop {
            return;
        }
    }
}

impl Iterator for Reader {
    type Item = Result<Frame, FrameError>;

    fn next(&mut self) -> Option<Self::Item> {
        let item = self.receiver.as_ref()?.recv().ok()?;
        self.delivered += 1;
        Some(item)
    }
}

impl Drop for Reader {
    fn drop(&mut self) {
        self.counters.stop.store(true, Ordering::Release);
        // Dropping the receiver makes a blocked `send` fail, so the thread ends promptly.
        drop(self.receiver.take());
        if let Some(t) = self.thread.take() {
            let _ = t.join();
        }
    }
}

//! The prefetching reader keeps ahead of a slow consumer with bounded memory: the 1000
//! 7-Scenes frames (JPEG colour + 16-bit PNG depth) read while the consumer sleeps 10 ms per
//! frame keep the consumer waiting for frames no more than 5 % of its sleeps, and no more than
//! `queue_length + 1` decoded frames ever wait (the queue plus the one being handed over).
//! Alone in its test binary, so that no other test competes for the cores while it is timed.
//!
//! The time the consumer waits in `next()` is what "keeps ahead" means; the whole run against
//! the nominal sleeps also counted how far each `sleep` overshot its 10 ms, which the reader
//! does not control (a run on a busy machine: 1.056 × the sleeps, with the reader ahead).

use data::paths::require;
use data::sequence::{OpenOptions, Sequence};
use std::time::{Duration, Instant};

fn rss_bytes() -> Option<usize> {
    let s = std::fs::read_to_string("/proc/self/statm").ok()?;
    let pages: usize = s.split_whitespace().nth(1)?.parse().ok()?;
    Some(pages * 4096)
}

#[test]
fn reader_keeps_ahead_of_a_10ms_consumer_with_bounded_memory() {
    let Some(dir) = require("seven_scenes_redkitchen_1000") else {
        return;
    };
    let queue = 8;
    let seq = Sequence::open(&dir, &OpenOptions::default()).unwrap();
    let n = seq.len();
    assert_eq!(n, 1000);
    let sleep = Duration::from_millis(10);
    let start = Instant::now();
    let mut reader = seq.into_reader(queue);
    let rss0 = rss_bytes();
    let (mut max_ahead, mut frame_bytes, mut max_rss, mut count) = (0, 0, 0, 0);
    let mut waited = Duration::ZERO;
    loop {
        let t = Instant::now();
        let Some(item) = reader.next() else { break };
        waited += t.elapsed();
        let frame = item.unwrap();
        frame_bytes = frame_bytes.max(frame.pixel_bytes());
        let s = reader.stats();
        max_ahead = max_ahead.max(s.decoded - s.delivered);
        max_rss = max_rss.max(rss_bytes().unwrap_or(0));
        count += 1;
        std::thread::sleep(sleep); // the consumer's work
    }
    let elapsed = start.elapsed();
    let sleeps = sleep * n as u32;
    let ratio = elapsed.as_secs_f64() / sleeps.as_secs_f64();
    let wait_ratio = waited.as_secs_f64() / sleeps.as_secs_f64();
    let growth = max_rss.saturating_sub(rss0.unwrap_or(0));
    eprintln!(
        "{count} frames in {elapsed:.2?} against {sleeps:.2?} of sleeps (ratio {ratio:.4}), waiting {waited:.2?} for frames ({wait_ratio:.4}); at most {max_ahead} frames decoded ahead (queue {queue}); frame {frame_bytes} B; RSS growth {growth} B"
    );
    assert_eq!(count, n);
    assert!(
        wait_ratio <= 0.05,
        "the consumer waited {wait_ratio:.4} × its sleeps for frames"
    );
    assert!(
        max_ahead <= queue + 1,
        "{max_ahead} frames ahead with a queue of {queue}"
    );
    // Memory: the frames in flight (queue + the one decoding + the consumer's) bound the growth;
    // all 1000 frames would be ~1.8 GB.
    assert!(
        growth < (queue + 3) * frame_bytes + (64 << 20),
        "RSS grew by {growth} B"
    );
}

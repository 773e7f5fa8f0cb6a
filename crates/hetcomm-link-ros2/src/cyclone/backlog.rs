//! Frames written on a listener's thread that Cyclone DDS would have throttled: they wait here
//! for a thread of the link's own, which may wait for the acknowledgements that the listener's
//! thread reads (see "Delivering on the receive thread" in the [module docs](super)).

use parking_lot::{Condvar, Mutex};
use std::collections::VecDeque;

use hetcomm_core::SystemId;

/// The most frames, and bytes, the backlog holds; beyond, a listener's write is refused as
/// congested (the router then retries an acknowledged send, or reports it failed).
pub const MAX_FRAMES: usize = 4096;
/// See [`MAX_FRAMES`].
pub const MAX_BYTES: usize = 64 << 20;

#[derive(Default)]
struct Queue {
    frames: VecDeque<(SystemId, Vec<u8>)>,
    bytes: usize,
    closed: bool,
}

/// A bounded FIFO of frames for the backlog thread.
#[derive(Default)]
pub struct Backlog {
    queue: Mutex<Queue>,
    ready: Condvar,
}

impl Backlog {
    /// Whether frames wait (a later frame of a listener's thread must queue behind them).
    pub fn is_empty(&self) -> bool {
        self.lock().frames.is_empty()
    }

    /// Bytes waiting.
    pub fn bytes(&self) -> usize {
        self.lock().bytes
    }

    /// Queues a copy of the frame made of `parts` for `to`; false if the backlog is full.
    pub fn push(&self, to: SystemId, parts: &[&[u8]]) -> bool {
        let len: usize = parts.iter().map(|p| p.len()).sum();
        let mut q = self.lock();
        if q.frames.len() >= MAX_FRAMES || q.bytes + len > MAX_BYTES {
            return false;
        }
        q.frames.push_back((to, parts.concat()));
        q.bytes += len;
        drop(q);
        self.ready.notify_one();
        true
    }

    /// The next frame, waiting for one; None once closed.
    pub fn pop(&self) -> Option<(SystemId, Vec<u8>)> {
        let mut q = self.lock();
        loop {
            if q.closed {
                return None;
            }
            if let Some((to, frame)) = q.frames.pop_front() {
                q.bytes -= frame.len();
                return Some((to, frame));
            }
            self.ready.wait(&mut q);
        }
    }

    /// Ends [`pop`](Backlog::pop) calls; returns how many frames were still waiting.
    pub fn close(&self) -> usize {
        let mut q = self.lock();
        q.closed = true;
        let left = q.frames.len();
        q.frames.clear();
        drop(q);
        self.ready.notify_all();
        left
    }

    fn lock(&self) -> parking_lot::MutexGuard<'_, Queue> {
        self.queue.lock()
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn frames_leave_in_order_and_the_bounds_hold() {
        let b = Backlog::default();
        assert!(b.is_empty());
        assert!(b.push(SystemId(1), &[b"ab", b"c"]));
        assert!(b.push(SystemId(2), &[b"d"]));
        assert!(!b.is_empty());
        assert_eq!(b.pop(), Some((SystemId(1), b"abc".to_vec())));
        assert_eq!(b.pop(), Some((SystemId(2), b"d".to_vec())));
        let big = vec![0u8; MAX_BYTES];
        assert!(b.push(SystemId(1), &[&big]));
        assert!(!b.push(SystemId(1), &[b"x"]), "over the byte bound");
        assert_eq!(b.close(), 1);
        assert_eq!(b.pop(), None);
    }
}

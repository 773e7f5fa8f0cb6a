//! Helpers every link of this crate shares: lock handling, atomic counters and the writer
//! thread that writes frames behind a streaming sender.
//!
//! Each link keeps its own counter struct (`UdpCounters`, `StreamCounters`) and its own
//! per-peer state (`UdpPeer`, `PeerSlot` of the stream layer): their fields differ, only these
//! operations on them are common.

use parking_lot::{Condvar, Mutex, MutexGuard};
use std::collections::VecDeque;
use std::sync::atomic::{AtomicU64, Ordering};
use std::sync::Arc;
use std::thread::JoinHandle;
use std::time::{Duration, Instant};

use hetcomm_core::SystemId;

/// A sender that comes back to the same peer within this long after its previous given-away
/// frame is streaming: its frames are written behind it. A sender that waits for answers
/// (a round trip takes longer) keeps writing on its own thread, without a hand-off.
pub(crate) const STREAMING_GAP: Duration = Duration::from_micros(20);

/// Which frames given away with `Link::send_owned` (the security layer's sealed frames of
/// 16 KiB and more) a link's writer thread writes while the caller prepares its next frame
/// ("Write-behind" in the [`udp`](crate::udp) and [`stream`](crate::stream) module docs);
/// the others are written on the caller's thread.
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq)]
pub enum WriteBehind {
    /// Those of a sender that streams: it came back to the same peer within 20 µs of its
    /// previous given-away frame's return. A sender that waits for answers between frames
    /// keeps writing on its own thread, so its latency has no hand-off in it. Where preparing
    /// a frame takes longer than 20 µs (a slow CPU's seal of a large frame, a debug build),
    /// a streaming sender is not recognised and writes on its own thread. The default.
    #[default]
    Streaming,
    /// Every one: for a sender known to stream whatever its pace, with a core to spare.
    Always,
    /// None: every frame is written on the caller's thread.
    Never,
}

impl WriteBehind {
    /// Whether a frame given away now goes behind the sender, whose previous given-away frame
    /// to the same peer returned at `last_given`.
    pub(crate) fn applies(self, last_given: Option<Instant>) -> bool {
        match self {
            WriteBehind::Streaming => last_given.is_some_and(|t| t.elapsed() < STREAMING_GAP),
            WriteBehind::Always => true,
            WriteBehind::Never => false,
        }
    }
}

/// Bytes queued for the writer, per peer, before a sender waits for room (one frame larger
/// than this is still taken when the queue is empty).
pub(crate) const BEHIND_MAX_BYTES: usize = 1 << 20;

/// A link's writer thread, started by the first frame written behind: it takes peers whose
/// frames are queued, in the order they became ready, and gives each a turn.
#[derive(Default)]
pub(crate) struct Writer {
    state: Mutex<WriterState>,
    wake: Condvar,
}

#[derive(Default)]
struct WriterState {
    /// Peers whose frames the writer should write, in the order they became ready.
    ready: VecDeque<SystemId>,
    closing: bool,
    thread: Option<JoinHandle<()>>,
}

impl Writer {
    /// Waits for a peer with frames; `None` once the link closes and nothing is ready.
    fn next(&self) -> Option<SystemId> {
        let mut st = lock(&self.state);
        loop {
            if let Some(to) = st.ready.pop_front() {
                return Some(to);
            }
            if st.closing {
                return None;
            }
            self.wake.wait(&mut st);
        }
    }

    /// Gives the writer `to`'s frames (the caller has marked the peer as the writer's).
    pub(crate) fn ready(&self, to: SystemId) {
        lock(&self.state).ready.push_back(to);
        self.wake.notify_one();
    }

    /// Starts the thread, named `name`, unless it runs; false if it cannot (the caller then
    /// writes itself) or the link is closing. `turn` writes what one peer has queued and says
    /// whether more came meanwhile: that peer then goes to the back of the line, so that one
    /// streaming peer does not starve the others.
    pub(crate) fn start(
        self: &Arc<Self>,
        name: String,
        turn: impl Fn(SystemId) -> bool + Send + 'static,
    ) -> bool {
        let mut st = lock(&self.state);
        if st.closing {
            return false;
        }
        if st.thread.is_some() {
            return true;
        }
        let writer = self.clone();
        let spawned = std::thread::Builder::new().name(name).spawn(move || {
            while let Some(to) = writer.next() {
                if turn(to) {
                    writer.ready(to);
                }
            }
        });
        match spawned {
            Ok(t) => {
                st.thread = Some(t);
                true
            }
            Err(_) => false,
        }
    }

    /// Lets the writer finish what is queued, then stops it (closing the link).
    pub(crate) fn stop(&self) {
        let thread = {
            let mut st = lock(&self.state);
            st.closing = true;
            st.thread.take()
        };
        self.wake.notify_all();
        if let Some(t) = thread {
            let _ = t.join();
        }
    }
}

/// Locks `m`, taking a poisoned lock over: a panic in a sink (or elsewhere) must not wedge the
/// whole link, and the data under every lock of this crate stays consistent between
/// statements.
pub(crate) fn lock<T>(m: &Mutex<T>) -> MutexGuard<'_, T> {
    m.lock()
}

/// Adds 1 to counter `c`.
pub(crate) fn bump(c: &AtomicU64) {
    c.fetch_add(1, Ordering::Relaxed);
}

/// Adds `n` to counter `c` (nothing is written when `n` is 0).
pub(crate) fn add<N: TryInto<u64>>(c: &AtomicU64, n: N) {
    let n = n.try_into().unwrap_or(u64::MAX);
    if n > 0 {
        c.fetch_add(n, Ordering::Relaxed);
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn counters_add_and_locks_survive_a_panic() {
        let c = AtomicU64::new(0);
        bump(&c);
        add(&c, 2usize);
        add(&c, 0u64);
        assert_eq!(c.load(Ordering::Relaxed), 3);
        let m = std::sync::Arc::new(Mutex::new(5));
        let m2 = m.clone();
        let _ = std::thread::spawn(move || {
            let _g = m2.lock();
            panic!("poison the lock");
        })
        .join();
        // parking_lot does not poison: the panicking holder released the lock as it unwound.
        assert!(!m.is_locked());
        assert_eq!(*lock(&m), 5);
    }
}

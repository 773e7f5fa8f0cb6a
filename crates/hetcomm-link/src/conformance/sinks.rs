//! The endpoints the checks open (a link, and a thread reading it if it is driven) and the
//! sinks they collect frames with.

use parking_lot::{Condvar, Mutex};
use std::sync::atomic::{AtomicBool, Ordering};
use std::sync::Arc;
use std::thread::JoinHandle;
use std::time::{Duration, Instant};

use hetcomm_core::SystemId;

use crate::{FrameSink, Link, Peer};

use super::Harness;

/// A link opened for a check: if it has a receive side, a thread reads it through
/// [`Link::readable`] (poll, then `read_ready`) until the endpoint is dropped.
pub(super) struct Endpoint {
    link: Arc<dyn Link>,
    reader: Option<Reader>,
}

struct Reader {
    stop: Arc<AtomicBool>,
    thread: Option<JoinHandle<()>>,
}

impl Drop for Reader {
    fn drop(&mut self) {
        self.stop.store(true, Ordering::SeqCst);
        if let Some(t) = self.thread.take() {
            let _ = t.join();
        }
    }
}

impl Endpoint {
    pub(super) fn new(link: Box<dyn Link>) -> Endpoint {
        let link: Arc<dyn Link> = Arc::from(link);
        let reader = link.readable().is_some().then(|| {
            let stop = Arc::new(AtomicBool::new(false));
            let stopping = stop.clone();
            let link = link.clone();
            let thread = std::thread::Builder::new()
                .name("conformance-reader".into())
                .spawn(move || {
                    let Some(rx) = link.readable() else { return };
                    while !stopping.load(Ordering::SeqCst) {
                        // A short wait so that a stop is noticed promptly; `read_ready` also
                        // does the link's upkeep when nothing arrived.
                        poll_readable(rx, 20);
                        let _ = rx.read_ready(64);
                    }
                })
                .expect("spawn the conformance reader");
            Reader {
                stop,
                thread: Some(thread),
            }
        });
        Endpoint { link, reader }
    }
}

impl Drop for Endpoint {
    fn drop(&mut self) {
        // Stop reading before the link goes: dropping it closes its sockets, and a restart
        // check binds the same address again.
        self.reader.take();
    }
}

impl std::ops::Deref for Endpoint {
    type Target = dyn Link;
    fn deref(&self) -> &(dyn Link + 'static) {
        &*self.link
    }
}

/// Opens `system` on `h`, reading it if it is driven.
pub(super) fn open(h: &mut dyn Harness, system: SystemId, sink: Arc<dyn FrameSink>) -> Endpoint {
    Endpoint::new(h.open(system, sink))
}

/// Waits up to `timeout_ms` for `rx` to poll readable.
pub(super) fn poll_readable(rx: &dyn crate::Readable, timeout_ms: u64) -> bool {
    use crate::readiness::{readable_fd, wait_readable};
    wait_readable(
        readable_fd(rx),
        std::time::Duration::from_millis(timeout_ms),
    )
}

/// A frame as a sink saw it.
#[derive(Clone, Debug, PartialEq, Eq)]
pub struct Received {
    /// The bytes.
    pub bytes: Vec<u8>,
    /// Who the link said sent it.
    pub from: Peer,
}

/// A sink that keeps every frame and lets a test wait for a count.
#[derive(Default)]
pub struct CollectSink {
    frames: Mutex<Vec<Received>>,
    arrived: Condvar,
}

impl CollectSink {
    /// A new, empty sink.
    pub fn new() -> Arc<CollectSink> {
        Arc::new(CollectSink::default())
    }

    /// How many frames were received so far.
    pub fn len(&self) -> usize {
        self.frames.lock().len()
    }

    /// Whether no frame was received yet.
    pub fn is_empty(&self) -> bool {
        self.len() == 0
    }

    /// Everything received so far.
    pub fn frames(&self) -> Vec<Received> {
        self.frames.lock().clone()
    }

    /// Waits until at least `n` frames arrived or `timeout` passed; returns how many arrived.
    pub fn wait_for(&self, n: usize, timeout: Duration) -> usize {
        let deadline = Instant::now() + timeout;
        let mut frames = self.frames.lock();
        while frames.len() < n {
            let left = deadline.saturating_duration_since(Instant::now());
            if left.is_zero() {
                break;
            }
            self.arrived.wait_for(&mut frames, left);
        }
        frames.len()
    }
}

impl FrameSink for CollectSink {
    fn on_frame(&self, frame: &[u8], from: Peer) {
        self.frames.lock().push(Received {
            bytes: frame.to_vec(),
            from,
        });
        self.arrived.notify_all();
    }
}

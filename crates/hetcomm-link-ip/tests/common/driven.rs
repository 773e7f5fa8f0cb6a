//! Driving a link's receive side ([`Readable`]) from a test, as a waiting runtime thread would.

use std::sync::atomic::{AtomicBool, Ordering};
use std::sync::Arc;
use std::thread::JoinHandle;
use std::time::Duration;

use hetcomm_link::readiness::{readable_fd, wait_readable};
use hetcomm_link::{Link, Readable};

/// Waits up to `timeout_ms` for `rx` to poll readable.
pub fn poll_readable(rx: &dyn Readable, timeout_ms: u64) -> bool {
    wait_readable(readable_fd(rx), Duration::from_millis(timeout_ms))
}

/// A thread that drives a link's receive side the way a waiting runtime thread would: poll,
/// then read what is ready. Stopped (and joined) on drop.
pub struct Driver {
    stop: Arc<AtomicBool>,
    thread: Option<JoinHandle<usize>>,
}

impl Driver {
    pub fn start<L: Link + Send + Sync + 'static>(link: Arc<L>) -> Driver {
        let stop = Arc::new(AtomicBool::new(false));
        let stopping = stop.clone();
        let thread = std::thread::spawn(move || {
            let rx = link.readable().expect("a driven link");
            let mut handed_on = 0;
            while !stopping.load(Ordering::SeqCst) {
                // A short timeout so that a stop is noticed promptly; read_ready also does
                // the link's upkeep.
                poll_readable(rx, 20);
                handed_on += rx.read_ready(64).expect("read_ready");
            }
            handed_on
        });
        Driver {
            stop,
            thread: Some(thread),
        }
    }

    /// Stops the thread; returns how many frames its `read_ready` calls reported.
    pub fn finish(mut self) -> usize {
        self.stop.store(true, Ordering::SeqCst);
        self.thread
            .take()
            .map(|t| t.join().expect("driver thread"))
            .unwrap_or(0)
    }
}

impl Drop for Driver {
    fn drop(&mut self) {
        self.stop.store(true, Ordering::SeqCst);
        if let Some(t) = self.thread.take() {
            let _ = t.join();
        }
    }
}

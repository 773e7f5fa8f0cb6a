//! Driving a link's receive side ([`Readable`]) from a test, as a waiting runtime thread would.

use std::os::fd::RawFd;
use std::sync::atomic::{AtomicBool, Ordering};
use std::sync::Arc;
use std::thread::JoinHandle;

use hetcomm_link::Link;

/// Waits up to `timeout_ms` for `fd` to poll readable.
pub fn poll_readable(fd: RawFd, timeout_ms: i32) -> bool {
    let mut p = libc::pollfd {
        fd,
        events: libc::POLLIN,
        revents: 0,
    };
    // SAFETY: one valid, exclusively borrowed pollfd for the duration of the call.
    let n = unsafe { libc::poll(&mut p, 1, timeout_ms) };
    n > 0 && p.revents & libc::POLLIN != 0
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
                poll_readable(rx.fd(), 20);
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

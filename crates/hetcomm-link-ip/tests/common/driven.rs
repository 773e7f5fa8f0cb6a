//! Driving a link's receive side ([`Readable`]) from a test, as a waiting runtime thread would.

use std::os::fd::RawFd;
use std::sync::atomic::{AtomicBool, Ordering};
use std::sync::Arc;
use std::thread::JoinHandle;

use hetcomm_core::SystemId;
use hetcomm_link::{Link, LinkCaps, LinkError, LinkStats, Readable};

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

/// A driven link with a driver thread of its own, so that suites that expect frames to
/// arrive by themselves (the conformance suite) can run on it.
pub struct DrivenLink<L: Link + Send + Sync + 'static> {
    link: Arc<L>,
    driver: Option<Driver>,
}

impl<L: Link + Send + Sync + 'static> DrivenLink<L> {
    pub fn new(link: L) -> Self {
        let link = Arc::new(link);
        let driver = Some(Driver::start(link.clone()));
        DrivenLink { link, driver }
    }
}

impl<L: Link + Send + Sync + 'static> Drop for DrivenLink<L> {
    fn drop(&mut self) {
        // Stop the driver first: it holds the other reference to the link, whose drop closes
        // its sockets (the suite rebinds the port to restart a peer).
        self.driver.take();
    }
}

impl<L: Link + Send + Sync + 'static> Link for DrivenLink<L> {
    fn caps(&self) -> LinkCaps {
        self.link.caps()
    }
    fn send(&self, to: SystemId, frame: &[u8]) -> Result<(), LinkError> {
        self.link.send(to, frame)
    }
    fn send_parts(&self, to: SystemId, head: &[u8], body: &[u8]) -> Result<(), LinkError> {
        self.link.send_parts(to, head, body)
    }
    fn stats(&self) -> LinkStats {
        self.link.stats()
    }
    fn send_held(&self, to: SystemId, frame: &[u8]) -> Result<(), LinkError> {
        self.link.send_held(to, frame)
    }
    fn flush(&self) -> Result<(), LinkError> {
        self.link.flush()
    }
    fn batches(&self) -> bool {
        self.link.batches()
    }
    fn readable(&self) -> Option<&dyn Readable> {
        self.link.readable()
    }
}

//! The eventfd the reader's data-available listener makes readable when it does not take the
//! sample itself: how such a sample wakes whoever drives the link.

use std::os::fd::{AsFd, AsRawFd, RawFd};
use std::sync::atomic::{AtomicBool, Ordering};
use std::time::Duration;

use hetcomm_link::readiness::{wait_readable, WakeFd};

/// An eventfd signalled by the listener once, until the reader is drained and the notifier
/// re-armed ([`rearm`](Notifier::rearm)): one `write` per burst of samples, not per sample.
pub struct Notifier {
    wake: WakeFd,
    armed: AtomicBool,
}

impl Notifier {
    /// A fresh, armed notifier.
    pub fn new() -> std::io::Result<Notifier> {
        Ok(Notifier {
            wake: WakeFd::new()?,
            armed: AtomicBool::new(true),
        })
    }

    /// The descriptor: readable once a sample arrived since the last re-arm.
    pub fn fd(&self) -> RawFd {
        self.wake.as_fd().as_raw_fd()
    }

    /// Clears the descriptor and re-arms the listener; call before taking the reader's
    /// samples, so that any sample stored after the take signals again.
    pub fn rearm(&self) {
        if self.armed.load(Ordering::SeqCst) {
            return; // nothing signalled: a spinning reader makes no syscall here
        }
        self.wake.drain();
        self.armed.store(true, Ordering::SeqCst);
    }

    /// Waits at most `timeout` (in whole milliseconds) for the descriptor to be readable.
    pub fn wait(&self, timeout: Duration) -> bool {
        let ms = Duration::from_millis(timeout.as_millis().min(u64::MAX as u128) as u64);
        wait_readable(self.wake.as_fd(), ms)
    }

    /// Makes the descriptor readable, unless it already is (and not yet re-armed).
    pub fn signal(&self) {
        if self.armed.swap(false, Ordering::SeqCst) {
            self.wake.wake();
        }
    }
}

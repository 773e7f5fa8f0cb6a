//! The eventfd the reader's data-available listener makes readable when it does not take the
//! sample itself: how such a sample wakes whoever drives the link.

use std::os::fd::{AsRawFd, FromRawFd, OwnedFd, RawFd};
use std::sync::atomic::{AtomicBool, Ordering};
use std::time::Duration;

/// An eventfd signalled by the listener once, until the reader is drained and the notifier
/// re-armed ([`rearm`](Notifier::rearm)): one `write` per burst of samples, not per sample.
pub struct Notifier {
    fd: OwnedFd,
    armed: AtomicBool,
}

impl Notifier {
    /// A fresh, armed notifier.
    pub fn new() -> std::io::Result<Notifier> {
        // SAFETY: plain syscall; the descriptor is owned from here on.
        let fd = unsafe { libc::eventfd(0, libc::EFD_NONBLOCK | libc::EFD_CLOEXEC) };
        if fd < 0 {
            return Err(std::io::Error::last_os_error());
        }
        Ok(Notifier {
            // SAFETY: a fresh descriptor of ours.
            fd: unsafe { OwnedFd::from_raw_fd(fd) },
            armed: AtomicBool::new(true),
        })
    }

    /// The descriptor: readable once a sample arrived since the last re-arm.
    pub fn fd(&self) -> RawFd {
        self.fd.as_raw_fd()
    }

    /// Clears the descriptor and re-arms the listener; call before taking the reader's
    /// samples, so that any sample stored after the take signals again.
    pub fn rearm(&self) {
        if self.armed.load(Ordering::SeqCst) {
            return; // nothing signalled: a spinning reader makes no syscall here
        }
        let mut count = 0u64;
        // SAFETY: reads 8 bytes into a u64 from our non-blocking eventfd.
        unsafe { libc::read(self.fd(), (&mut count as *mut u64).cast(), 8) };
        self.armed.store(true, Ordering::SeqCst);
    }

    /// Waits at most `timeout` for the descriptor to be readable.
    pub fn wait(&self, timeout: Duration) -> bool {
        let mut pfd = libc::pollfd {
            fd: self.fd(),
            events: libc::POLLIN,
            revents: 0,
        };
        // SAFETY: one valid pollfd.
        unsafe { libc::poll(&mut pfd, 1, timeout.as_millis() as libc::c_int) > 0 }
    }

    /// Makes the descriptor readable, unless it already is (and not yet re-armed).
    pub fn signal(&self) {
        if self.armed.swap(false, Ordering::SeqCst) {
            let one = 1u64;
            // SAFETY: writes 8 bytes to our eventfd (cannot block: the count stays small).
            unsafe { libc::write(self.fd(), (&one as *const u64).cast(), 8) };
        }
    }
}

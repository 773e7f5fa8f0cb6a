//! OS readiness shared by links and the runtime: waiting for a descriptor to poll readable,
//! and a descriptor another thread makes readable to wake a waiter.
//!
//! Built on `rustix`'s safe `poll(2)` and `eventfd(2)`: level-triggered, one system call per
//! wait, the same calls the hand-written `libc` code made.

use std::io;
use std::os::fd::{AsFd, BorrowedFd, OwnedFd};
use std::time::Duration;

use rustix::event::{eventfd, poll, EventfdFlags, PollFd, PollFlags, Timespec};

use crate::Readable;

/// The descriptor of a driven receive side, borrowed for as long as the receive side is.
pub fn readable_fd(r: &dyn Readable) -> BorrowedFd<'_> {
    // SAFETY: `Readable::fd`'s contract: an open descriptor for as long as `r` lives.
    unsafe { BorrowedFd::borrow_raw(r.fd()) }
}

/// `timeout` as the `Timespec` that `poll(2)` and `epoll_wait(2)` take.
pub fn timespec(timeout: Duration) -> Timespec {
    Timespec {
        tv_sec: timeout.as_secs().min(i64::MAX as u64) as i64,
        tv_nsec: i64::from(timeout.subsec_nanos()),
    }
}

/// Waits up to `timeout` for `fd` to poll readable. An interrupted or failed wait is `false`.
pub fn wait_readable(fd: BorrowedFd<'_>, timeout: Duration) -> bool {
    let mut fds = [PollFd::from_borrowed_fd(fd, PollFlags::IN)];
    matches!(poll(&mut fds, Some(&timespec(timeout))), Ok(n) if n > 0)
        && fds[0].revents().contains(PollFlags::IN)
}

/// An `eventfd` one thread makes readable ([`wake`](WakeFd::wake)) to end another's wait on
/// it; [`drain`](WakeFd::drain) makes it not readable again.
#[derive(Debug)]
pub struct WakeFd(OwnedFd);

impl WakeFd {
    /// A fresh descriptor, not readable.
    pub fn new() -> io::Result<WakeFd> {
        let fd = eventfd(0, EventfdFlags::NONBLOCK | EventfdFlags::CLOEXEC)?;
        Ok(WakeFd(fd))
    }

    /// Makes the descriptor readable. A full counter (`EAGAIN`) still leaves it readable,
    /// which is all a wake-up needs, so the result is not looked at.
    pub fn wake(&self) {
        let _ = rustix::io::write(&self.0, &1u64.to_ne_bytes());
    }

    /// Makes the descriptor not readable (until the next [`wake`](WakeFd::wake)).
    pub fn drain(&self) {
        let mut count = [0u8; 8];
        let _ = rustix::io::read(&self.0, &mut count);
    }
}

impl AsFd for WakeFd {
    fn as_fd(&self) -> BorrowedFd<'_> {
        self.0.as_fd()
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn a_wake_makes_the_descriptor_readable_until_drained() {
        let w = WakeFd::new().unwrap();
        assert!(!wait_readable(w.as_fd(), Duration::ZERO));
        w.wake();
        w.wake();
        assert!(wait_readable(w.as_fd(), Duration::from_millis(100)));
        w.drain();
        assert!(!wait_readable(w.as_fd(), Duration::from_millis(1)));
    }
}

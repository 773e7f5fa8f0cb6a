//! Helpers every link of this crate shares: lock handling and atomic counters.
//!
//! Each link keeps its own counter struct (`UdpCounters`, `StreamCounters`) and its own
//! per-peer state (`UdpPeer`, `PeerSlot` of the stream layer): their fields differ, only these
//! operations on them are common.

use std::sync::atomic::{AtomicU64, Ordering};
use std::sync::{Mutex, MutexGuard};

/// Locks `m`, taking a poisoned lock over: a panic in a sink (or elsewhere) must not wedge the
/// whole link, and the data under every lock of this crate stays consistent between
/// statements.
pub(crate) fn lock<T>(m: &Mutex<T>) -> MutexGuard<'_, T> {
    m.lock().unwrap_or_else(|e| e.into_inner())
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
            let _g = m2.lock().unwrap();
            panic!("poison the lock");
        })
        .join();
        assert!(m.is_poisoned());
        assert_eq!(*lock(&m), 5);
    }
}

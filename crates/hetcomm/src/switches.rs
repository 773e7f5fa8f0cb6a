//! Path switches, for every consumer: the system keeps the last ones
//! ([`Comm::path_changes`](crate::Comm::path_changes), [`SystemStats`](crate::SystemStats))
//! and reports each to its observers ([`Observer::on_path_change`]); a [`PathWatch`] is an
//! observer that queues them for a thread (or a Python iterator, or a C poll) of its own.
//! Each consumer sees every switch: none takes it from another.

use parking_lot::{Condvar, Mutex};
use std::collections::VecDeque;
use std::sync::Arc;
use std::time::Duration;

use hetcomm_core::Time;
use hetcomm_router::PathChange;

use crate::comm::PathSwitch;
use crate::observe::{ObserverHandle, PathChangeRecord};
use crate::runtime::SystemCore;
use crate::Observer;

/// Switches a system keeps (and a [`PathWatch`] holds before it drops the oldest).
pub(crate) const KEPT: usize = 1024;

/// The last [`KEPT`] switches of a system, numbered from 1.
#[derive(Default)]
pub(crate) struct PathLog {
    inner: Mutex<LogInner>,
}

#[derive(Default)]
struct LogInner {
    /// Switches so far (the number of the newest).
    count: u64,
    kept: VecDeque<PathSwitch>,
}

impl PathLog {
    /// The switches numbered above `after`, oldest first, and the newest number.
    pub(crate) fn since(&self, after: u64) -> (Vec<PathSwitch>, u64) {
        let log = self.inner.lock();
        let list = log
            .kept
            .iter()
            .filter(|s| s.number > after)
            .cloned()
            .collect();
        (list, log.count)
    }

    /// The last `n` switches, oldest first.
    pub(crate) fn last(&self, n: usize) -> Vec<PathSwitch> {
        let log = self.inner.lock();
        log.kept
            .iter()
            .skip(log.kept.len().saturating_sub(n))
            .cloned()
            .collect()
    }
}

impl SystemCore {
    /// Records the router's switches and reports them to the observers (called by the pump,
    /// without the router's lock).
    #[cold]
    #[inline(never)]
    pub(crate) fn path_switched(&self, changes: &[PathChange], now: Time) {
        for c in changes {
            let from = self.link_name(c.from.link).unwrap_or("?");
            let to_transport = self.link_name(c.now.link).unwrap_or("?");
            let to_name = self.directory.system_name(c.to);
            let number = {
                let mut log = self.path_log.inner.lock();
                log.count += 1;
                let number = log.count;
                if log.kept.len() >= KEPT {
                    log.kept.pop_front();
                }
                log.kept.push_back(PathSwitch {
                    to: to_name.to_string(),
                    from: from.to_string(),
                    now: to_transport.to_string(),
                    at: now,
                    number,
                });
                number
            };
            self.observe_path_change(&PathChangeRecord {
                to: c.to,
                to_name,
                from,
                now: to_transport,
                links: (c.from.link, c.now.link),
                time: now,
                number,
            });
        }
    }
}

/// Path switches of one system, queued for whoever reads them
/// ([`Comm::watch_paths`](crate::Comm::watch_paths)): every switch after the watch was made,
/// in order, whatever other consumers read. It holds up to 1024 unread switches; beyond that
/// the oldest are dropped and counted ([`PathWatch::dropped`]). Dropping it stops the watch.
pub struct PathWatch {
    queue: Arc<WatchQueue>,
    _handle: ObserverHandle,
}

#[derive(Default)]
struct WatchQueue {
    state: Mutex<(VecDeque<PathSwitch>, u64)>,
    ready: Condvar,
}

impl Observer for WatchQueue {
    fn on_path_change(&self, r: &PathChangeRecord<'_>) {
        let mut s = self.state.lock();
        if s.0.len() >= KEPT {
            s.0.pop_front();
            s.1 += 1;
        }
        s.0.push_back(PathSwitch {
            to: r.to_name.to_string(),
            from: r.from.to_string(),
            now: r.now.to_string(),
            at: r.time,
            number: r.number,
        });
        drop(s);
        self.ready.notify_all();
    }
}

impl PathWatch {
    pub(crate) fn new(core: &Arc<SystemCore>) -> PathWatch {
        let queue = Arc::new(WatchQueue::default());
        PathWatch {
            _handle: ObserverHandle::register(core, queue.clone()),
            queue,
        }
    }

    /// The next switch, if one is waiting.
    pub fn try_next(&self) -> Option<PathSwitch> {
        let mut s = self.queue.state.lock();
        s.0.pop_front()
    }

    /// The next switch, waiting up to `timeout` for one.
    pub fn next_timeout(&self, timeout: Duration) -> Option<PathSwitch> {
        let deadline = std::time::Instant::now() + timeout;
        let mut s = self.queue.state.lock();
        loop {
            if let Some(c) = s.0.pop_front() {
                return Some(c);
            }
            let left = deadline.checked_duration_since(std::time::Instant::now())?;
            self.queue.ready.wait_for(&mut s, left);
        }
    }

    /// Every switch waiting, oldest first.
    pub fn drain(&self) -> Vec<PathSwitch> {
        let mut s = self.queue.state.lock();
        s.0.drain(..).collect()
    }

    /// Switches dropped because more than 1024 were waiting unread.
    pub fn dropped(&self) -> u64 {
        self.queue.state.lock().1
    }
}

impl std::fmt::Debug for PathWatch {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        f.debug_struct("PathWatch").finish_non_exhaustive()
    }
}

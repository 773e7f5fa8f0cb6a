//! A module's inbox: bounded, ordered by priority then arrival, with an explicit overflow
//! policy and exact drop counters.

use std::collections::VecDeque;
use std::sync::atomic::{AtomicU64, AtomicUsize, Ordering};
use std::sync::{Condvar, Mutex, MutexGuard};
use std::time::{Duration, Instant};

use hetcomm_config::{InboxConfig, OverflowPolicy};
use hetcomm_core::{Header, MessageType, PayloadBuf};

/// One queued message.
#[derive(Clone, Debug)]
pub(crate) struct Entry {
    pub header: Header,
    pub payload: PayloadBuf,
    pub received_at: hetcomm_core::Time,
}

/// Counters of one inbox.
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq)]
pub struct InboxStats {
    /// Messages accepted into the inbox.
    pub accepted: u64,
    /// Messages taken out by the module (or its callbacks).
    pub taken: u64,
    /// Queued messages evicted to make room (`drop-oldest`).
    pub dropped_oldest: u64,
    /// Arriving messages refused because the inbox was full (`drop-newest`, or `drop-oldest`
    /// when everything queued outranks the newcomer).
    pub dropped_newest: u64,
    /// Arriving messages refused after waiting for room (`block`).
    pub dropped_after_wait: u64,
    /// Messages queued now.
    pub len: usize,
    /// The bound.
    pub capacity: usize,
}

impl InboxStats {
    /// Every message lost to overflow, whatever the policy.
    pub fn dropped(&self) -> u64 {
        self.dropped_oldest + self.dropped_newest + self.dropped_after_wait
    }
}

#[derive(Default)]
struct State {
    /// One FIFO per priority in use, highest priority first. Emptied queues stay (a fleet uses
    /// a handful of priorities), so the common push is a short scan and a `push_back`.
    queues: Vec<(u8, VecDeque<Entry>)>,
    len: usize,
    stats: InboxStats,
    closed: bool,
    /// Threads waiting in `take_timeout` / a blocked `push`: a condition variable is only
    /// signalled when someone waits, since every signal is a system call.
    empty_waiters: usize,
    full_waiters: usize,
}

impl State {
    fn push(&mut self, e: Entry) {
        let prio = e.header.priority.0;
        let at = match self.queues.iter().position(|(p, _)| *p <= prio) {
            Some(i) if self.queues[i].0 == prio => i,
            Some(i) => {
                self.queues.insert(i, (prio, VecDeque::new()));
                i
            }
            None => {
                self.queues.push((prio, VecDeque::new()));
                self.queues.len() - 1
            }
        };
        self.queues[at].1.push_back(e);
        self.len += 1;
        self.stats.accepted += 1;
    }

    fn front(&self) -> Option<&Entry> {
        self.queues.iter().find_map(|(_, q)| q.front())
    }

    fn pop(&mut self) -> Option<Entry> {
        let e = self.queues.iter_mut().find_map(|(_, q)| q.pop_front())?;
        self.len -= 1;
        self.stats.taken += 1;
        Some(e)
    }

    /// Evicts the oldest message of the lowest priority at or below `prio`.
    fn evict_for(&mut self, prio: u8) -> bool {
        let Some((lowest, q)) = self.queues.iter_mut().rev().find(|(_, q)| !q.is_empty()) else {
            return false;
        };
        if *lowest > prio {
            return false;
        }
        q.pop_front();
        self.len -= 1;
        self.stats.dropped_oldest += 1;
        true
    }
}

/// Why a push was refused.
#[derive(Debug, PartialEq, Eq)]
pub(crate) enum PushError {
    Full,
    Closed,
}

pub(crate) struct Inbox {
    config: InboxConfig,
    /// Messages queued, readable without the lock: a waiter that spins watches it.
    queued: AtomicUsize,
    /// How long a waiter spins before it sleeps on the condition variable (µs; 0: never).
    spin_us: AtomicU64,
    state: Mutex<State>,
    not_empty: Condvar,
    not_full: Condvar,
}

impl Inbox {
    pub(crate) fn new(config: InboxConfig) -> Self {
        let capacity = config.capacity.max(1);
        Inbox {
            config: InboxConfig { capacity, ..config },
            queued: AtomicUsize::new(0),
            spin_us: AtomicU64::new(0),
            state: Mutex::new(State {
                stats: InboxStats {
                    capacity,
                    ..InboxStats::default()
                },
                ..State::default()
            }),
            not_empty: Condvar::new(),
            not_full: Condvar::new(),
        }
    }

    fn lock(&self) -> MutexGuard<'_, State> {
        self.state.lock().unwrap_or_else(|e| e.into_inner())
    }

    /// Puts a message in, applying the overflow policy.
    pub(crate) fn push(&self, e: Entry) -> Result<(), PushError> {
        let mut s = self.lock();
        if s.closed {
            return Err(PushError::Closed);
        }
        if s.len >= self.config.capacity {
            match self.config.overflow {
                OverflowPolicy::DropOldest => {
                    if !s.evict_for(e.header.priority.0) {
                        s.stats.dropped_newest += 1;
                        return Err(PushError::Full);
                    }
                }
                OverflowPolicy::DropNewest => {
                    s.stats.dropped_newest += 1;
                    return Err(PushError::Full);
                }
                OverflowPolicy::Block { timeout } => {
                    let deadline = Instant::now() + timeout;
                    while s.len >= self.config.capacity && !s.closed {
                        let left = deadline.saturating_duration_since(Instant::now());
                        if left.is_zero() {
                            s.stats.dropped_after_wait += 1;
                            return Err(PushError::Full);
                        }
                        s.full_waiters += 1;
                        s = self
                            .not_full
                            .wait_timeout(s, left)
                            .unwrap_or_else(|e| e.into_inner())
                            .0;
                        s.full_waiters -= 1;
                    }
                    if s.closed {
                        return Err(PushError::Closed);
                    }
                }
            }
        }
        s.push(e);
        self.queued.store(s.len, Ordering::Release);
        let wake = s.empty_waiters > 0;
        drop(s);
        if wake {
            self.not_empty.notify_one();
        }
        Ok(())
    }

    pub(crate) fn len(&self) -> usize {
        self.lock().len
    }

    pub(crate) fn next_type(&self) -> Option<MessageType> {
        self.lock().front().map(|e| e.header.message_type)
    }

    /// Takes the front message if `accept` agrees (it sees the header), without waiting.
    /// `Ok(None)`: empty. `Err(header)`: refused, left in place.
    pub(crate) fn try_take(
        &self,
        accept: impl Fn(&Header) -> bool,
    ) -> Result<Option<Entry>, Header> {
        let mut s = self.lock();
        self.take_locked(&mut s, &accept)
    }

    fn take_locked(
        &self,
        s: &mut State,
        accept: &impl Fn(&Header) -> bool,
    ) -> Result<Option<Entry>, Header> {
        match s.front() {
            None => Ok(None),
            Some(e) if !accept(&e.header) => Err(e.header),
            Some(_) => {
                let e = s.pop();
                self.queued.store(s.len, Ordering::Release);
                if s.full_waiters > 0 {
                    self.not_full.notify_one();
                }
                Ok(e)
            }
        }
    }

    /// Like [`Inbox::try_take`], waiting up to `timeout` (None: forever) for a message.
    /// `Ok(None)` after the timeout or when the inbox is closed and empty.
    pub(crate) fn take_timeout(
        &self,
        accept: impl Fn(&Header) -> bool,
        timeout: Option<Duration>,
    ) -> Result<Option<Entry>, Header> {
        let deadline = timeout.map(|t| Instant::now() + t);
        let mut s = self.lock();
        loop {
            if s.len > 0 || s.closed {
                return self.take_locked(&mut s, &accept);
            }
            let left = match deadline {
                None => None,
                Some(d) => {
                    let left = d.saturating_duration_since(Instant::now());
                    if left.is_zero() {
                        return Ok(None);
                    }
                    Some(left)
                }
            };
            let spin = self.spin_us.load(Ordering::Relaxed);
            if spin > 0 && !s.closed {
                drop(s);
                self.spin_until_queued(
                    Duration::from_micros(spin).min(left.unwrap_or(Duration::MAX)),
                );
                s = self.lock();
                if s.len > 0 || s.closed {
                    continue;
                }
            }
            s.empty_waiters += 1;
            s = match left {
                None => self.not_empty.wait(s).unwrap_or_else(|e| e.into_inner()),
                Some(left) => {
                    self.not_empty
                        .wait_timeout(s, left)
                        .unwrap_or_else(|e| e.into_inner())
                        .0
                }
            };
            s.empty_waiters -= 1;
        }
    }

    /// Makes waiters spin up to `spin` for a message before they sleep: a message that comes
    /// meanwhile is taken without a wake-up (a system call and a reschedule, microseconds), at
    /// the price of a busy core while spinning.
    pub(crate) fn set_spin(&self, spin: Duration) {
        let us = u64::try_from(spin.as_micros()).unwrap_or(u64::MAX);
        self.spin_us.store(us, Ordering::Relaxed);
    }

    fn spin_until_queued(&self, spin: Duration) {
        let start = Instant::now();
        let mut rounds = 0u32;
        while self.queued.load(Ordering::Acquire) == 0 {
            std::hint::spin_loop();
            rounds += 1;
            // Reading the clock costs more than a spin: look at it now and then.
            if rounds.is_multiple_of(64) && start.elapsed() >= spin {
                return;
            }
        }
    }

    pub(crate) fn stats(&self) -> InboxStats {
        let s = self.lock();
        InboxStats {
            len: s.len,
            ..s.stats
        }
    }

    /// Wakes every waiter; later pushes fail and waits return what is left.
    pub(crate) fn close(&self) {
        self.lock().closed = true;
        self.not_empty.notify_all();
        self.not_full.notify_all();
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use hetcomm_core::{Address, ModuleId, Priority, SystemId};

    fn entry(prio: u8, tag: u8) -> Entry {
        let a = Address {
            system: SystemId(0),
            module: ModuleId(0),
        };
        let mut header = Header::data(a, a, MessageType(1));
        header.priority = Priority(prio);
        Entry {
            header,
            payload: PayloadBuf::copy_from_slice(&[tag]),
            received_at: hetcomm_core::Time::ZERO,
        }
    }

    fn inbox(capacity: usize, overflow: OverflowPolicy) -> Inbox {
        Inbox::new(InboxConfig { capacity, overflow })
    }

    fn drain(i: &Inbox) -> Vec<u8> {
        let mut out = vec![];
        while let Ok(Some(e)) = i.try_take(|_| true) {
            out.push(e.payload[0]);
        }
        out
    }

    #[test]
    fn priority_then_arrival() {
        let i = inbox(10, OverflowPolicy::DropNewest);
        for (p, t) in [(1, 1), (5, 2), (1, 3), (9, 4), (5, 5)] {
            i.push(entry(p, t)).unwrap();
        }
        assert_eq!(drain(&i), vec![4, 2, 5, 1, 3]);
    }

    #[test]
    fn drop_oldest_evicts_lowest_priority_oldest() {
        let i = inbox(3, OverflowPolicy::DropOldest);
        for (p, t) in [(5, 1), (1, 2), (1, 3)] {
            i.push(entry(p, t)).unwrap();
        }
        i.push(entry(1, 4)).unwrap(); // evicts 2
        assert_eq!(i.push(entry(0, 5)), Err(PushError::Full)); // everything outranks it
        let s = i.stats();
        assert_eq!((s.dropped_oldest, s.dropped_newest), (1, 1));
        assert_eq!(drain(&i), vec![1, 3, 4]);
    }

    #[test]
    fn drop_newest_refuses() {
        let i = inbox(2, OverflowPolicy::DropNewest);
        for t in 0..5 {
            let _ = i.push(entry(1, t));
        }
        assert_eq!(i.stats().dropped_newest, 3);
        assert_eq!(drain(&i), vec![0, 1]);
    }

    #[test]
    fn block_waits_for_room_then_gives_up() {
        let i = std::sync::Arc::new(inbox(
            1,
            OverflowPolicy::Block {
                timeout: Duration::from_millis(20),
            },
        ));
        i.push(entry(1, 0)).unwrap();
        assert_eq!(i.push(entry(1, 1)), Err(PushError::Full));
        assert_eq!(i.stats().dropped_after_wait, 1);
        // With a consumer making room, a blocked push succeeds.
        let patient = std::sync::Arc::new(inbox(
            1,
            OverflowPolicy::Block {
                timeout: Duration::from_secs(10),
            },
        ));
        patient.push(entry(1, 0)).unwrap();
        let p2 = patient.clone();
        let pusher = std::thread::spawn(move || p2.push(entry(1, 1)));
        let first = patient.take_timeout(|_| true, Some(Duration::from_secs(10)));
        assert_eq!(first.unwrap().unwrap().payload, vec![0]);
        assert_eq!(pusher.join().unwrap(), Ok(()));
        assert_eq!(drain(&patient), vec![1]);
        assert_eq!(patient.stats().dropped(), 0);
    }

    #[test]
    fn refused_take_leaves_message() {
        let i = inbox(4, OverflowPolicy::DropNewest);
        i.push(entry(1, 7)).unwrap();
        assert!(i.try_take(|_| false).is_err());
        assert_eq!(i.len(), 1);
    }
}

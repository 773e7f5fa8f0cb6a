//! A module's inbox: bounded, ordered by priority then arrival, with an explicit overflow
//! policy and exact drop counters.

use std::collections::VecDeque;
use std::sync::atomic::{AtomicU16, AtomicU64, AtomicUsize, Ordering};
use std::sync::{Condvar, Mutex, MutexGuard};
use std::time::{Duration, Instant};

use hetcomm_config::{InboxConfig, OverflowPolicy};

use crate::padded::CachePadded;
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

/// The producers' side: what arrived since the consumer last took a batch.
#[derive(Default)]
struct State {
    /// One FIFO per priority in use, highest priority first. Emptied queues stay (a fleet uses
    /// a handful of priorities), so the common push is a short scan and a `push_back`.
    queues: Vec<(u8, VecDeque<Entry>)>,
    len: usize,
    /// The stash's length when it was last filled: an upper bound of what it holds now (it
    /// only shrinks in between), so a push far from full needs no look at the stash.
    stash_bound: usize,
    stats: InboxStats,
    closed: bool,
    /// Threads waiting in `take_timeout`: a condition variable is only signalled when someone
    /// waits, since every signal is a system call.
    empty_waiters: usize,
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

    /// [`SHARED_EMPTY`] or the highest priority queued, plus one.
    fn top(&self) -> u16 {
        self.front()
            .map_or(SHARED_EMPTY, |e| u16::from(e.header.priority.0) + 1)
    }

    /// The lowest priority queued.
    fn lowest(&self) -> Option<u8> {
        self.queues
            .iter()
            .rev()
            .find(|(_, q)| !q.is_empty())
            .map(|(p, _)| *p)
    }
}

/// The consumers' side: a batch moved out of [`State`] in one go, in the order it is to be
/// taken (priority, then arrival), so that taking a message usually touches nothing the
/// producers write.
#[derive(Default)]
struct Stash {
    entries: VecDeque<Entry>,
    taken: u64,
}

/// `Inbox::shared_top` when the producers' side is empty.
const SHARED_EMPTY: u16 = 0;

/// Why a push was refused.
#[derive(Debug, PartialEq, Eq)]
pub(crate) enum PushError {
    Full,
    Closed,
}

/// A bounded priority inbox with many producers and (usually) one consumer.
///
/// Producers push into `shared` under its lock. A consumer that finds its `stash` empty moves
/// everything queued there into the stash at once, then takes from the stash under a lock
/// producers never touch: one exchange of the shared lock per batch instead of per message.
/// Priority order is kept exactly: a consumer takes from the stash only while its front is
/// at least the highest priority waiting in `shared` (`shared_top`, readable without the
/// lock), and a stashed message arrived before anything in `shared`, so it wins ties.
/// Capacity, eviction and counters cover both sides. Lock order: `stash`, then `shared`.
pub(crate) struct Inbox {
    config: InboxConfig,
    /// Producers write here per message, the consumer reads its stash per message: each on
    /// lines of its own.
    shared: CachePadded<Mutex<State>>,
    stash: CachePadded<Mutex<Stash>>,
    /// [`State::top`] of `shared`, stored by whoever changes it (only when it changes, so a
    /// stream of pushes at one priority does not write it per message).
    shared_top: AtomicU16,
    /// Messages in the stash: for a push near the bound, and for spinning waiters.
    stash_len: CachePadded<AtomicUsize>,
    /// Producers blocked for room (`block` policy): a consumer that makes room wakes one.
    full_waiters: AtomicUsize,
    /// How long a waiter spins before it sleeps on the condition variable (µs; 0: never).
    spin_us: AtomicU64,
    not_empty: Condvar,
    not_full: Condvar,
}

impl Inbox {
    pub(crate) fn new(config: InboxConfig) -> Self {
        let capacity = config.capacity.max(1);
        Inbox {
            config: InboxConfig { capacity, ..config },
            shared: CachePadded(Mutex::new(State {
                stats: InboxStats {
                    capacity,
                    ..InboxStats::default()
                },
                ..State::default()
            })),
            stash: CachePadded(Mutex::new(Stash::default())),
            shared_top: AtomicU16::new(SHARED_EMPTY),
            stash_len: CachePadded(AtomicUsize::new(0)),
            full_waiters: AtomicUsize::new(0),
            spin_us: AtomicU64::new(0),
            not_empty: Condvar::new(),
            not_full: Condvar::new(),
        }
    }

    fn lock(&self) -> MutexGuard<'_, State> {
        self.shared.lock().unwrap_or_else(|e| e.into_inner())
    }

    fn lock_stash(&self) -> MutexGuard<'_, Stash> {
        self.stash.lock().unwrap_or_else(|e| e.into_inner())
    }

    /// Stores `shared`'s top priority after it changed.
    fn publish_top(&self, s: &State) {
        let top = s.top();
        if self.shared_top.load(Ordering::Relaxed) != top {
            self.shared_top.store(top, Ordering::Release);
        }
    }

    /// Messages queued on both sides (with `shared` locked).
    fn queued(&self, s: &State) -> usize {
        // The bound is exact enough far from full; near it, read the stash's length.
        if s.len + s.stash_bound < self.config.capacity {
            return s.len + s.stash_bound;
        }
        s.len + self.stash_len.load(Ordering::SeqCst)
    }

    /// Puts a message in, applying the overflow policy.
    pub(crate) fn push(&self, e: Entry) -> Result<(), PushError> {
        let mut s = self.lock();
        if s.closed {
            return Err(PushError::Closed);
        }
        if self.queued(&s) >= self.config.capacity {
            match self.config.overflow {
                OverflowPolicy::DropOldest => {
                    // The oldest may be in the stash: take both locks, in order.
                    drop(s);
                    let mut stash = self.lock_stash();
                    s = self.lock();
                    if s.closed {
                        return Err(PushError::Closed);
                    }
                    if s.len + stash.entries.len() >= self.config.capacity
                        && !self.evict_for(&mut s, &mut stash, e.header.priority.0)
                    {
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
                    loop {
                        // Counted as waiting before looking, so that a consumer making room
                        // after the look sees the count and wakes it (see `made_room`).
                        self.full_waiters.fetch_add(1, Ordering::SeqCst);
                        if self.queued(&s) < self.config.capacity || s.closed {
                            self.full_waiters.fetch_sub(1, Ordering::SeqCst);
                            break;
                        }
                        let left = deadline.saturating_duration_since(Instant::now());
                        if left.is_zero() {
                            self.full_waiters.fetch_sub(1, Ordering::SeqCst);
                            s.stats.dropped_after_wait += 1;
                            return Err(PushError::Full);
                        }
                        s = self
                            .not_full
                            .wait_timeout(s, left)
                            .unwrap_or_else(|e| e.into_inner())
                            .0;
                        self.full_waiters.fetch_sub(1, Ordering::SeqCst);
                    }
                    if s.closed {
                        return Err(PushError::Closed);
                    }
                }
            }
        }
        let prio = e.header.priority.0;
        s.push(e);
        if u16::from(prio) + 1 > self.shared_top.load(Ordering::Relaxed) {
            self.shared_top
                .store(u16::from(prio) + 1, Ordering::Release);
        }
        let wake = s.empty_waiters > 0;
        drop(s);
        if wake {
            self.not_empty.notify_one();
        }
        Ok(())
    }

    /// Evicts the oldest message of the lowest priority at or below `prio`, from either side
    /// (both locked). A stashed message arrived before any in `shared`, so it goes first on a tie.
    fn evict_for(&self, s: &mut State, stash: &mut Stash, prio: u8) -> bool {
        let stashed = stash.entries.back().map(|e| e.header.priority.0);
        let lowest = match (stashed, s.lowest()) {
            (None, None) => return false,
            (Some(a), Some(b)) => a.min(b),
            (Some(a), None) => a,
            (None, Some(b)) => b,
        };
        if lowest > prio {
            return false;
        }
        if stashed == Some(lowest) {
            // The stash is sorted by priority, highest first: its oldest of the lowest
            // priority is the first of that priority.
            let at = stash
                .entries
                .partition_point(|e| e.header.priority.0 > lowest);
            stash.entries.remove(at);
            self.stash_len.store(stash.entries.len(), Ordering::Release);
        } else if let Some((_, q)) = s.queues.iter_mut().find(|(p, _)| *p == lowest) {
            q.pop_front();
            s.len -= 1;
            self.publish_top(s);
        }
        s.stats.dropped_oldest += 1;
        true
    }

    pub(crate) fn len(&self) -> usize {
        let stash = self.lock_stash();
        stash.entries.len() + self.lock().len
    }

    /// Whether anything is queued (no lock taken).
    pub(crate) fn is_empty(&self) -> bool {
        self.shared_top.load(Ordering::Acquire) == SHARED_EMPTY
            && self.stash_len.load(Ordering::Acquire) == 0
    }

    pub(crate) fn next_type(&self) -> Option<MessageType> {
        let stash = self.lock_stash();
        let s = self.lock();
        match (stash.entries.front(), s.front()) {
            (Some(a), Some(b)) if b.header.priority > a.header.priority => Some(b),
            (Some(a), _) => Some(a),
            (None, b) => b,
        }
        .map(|e| e.header.message_type)
    }

    /// Takes the front message if `accept` agrees (it sees the header), without waiting.
    /// `Ok(None)`: empty. `Err(header)`: refused, left in place.
    pub(crate) fn try_take(
        &self,
        accept: impl Fn(&Header) -> bool,
    ) -> Result<Option<Entry>, Header> {
        let mut stash = self.lock_stash();
        self.take_from(&mut stash, &accept)
    }

    /// One take with the stash locked: from the stash while it comes first, else from
    /// `shared` (moving all of it into an empty stash).
    fn take_from(
        &self,
        stash: &mut Stash,
        accept: &impl Fn(&Header) -> bool,
    ) -> Result<Option<Entry>, Header> {
        let top = self.shared_top.load(Ordering::Acquire);
        if let Some(front) = stash.entries.front() {
            if u16::from(front.header.priority.0) + 1 >= top {
                return self.take_stashed(stash, accept);
            }
        }
        if top == SHARED_EMPTY {
            return Ok(None);
        }
        let mut s = self.lock();
        let Some(front) = s.front() else {
            drop(s);
            return self.take_stashed(stash, accept);
        };
        if stash
            .entries
            .front()
            .is_some_and(|e| e.header.priority >= front.header.priority)
        {
            drop(s);
            return self.take_stashed(stash, accept);
        }
        if !accept(&front.header) {
            return Err(front.header);
        }
        if !stash.entries.is_empty() {
            // A higher priority arrived after the batch: it goes first.
            let e = s.pop();
            self.publish_top(&s);
            drop(s);
            self.made_room();
            return Ok(e);
        }
        for (_, q) in s.queues.iter_mut() {
            stash.entries.extend(q.drain(..));
        }
        s.stash_bound = s.len;
        s.len = 0;
        // Before the shared lock is released: a push near the bound counts the stash by it.
        self.stash_len.store(stash.entries.len(), Ordering::SeqCst);
        self.shared_top.store(SHARED_EMPTY, Ordering::Release);
        drop(s);
        self.take_stashed(stash, accept)
    }

    fn take_stashed(
        &self,
        stash: &mut Stash,
        accept: &impl Fn(&Header) -> bool,
    ) -> Result<Option<Entry>, Header> {
        match stash.entries.front() {
            None => return Ok(None),
            Some(e) if !accept(&e.header) => return Err(e.header),
            Some(_) => {}
        }
        let e = stash.entries.pop_front();
        stash.taken += 1;
        self.stash_len.store(stash.entries.len(), Ordering::SeqCst);
        self.made_room();
        Ok(e)
    }

    /// Wakes a producer blocked for room, if any.
    fn made_room(&self) {
        if self.full_waiters.load(Ordering::SeqCst) > 0 {
            // Under the lock, so the wake-up cannot fall between its check and its wait.
            let _s = self.lock();
            self.not_full.notify_one();
        }
    }

    /// Like [`Inbox::try_take`], waiting up to `timeout` (None: forever) for a message.
    /// `Ok(None)` after the timeout or when the inbox is closed and empty.
    pub(crate) fn take_timeout(
        &self,
        accept: impl Fn(&Header) -> bool,
        timeout: Option<Duration>,
    ) -> Result<Option<Entry>, Header> {
        // The deadline is computed on the first wait, not before: most takes find a message.
        let mut deadline: Option<Option<Instant>> = None;
        loop {
            let mut stash = self.lock_stash();
            match self.take_from(&mut stash, &accept) {
                Ok(None) => {}
                other => return other,
            }
            let mut s = self.lock();
            // Never sleep holding the stash: producers evicting need it.
            drop(stash);
            if s.len > 0 {
                continue; // arrived since the look above
            }
            if s.closed {
                return Ok(None);
            }
            let left = match *deadline.get_or_insert_with(|| timeout.map(|t| Instant::now() + t)) {
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
            if spin > 0 {
                drop(s);
                if self.spin_until_queued(
                    Duration::from_micros(spin).min(left.unwrap_or(Duration::MAX)),
                ) {
                    continue;
                }
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

    /// Spins until something is queued (true) or `spin` has passed (false).
    fn spin_until_queued(&self, spin: Duration) -> bool {
        let start = Instant::now();
        let mut rounds = 0u32;
        while self.is_empty() {
            std::hint::spin_loop();
            rounds += 1;
            // Reading the clock costs more than a spin: look at it now and then.
            if rounds.is_multiple_of(64) && start.elapsed() >= spin {
                return false;
            }
        }
        true
    }

    pub(crate) fn stats(&self) -> InboxStats {
        let stash = self.lock_stash();
        let s = self.lock();
        InboxStats {
            len: s.len + stash.entries.len(),
            taken: s.stats.taken.wrapping_add(stash.taken),
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

    #[test]
    fn a_higher_priority_overtakes_a_stashed_batch() {
        let i = inbox(10, OverflowPolicy::DropNewest);
        for t in 0..3 {
            i.push(entry(5, t)).unwrap();
        }
        // The first take moves all three into the stash.
        assert_eq!(i.try_take(|_| true).unwrap().unwrap().payload, [0u8]);
        i.push(entry(9, 10)).unwrap();
        i.push(entry(5, 11)).unwrap(); // same priority as the stash: after it
        i.push(entry(1, 12)).unwrap();
        assert_eq!(i.next_type(), Some(MessageType(1)));
        assert_eq!(drain(&i), vec![10, 1, 2, 11, 12]);
        let s = i.stats();
        assert_eq!((s.accepted, s.taken, s.len), (6, 6, 0));
        assert!(i.is_empty());
    }

    #[test]
    fn the_bound_counts_stashed_and_shared_messages() {
        let i = inbox(3, OverflowPolicy::DropNewest);
        for t in 0..3 {
            i.push(entry(1, t)).unwrap();
        }
        assert_eq!(i.try_take(|_| true).unwrap().unwrap().payload, [0u8]); // stash: 1, 2
        i.push(entry(1, 3)).unwrap();
        assert_eq!(i.push(entry(9, 4)), Err(PushError::Full));
        assert_eq!(
            (i.len(), i.stats().len, i.stats().dropped_newest),
            (3, 3, 1)
        );
        assert!(!i.is_empty());
        assert_eq!(drain(&i), vec![1, 2, 3]);
        assert!(i.is_empty());
    }

    #[test]
    fn drop_oldest_evicts_from_the_stash_first_on_a_tie() {
        let i = inbox(3, OverflowPolicy::DropOldest);
        for t in 0..3 {
            i.push(entry(1, t)).unwrap();
        }
        assert_eq!(i.try_take(|_| true).unwrap().unwrap().payload, [0u8]); // stash: 1, 2
        i.push(entry(1, 3)).unwrap(); // room: 3 queued
        i.push(entry(1, 4)).unwrap(); // full: evicts 1 (stashed, oldest)
        i.push(entry(0, 5)).unwrap_err(); // everything outranks it
        i.push(entry(7, 6)).unwrap(); // evicts 2 (stashed)
        assert_eq!(drain(&i), vec![6, 3, 4]);
        let s = i.stats();
        assert_eq!((s.dropped_oldest, s.dropped_newest, s.len), (2, 1, 0));
        assert_eq!(s.accepted, s.taken + s.dropped_oldest);
    }

    #[test]
    fn a_blocked_push_is_woken_by_a_take_from_the_stash() {
        let i = std::sync::Arc::new(inbox(
            2,
            OverflowPolicy::Block {
                timeout: Duration::from_secs(10),
            },
        ));
        i.push(entry(1, 0)).unwrap();
        i.push(entry(1, 1)).unwrap();
        assert_eq!(i.try_take(|_| true).unwrap().unwrap().payload, [0u8]); // stash: 1
        i.push(entry(1, 2)).unwrap(); // full again
        let i2 = i.clone();
        let started = Instant::now();
        let pusher = std::thread::spawn(move || i2.push(entry(1, 3)));
        std::thread::sleep(Duration::from_millis(20));
        assert_eq!(i.try_take(|_| true).unwrap().unwrap().payload, [1u8]);
        assert_eq!(pusher.join().unwrap(), Ok(()));
        assert!(started.elapsed() < Duration::from_secs(5));
        assert_eq!(drain(&i), vec![2, 3]);
    }

    /// Producers on several threads, one consumer: nothing lost or duplicated, and each
    /// producer's messages of one priority come out in the order sent.
    #[test]
    fn concurrent_producers_keep_per_priority_order() {
        const PRODUCERS: u8 = 3;
        const EACH: u32 = 20_000;
        let i = std::sync::Arc::new(inbox(
            64,
            OverflowPolicy::Block {
                timeout: Duration::from_secs(30),
            },
        ));
        let producers: Vec<_> = (0..PRODUCERS)
            .map(|p| {
                let i = i.clone();
                std::thread::spawn(move || {
                    for n in 0..EACH {
                        let mut e = entry(((n * 7 + u32::from(p)) % 3) as u8, p);
                        e.payload =
                            PayloadBuf::copy_from_slice(&[&[p][..], &n.to_le_bytes()].concat());
                        i.push(e).unwrap();
                    }
                })
            })
            .collect();
        let mut last = std::collections::HashMap::new();
        let mut got = 0u32;
        while got < u32::from(PRODUCERS) * EACH {
            let e = i
                .take_timeout(|_| true, Some(Duration::from_secs(30)))
                .unwrap()
                .expect("a message within 30 s");
            let (p, n) = (
                e.payload[0],
                u32::from_le_bytes(e.payload[1..5].try_into().unwrap()),
            );
            let key = (p, e.header.priority.0);
            if let Some(prev) = last.insert(key, n) {
                assert!(
                    n > prev,
                    "producer {p} priority {}: {n} after {prev}",
                    key.1
                );
            }
            got += 1;
        }
        for p in producers {
            p.join().unwrap();
        }
        let s = i.stats();
        assert_eq!(
            (s.accepted, s.taken, s.dropped(), s.len),
            (60_000, 60_000, 0, 0)
        );
    }
}

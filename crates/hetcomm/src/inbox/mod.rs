//! A module's inbox: bounded, ordered by priority then arrival, with an explicit overflow
//! policy and exact drop counters.

use parking_lot::{Condvar, Mutex, MutexGuard};
use std::collections::VecDeque;
use std::sync::atomic::{AtomicBool, AtomicU16, AtomicU64, AtomicUsize, Ordering};
use std::time::{Duration, Instant};

use hetcomm_config::{InboxConfig, OverflowPolicy};

use crossbeam_utils::CachePadded;
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
    /// Messages from a link refused at once because the inbox was full under `block`: a link
    /// is never stopped waiting for room (its socket would stop being read and the kernel
    /// would drop frames nobody counts). Acknowledged senders are answered "inbox full".
    pub refused_from_link: u64,
    /// Messages queued now.
    pub len: usize,
    /// The bound.
    pub capacity: usize,
}

impl InboxStats {
    /// Every message lost to overflow, whatever the policy.
    pub fn dropped(&self) -> u64 {
        self.dropped_oldest + self.dropped_newest + self.dropped_after_wait + self.refused_from_link
    }
}

/// The consumers' side: every message moved out of the intake, sorted by priority, then
/// arrival. Producers lock it only when the inbox is (nearly) full.
#[derive(Default)]
struct Stash {
    /// One FIFO per priority in use, highest priority first. Emptied queues stay (a fleet uses
    /// a handful of priorities), so the common insert is a short scan and a `push_back`.
    queues: Vec<(u8, VecDeque<Entry>)>,
    len: usize,
    taken: u64,
    dropped_oldest: u64,
    dropped_newest: u64,
    dropped_after_wait: u64,
    refused_from_link: u64,
    /// Places freed (taken or evicted) since [`Shared::counted`] was last lowered: they are
    /// given back in batches, so a consumer does not write a line producers read per message.
    unreleased: usize,
    /// Producers waiting for room (`block` policy).
    full_waiters: usize,
    /// The intake's vector from the last drain, emptied: swapped in at the next drain, so a
    /// steady stream allocates nothing.
    spare: Vec<Entry>,
}

impl Stash {
    fn insert(&mut self, e: Entry) {
        let at = self.insert_queue(e.header.priority.0);
        self.queues[at].1.push_back(e);
        self.len += 1;
    }

    /// The index of priority `prio`'s queue, made if it is the first of that priority.
    fn insert_queue(&mut self, prio: u8) -> usize {
        match self.queues.iter().position(|(p, _)| *p <= prio) {
            Some(i) if self.queues[i].0 == prio => i,
            Some(i) => {
                self.queues.insert(i, (prio, VecDeque::new()));
                i
            }
            None => {
                self.queues.push((prio, VecDeque::new()));
                self.queues.len() - 1
            }
        }
    }

    fn front(&self) -> Option<&Entry> {
        self.queues.iter().find_map(|(_, q)| q.front())
    }

    fn pop(&mut self) -> Option<Entry> {
        let e = self.queues.iter_mut().find_map(|(_, q)| q.pop_front())?;
        self.len -= 1;
        Some(e)
    }

    /// Sorts a batch taken from the intake in, and keeps its vector for the next swap
    /// (unless a burst made it large: its memory goes back then).
    fn put_batch(&mut self, mut batch: Vec<Entry>) {
        if let Some(first) = batch.first() {
            let prio = first.header.priority.0;
            if self.len == 0 && batch.iter().all(|e| e.header.priority.0 == prio) {
                // The common case, a stream of one priority into an empty stash: the vector
                // becomes that priority's queue as it is, and the queue's emptied buffer the
                // spare, with nothing moved.
                let at = self.insert_queue(prio);
                let q = &mut self.queues[at].1;
                self.len = batch.len();
                batch = Vec::from(std::mem::replace(q, VecDeque::from(batch)));
            } else {
                for e in batch.drain(..) {
                    self.insert(e);
                }
            }
        }
        if batch.capacity() <= SPARE_MAX {
            self.spare = batch;
        }
    }

    /// Evicts the oldest message of the lowest priority queued, if that priority is at most
    /// `prio`.
    fn evict_for(&mut self, prio: u8) -> bool {
        let Some((lowest, q)) = self.queues.iter_mut().rev().find(|(_, q)| !q.is_empty()) else {
            return false;
        };
        if *lowest > prio {
            return false;
        }
        q.pop_front();
        self.len -= 1;
        self.dropped_oldest += 1;
        true
    }
}

/// The producers' side: arrivals not yet seen by a consumer, in order.
struct Intake {
    /// Written by producers at every push: on a line of its own.
    queue: CachePadded<Mutex<Vec<Entry>>>,
    /// The highest priority in the queue, plus one (0: empty); stored under the lock, and
    /// only when it changes: once per batch in a stream of one priority. Consumers look at
    /// it at every take without the lock, so it has a line of its own that producers leave
    /// alone (a line written at every push would move between the cores at every message).
    /// A consumer whose stash front is at least that takes from the stash without locking
    /// the intake, so a consumer that lags takes whole batches touching nothing producers
    /// write.
    top: CachePadded<AtomicU16>,
}

/// What consumers publish for producers, who read it at every push; written rarely.
struct Shared {
    /// At least the number of messages in the stash: raised (under the intake lock) when a
    /// consumer moves the intake into the stash, lowered in batches as messages are taken.
    /// A producer counts `counted` plus the intake's length against the bound.
    counted: AtomicUsize,
    /// Consumers about to sleep or asleep in `take_timeout`: a producer signals only when
    /// someone sleeps, since every signal is a system call. Raised under the intake lock.
    sleepers: AtomicUsize,
    closed: AtomicBool,
}

/// Entries an empty intake makes room for at its first push.
const INTAKE_FIRST: usize = 32;

/// The largest intake vector (in entries) a consumer keeps for reuse.
const SPARE_MAX: usize = 1024;

/// Spins of a waiter's short look before it sleeps ([`Inbox::spin_until_queued`]).
const BRIEF_POLL_SPINS: u32 = 40;

/// Why a push was refused.
#[derive(Debug, PartialEq, Eq)]
pub(crate) enum PushError {
    Full,
    Closed,
}

/// A bounded priority inbox with many producers and (usually) one consumer.
///
/// A producer locks the `intake`, appends to its vector and unlocks: a short critical
/// section with no allocation in a steady stream. A consumer locks the `stash`; when the
/// stash holds nothing that ranks at least as high as the intake's best, it swaps the
/// intake's whole vector for an empty one (one pass through the intake lock per batch, not
/// per message) and sorts the batch into the stash by priority, then arrival. So priority
/// order is exact for every message pushed before the take.
///
/// The bound: a producer counts the intake's length plus [`Shared::counted`], which is at
/// least the stash's length. Freed places are given back in batches; a producer that finds
/// the inbox full takes the stash lock, collects them and looks again before it applies
/// the overflow policy, so the bound and the counters are exact. Lock order: `stash`, then
/// `intake`.
pub(crate) struct Inbox {
    config: InboxConfig,
    intake: Intake,
    shared: CachePadded<Shared>,
    stash: CachePadded<Mutex<Stash>>,
    /// [`Stash::len`] as last stored by a consumer, for the lock-free [`Inbox::is_empty`]:
    /// on its own line, which producers never touch.
    stash_len: CachePadded<AtomicUsize>,
    /// How many freed places a consumer gathers before giving them back.
    release_batch: usize,
    /// How long a waiter spins before it sleeps on the condition variable (µs; 0: never).
    spin_us: AtomicU64,
    /// Both used with the stash lock.
    not_empty: Condvar,
    not_full: Condvar,
}

impl Inbox {
    pub(crate) fn new(config: InboxConfig) -> Self {
        let capacity = config.capacity.max(1);
        Inbox {
            config: InboxConfig { capacity, ..config },
            intake: Intake {
                queue: CachePadded::new(Mutex::new(Vec::new())),
                top: CachePadded::new(AtomicU16::new(0)),
            },
            shared: CachePadded::new(Shared {
                counted: AtomicUsize::new(0),
                sleepers: AtomicUsize::new(0),
                closed: AtomicBool::new(false),
            }),
            stash: CachePadded::new(Mutex::new(Stash::default())),
            stash_len: CachePadded::new(AtomicUsize::new(0)),
            // A producer may find the inbox full up to this many places early (it then
            // collects them under the lock): an eighth of the bound at most.
            release_batch: (capacity / 8).clamp(1, 64),
            spin_us: AtomicU64::new(0),
            not_empty: Condvar::new(),
            not_full: Condvar::new(),
        }
    }

    fn lock_stash(&self) -> MutexGuard<'_, Stash> {
        self.stash.lock()
    }

    fn lock_intake(&self) -> MutexGuard<'_, Vec<Entry>> {
        self.intake.queue.lock()
    }

    fn is_closed(&self) -> bool {
        self.shared.closed.load(Ordering::Acquire)
    }

    /// Swaps the intake's vector (locked by the caller) for the stash's spare one, and
    /// counts its messages as the stash's before the intake lock is released: a producer
    /// never sees them in neither count. The caller sorts them in with [`Stash::put_batch`].
    fn take_intake(&self, stash: &mut Stash, queue: &mut Vec<Entry>) -> Vec<Entry> {
        let mut batch = std::mem::take(&mut stash.spare);
        std::mem::swap(queue, &mut batch);
        self.intake.top.store(0, Ordering::Relaxed);
        self.count_at_least(stash.len + batch.len());
        batch
    }

    /// Raises [`Shared::counted`] to `held` messages in the stash (intake and stash locked),
    /// writing the line producers read only when it must.
    fn count_at_least(&self, held: usize) {
        if self.shared.counted.load(Ordering::Relaxed) < held {
            self.shared.counted.store(held, Ordering::Release);
        }
    }

    /// Moves everything in the intake into the stash (locked by the caller).
    fn drain(&self, stash: &mut Stash) {
        if self.intake.top.load(Ordering::Acquire) == 0 {
            return;
        }
        let batch = {
            let mut queue = self.lock_intake();
            self.take_intake(stash, &mut queue)
        };
        stash.put_batch(batch);
    }

    /// Gives freed places back to producers: all of them, or once a batch has gathered.
    fn release(&self, stash: &mut Stash, all: bool) {
        if stash.unreleased > 0 && (all || stash.unreleased >= self.release_batch) {
            // Every write of `counted` is made under the stash lock, and a drain inserts what
            // it counted before it lets go of that lock: this is the stash's exact length.
            self.shared.counted.store(stash.len, Ordering::Release);
            stash.unreleased = 0;
        }
    }

    fn publish_len(&self, stash: &Stash) {
        if self.stash_len.load(Ordering::Relaxed) != stash.len {
            self.stash_len.store(stash.len, Ordering::Release);
        }
    }

    /// Puts a message in, applying the overflow policy (`block` waits for room on the
    /// caller's thread: use this for senders of the same process).
    pub(crate) fn push(&self, e: Entry) -> Result<(), PushError> {
        self.push_with(e, true)
    }

    /// Puts a message that came from a link in: like [`push`](Inbox::push), except that under
    /// `block` a full inbox refuses it at once (counted in
    /// [`InboxStats::refused_from_link`]) instead of stopping the link's reader.
    pub(crate) fn push_from_link(&self, e: Entry) -> Result<(), PushError> {
        self.push_with(e, false)
    }

    /// Puts messages of this process in, in order, as [`push`](Inbox::push) would one by one,
    /// through the intake lock once for as many as there is room for; `result` gets each
    /// one's answer, in order.
    pub(crate) fn push_many(
        &self,
        entries: impl ExactSizeIterator<Item = Entry>,
        mut result: impl FnMut(Result<(), PushError>),
    ) {
        let mut entries = entries;
        let mut queue = self.lock_intake();
        if self.is_closed() {
            drop(queue);
            entries.for_each(|_| result(Err(PushError::Closed)));
            return;
        }
        let room = self
            .config
            .capacity
            .saturating_sub(queue.len() + self.shared.counted.load(Ordering::Acquire));
        let fits = room.min(entries.len());
        if fits > 0 {
            queue.reserve(fits.max(INTAKE_FIRST));
            let mut top = self.intake.top.load(Ordering::Relaxed);
            for e in entries.by_ref().take(fits) {
                top = top.max(u16::from(e.header.priority.0) + 1);
                queue.push(e);
                result(Ok(()));
            }
            if self.intake.top.load(Ordering::Relaxed) < top {
                self.intake.top.store(top, Ordering::Release);
            }
        }
        let wake = fits > 0 && self.shared.sleepers.load(Ordering::Relaxed) > 0;
        drop(queue);
        if wake {
            // As in `push_with`.
            drop(self.lock_stash());
            self.not_empty.notify_one();
        }
        // The rest found the inbox full: the overflow policy, one by one.
        for e in entries {
            result(self.push_when_full(e, true));
        }
    }

    fn push_with(&self, e: Entry, may_wait: bool) -> Result<(), PushError> {
        let mut queue = self.lock_intake();
        if self.is_closed() {
            return Err(PushError::Closed);
        }
        if queue.len() + self.shared.counted.load(Ordering::Acquire) < self.config.capacity {
            let top = u16::from(e.header.priority.0) + 1;
            if self.intake.top.load(Ordering::Relaxed) < top {
                self.intake.top.store(top, Ordering::Release);
            }
            if queue.capacity() == 0 {
                // A first block that holds a burst, rather than growing by copying from 4.
                queue.reserve(INTAKE_FIRST);
            }
            queue.push(e);
            // Read under the intake lock, under which a consumer registers before it sleeps:
            // either it saw this message, or this sees it.
            let wake = self.shared.sleepers.load(Ordering::Relaxed) > 0;
            drop(queue);
            if wake {
                // The sleeper registered with the stash locked and holds that lock until it
                // waits: passing through the lock puts this signal after its wait began.
                // Signalled after the lock is released, so the woken thread does not block
                // on it.
                drop(self.lock_stash());
                self.not_empty.notify_one();
            }
            return Ok(());
        }
        drop(queue);
        self.push_when_full(e, may_wait)
    }

    /// A push that found no place: collects the places consumers have freed but not given
    /// back, then applies the overflow policy if the inbox is still full. The intake stays
    /// locked from the look to the insertion, so the bound is exact.
    fn push_when_full(&self, e: Entry, may_wait: bool) -> Result<(), PushError> {
        let mut stash = self.lock_stash();
        let mut deadline = None;
        loop {
            if self.is_closed() {
                return Err(PushError::Closed);
            }
            let waited_enough = deadline.is_some_and(|d| Instant::now() >= d);
            // A blocked producer resumes once a batch of places is free (or the inbox is
            // empty, or it would give up): resuming at every take would make producer and
            // consumer fight for this lock per message while the inbox stays full.
            let collect = !matches!(self.config.overflow, OverflowPolicy::Block { .. })
                || !may_wait
                || stash.unreleased >= self.release_batch
                || stash.len == 0
                || waited_enough;
            if collect {
                self.release(&mut stash, true);
            }
            let mut queue = self.lock_intake();
            // Everything that arrived before goes ahead of this message (and competes for
            // eviction); the stash is then the whole inbox.
            let batch = self.take_intake(&mut stash, &mut queue);
            stash.put_batch(batch);
            let queued = if collect {
                stash.len
            } else {
                self.shared.counted.load(Ordering::Relaxed)
            };
            let admitted = if queued < self.config.capacity {
                true
            } else {
                match self.config.overflow {
                    OverflowPolicy::DropNewest => {
                        stash.dropped_newest += 1;
                        return Err(PushError::Full);
                    }
                    // One out, one in: the evicted message's place is the newcomer's.
                    OverflowPolicy::DropOldest if stash.evict_for(e.header.priority.0) => true,
                    OverflowPolicy::DropOldest => {
                        stash.dropped_newest += 1;
                        return Err(PushError::Full);
                    }
                    OverflowPolicy::Block { .. } if !may_wait => {
                        stash.refused_from_link += 1;
                        return Err(PushError::Full);
                    }
                    OverflowPolicy::Block { .. } if waited_enough => {
                        stash.dropped_after_wait += 1;
                        return Err(PushError::Full);
                    }
                    OverflowPolicy::Block { .. } => false,
                }
            };
            if admitted {
                // Straight into the stash, behind everything that arrived before.
                stash.insert(e);
                self.count_at_least(stash.len);
                drop(queue);
                self.publish_len(&stash);
                // A sleeping consumer looked at the stash under this lock before it slept.
                if self.shared.sleepers.load(Ordering::Relaxed) > 0 {
                    self.not_empty.notify_one();
                }
                return Ok(());
            }
            drop(queue);
            let OverflowPolicy::Block { timeout } = self.config.overflow else {
                unreachable!("only a blocking push waits for room");
            };
            let deadline = *deadline.get_or_insert_with(|| Instant::now() + timeout);
            let left = deadline.saturating_duration_since(Instant::now());
            stash.full_waiters += 1;
            self.not_full.wait_for(&mut stash, left);
            stash.full_waiters -= 1;
        }
    }

    pub(crate) fn len(&self) -> usize {
        let mut stash = self.lock_stash();
        self.drain(&mut stash);
        self.publish_len(&stash);
        stash.len
    }

    /// Whether anything is queued (no lock taken).
    pub(crate) fn is_empty(&self) -> bool {
        self.intake.top.load(Ordering::Acquire) == 0 && self.stash_len.load(Ordering::Acquire) == 0
    }

    pub(crate) fn next_type(&self) -> Option<MessageType> {
        let mut stash = self.lock_stash();
        self.drain(&mut stash);
        self.publish_len(&stash);
        stash.front().map(|e| e.header.message_type)
    }

    /// Takes the front message if `accept` agrees (it sees the header), without waiting.
    /// `Ok(None)`: empty. `Err(header)`: refused, left in place.
    pub(crate) fn try_take(
        &self,
        accept: impl Fn(&Header) -> bool,
    ) -> Result<Option<Entry>, Header> {
        let mut stash = self.lock_stash();
        self.take_locked(&mut stash, &accept)
    }

    /// Takes up to `max` messages, highest priority first, without waiting, handing each to
    /// `each`: the stash is locked once for all of them. Returns how many.
    pub(crate) fn take_up_to(&self, max: usize, mut each: impl FnMut(Entry)) -> usize {
        let mut stash = self.lock_stash();
        let mut taken = 0;
        while taken < max {
            match self.take_locked(&mut stash, &|_: &Header| true) {
                Ok(Some(e)) => each(e),
                _ => break,
            }
            taken += 1;
        }
        taken
    }

    /// One take with the stash locked.
    fn take_locked(
        &self,
        stash: &mut Stash,
        accept: &impl Fn(&Header) -> bool,
    ) -> Result<Option<Entry>, Header> {
        let top = self.intake.top.load(Ordering::Acquire);
        // The intake's newest arrivals come after the stash unless they rank higher.
        if stash
            .front()
            .is_none_or(|e| u16::from(e.header.priority.0) + 1 < top)
        {
            self.drain(stash);
        }
        match stash.front() {
            None => {
                self.publish_len(stash);
                return Ok(None);
            }
            Some(e) if !accept(&e.header) => {
                self.publish_len(stash);
                return Err(e.header);
            }
            Some(_) => {}
        }
        let e = stash.pop();
        stash.taken += 1;
        stash.unreleased += 1;
        // A blocked producer is woken once a batch of places is free (or nothing is left),
        // not at every take: each wake-up is a system call.
        if stash.full_waiters > 0 && (stash.unreleased >= self.release_batch || stash.len == 0) {
            self.release(stash, true);
            self.not_full.notify_all();
        } else {
            self.release(stash, false);
        }
        self.publish_len(stash);
        Ok(e)
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
        let mut spun = false;
        let mut stash = self.lock_stash();
        loop {
            match self.take_locked(&mut stash, &accept) {
                Ok(None) => {}
                other => return other,
            }
            if self.is_closed() {
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
            // Before sleeping: the configured spin, or else one short look (a producer that
            // keeps sending refills the inbox far sooner than a sleep and a wake-up take).
            let spin = self.spin();
            let look = if !spin.is_zero() {
                Some(Some(spin.min(left.unwrap_or(Duration::MAX))))
            } else if !spun {
                spun = true;
                Some(None)
            } else {
                None
            };
            if let Some(limit) = look {
                // Never spin holding the stash: producers of a full inbox need it.
                drop(stash);
                let came = self.spin_until_queued(limit);
                stash = self.lock_stash();
                if came {
                    continue;
                }
            }
            // Registered under the intake lock: a push either came before and is seen here,
            // or sees this sleeper and signals (see `push`).
            let sleep = {
                let queue = self.lock_intake();
                let sleep = queue.is_empty() && stash.len == 0 && !self.is_closed();
                if sleep {
                    self.shared.sleepers.fetch_add(1, Ordering::Relaxed);
                }
                sleep
            };
            if sleep {
                match left {
                    None => self.not_empty.wait(&mut stash),
                    Some(left) => {
                        self.not_empty.wait_for(&mut stash, left);
                    }
                }
                self.shared.sleepers.fetch_sub(1, Ordering::Relaxed);
            }
        }
    }

    /// Makes waiters spin up to `spin` for a message before they sleep: a message that comes
    /// meanwhile is taken without a wake-up (a system call and a reschedule, microseconds), at
    /// the price of a busy core while spinning.
    pub(crate) fn set_spin(&self, spin: Duration) {
        let us = u64::try_from(spin.as_micros()).unwrap_or(u64::MAX);
        self.spin_us.store(us, Ordering::Relaxed);
    }

    /// How long a waiter spins before it sleeps ([`Inbox::set_spin`]).
    pub(crate) fn spin(&self) -> Duration {
        Duration::from_micros(self.spin_us.load(Ordering::Relaxed))
    }

    /// Spins until something is queued or the inbox closed (true), or until `limit` has
    /// passed (false); `None`: a short look of [`BRIEF_POLL_SPINS`] spins (about a
    /// microsecond here), with no clock read.
    fn spin_until_queued(&self, limit: Option<Duration>) -> bool {
        let start = limit.map(|limit| (Instant::now(), limit));
        let mut rounds = 0u32;
        while self.is_empty() && !self.shared.closed.load(Ordering::Relaxed) {
            for _ in 0..16 {
                std::hint::spin_loop();
            }
            rounds += 1;
            let done = match start {
                // Reading the clock costs more than a spin: look at it now and then.
                Some((start, limit)) => rounds.is_multiple_of(64) && start.elapsed() >= limit,
                None => rounds >= BRIEF_POLL_SPINS,
            };
            if done {
                return false;
            }
        }
        true
    }

    pub(crate) fn stats(&self) -> InboxStats {
        let mut stash = self.lock_stash();
        self.drain(&mut stash);
        self.publish_len(&stash);
        InboxStats {
            // Every accepted message was taken, evicted, or is still here.
            accepted: stash.taken + stash.dropped_oldest + stash.len as u64,
            taken: stash.taken,
            dropped_oldest: stash.dropped_oldest,
            dropped_newest: stash.dropped_newest,
            dropped_after_wait: stash.dropped_after_wait,
            refused_from_link: stash.refused_from_link,
            len: stash.len,
            capacity: self.config.capacity,
        }
    }

    /// Wakes every waiter; later pushes fail and waits return what is left.
    pub(crate) fn close(&self) {
        self.shared.closed.store(true, Ordering::SeqCst);
        let _stash = self.lock_stash();
        self.not_empty.notify_all();
        self.not_full.notify_all();
    }
}

#[cfg(test)]
mod tests;

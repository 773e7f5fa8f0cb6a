//! One system's harness: its taps, its scheduled faults, and the queue of what is held back
//! for later (delayed messages and frames, scheduled injections).
//!
//! The queue is driven by the simulator in virtual time (`SimFleet` asks for
//! [`SystemHarness::next_due`] and calls [`SystemHarness::fire_due`], in time order with
//! frames and timers), or in real time by a thread the harness starts the first time
//! something is held, which stops when the system closes.

use parking_lot::{Condvar, Mutex, RwLock};
use std::cmp::Reverse;
use std::collections::BinaryHeap;
use std::sync::atomic::{AtomicBool, AtomicU64, AtomicUsize, Ordering};
use std::sync::{Arc, OnceLock, Weak};
use std::thread::JoinHandle;
use std::time::Duration;

use hetcomm_core::wire::AckStatus;
use hetcomm_core::{Header, MessageType, ModuleId, PayloadBuf, SystemId, Time};

use super::faults::{FaultVerdict, Faults};
use super::{
    Body, HarnessStats, InjectError, TapAction, TapError, TapMessage, TapVerdict, TopicValue,
};
use crate::runtime::{ModuleCore, Source, SystemCore};

mod held;

/// Whether the header a tap left points at another module than the one looked up.
fn m_header_changed(h: &Header, module: Option<&ModuleCore>) -> bool {
    module.is_some_and(|m| m.id != h.destination.module)
}

/// A resolved path ([`super::TapPath`] with ids).
#[derive(Clone, Debug, PartialEq, Eq)]
pub(crate) enum Target {
    Topic(Arc<str>),
    Messages(MessageMatch),
}

/// Which messages arriving at a system a tap takes.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub(crate) struct MessageMatch {
    pub from: Option<SystemId>,
    pub to: SystemId,
    pub module: Option<ModuleId>,
    pub message_type: Option<MessageType>,
}

/// How many message taps of a system get a filter slot of their own.
const FILTERS: usize = 8;

/// Width of each of the three fields of a [`PathFilter`] word, in bits.
const FIELD: u32 = 21;
/// A field with every bit set: "any value".
const ANY: u64 = (1 << FIELD) - 1;

/// The bit of value `v` in a field.
#[inline(always)]
fn field_bit(v: u32) -> u64 {
    1 << (v % FIELD)
}

/// A message's path as a filter key: one bit in each field (source system, destination
/// module, message type).
#[inline(always)]
fn path_key(h: &Header) -> u64 {
    field_bit(u32::from(h.source.system.0))
        | field_bit(u32::from(h.destination.module.0)) << FIELD
        | field_bit(h.message_type.0) << (2 * FIELD)
}

impl MessageMatch {
    /// The filter bits of the paths this match takes (see [`SystemHarness::tapped_for`]).
    fn filter_bits(&self) -> u64 {
        let f = |v: Option<u32>| v.map_or(ANY, field_bit);
        f(self.from.map(|s| u32::from(s.0)))
            | f(self.module.map(|m| u32::from(m.0))) << FIELD
            | f(self.message_type.map(|t| t.0)) << (2 * FIELD)
    }

    #[inline]
    fn matches(&self, h: &Header) -> bool {
        self.from.is_none_or(|f| f == h.source.system)
            && self.module.is_none_or(|m| m == h.destination.module)
            && self.message_type.is_none_or(|t| t == h.message_type)
    }

    /// Whether two matches can take the same message.
    fn overlaps(&self, o: &MessageMatch) -> bool {
        fn meet<T: PartialEq>(a: Option<T>, b: Option<T>) -> bool {
            match (a, b) {
                (Some(a), Some(b)) => a == b,
                _ => true,
            }
        }
        self.to == o.to
            && meet(self.from, o.from)
            && meet(self.module, o.module)
            && meet(self.message_type, o.message_type)
    }
}

struct TapEntry {
    id: u64,
    target: Target,
    action: TapAction,
    window: Option<(Time, Time)>,
}

impl TapEntry {
    #[inline]
    fn active(&self, now: Time) -> bool {
        self.window.is_none_or(|(a, b)| a <= now && now < b)
    }
}

/// A scheduled action: run on the system's harness thread (or the simulator's) at its time.
pub(crate) type Action = Box<dyn FnOnce(&SystemCore, Time) + Send>;

/// Something held back until its time.
pub(crate) enum Held {
    /// A message for one of this system's modules.
    Deliver { header: Header, payload: PayloadBuf },
    /// A value for a topic's subscribers.
    Topic { topic: Arc<str>, value: TopicValue },
    /// A frame for link `link`, to system `to` (a fault's latency).
    Frame {
        link: usize,
        to: SystemId,
        bytes: Vec<u8>,
    },
    /// A scheduled action (an injection, a scripted value).
    Run(Action),
}

struct Due {
    at: Time,
    id: u64,
    item: Held,
}

impl PartialEq for Due {
    fn eq(&self, o: &Self) -> bool {
        (self.at, self.id) == (o.at, o.id)
    }
}
impl Eq for Due {}
impl PartialOrd for Due {
    fn partial_cmp(&self, o: &Self) -> Option<std::cmp::Ordering> {
        Some(self.cmp(o))
    }
}
impl Ord for Due {
    fn cmp(&self, o: &Self) -> std::cmp::Ordering {
        (self.at, self.id).cmp(&(o.at, o.id))
    }
}

#[derive(Default)]
struct Counters {
    tapped: AtomicU64,
    dropped: AtomicU64,
    delayed: AtomicU64,
    duplicated: AtomicU64,
    modified: AtomicU64,
    replaced: AtomicU64,
    injected: AtomicU64,
    fault_dropped: AtomicU64,
    fault_delayed: AtomicU64,
    lost_on_close: AtomicU64,
}

fn bump(c: &AtomicU64, n: u64) {
    c.fetch_add(n, Ordering::Relaxed);
}

/// Numbers the lists of taps of every system of the process (0: never set).
static TAP_VERSIONS: AtomicU64 = AtomicU64::new(1);

/// Snapshot of taps type.
type TapList = Arc<[Arc<TapEntry>]>;

/// A version of a tap list and a weak reference to it.
type SeenTaps = (u64, Option<Weak<[Arc<TapEntry>]>>);

thread_local! {
    /// The last list of taps this thread delivered through, with its version. Weak: a list
    /// replaced or a system closed frees its taps (and what their functions hold) at once.
    static TAPS_SEEN: std::cell::RefCell<SeenTaps> =
        const { std::cell::RefCell::new((0, None)) };
}

/// One system's taps, faults and held items. A field of `SystemCore`.
#[derive(Default)]
pub(crate) struct SystemHarness {
    /// The filter bits of each message tap here, the first [`FILTERS`]` - 1` taps one slot
    /// each and the rest merged into the last: the gate every delivery checks
    /// ([`SystemHarness::tapped_for`]).
    filters: [AtomicU64; FILTERS],
    /// How many of `filters` are in use (0: no message tap).
    filters_used: AtomicUsize,
    /// Which list of taps is current (see [`SystemHarness::with_taps`]); 0: none yet.
    version: AtomicU64,
    /// Some tap sits on a topic path here: the gate every publish checks.
    topic_tapped: AtomicBool,
    /// A fault schedule is installed: the gate every frame checks.
    faulted: AtomicBool,
    taps: RwLock<TapList>,
    next_tap: AtomicU64,
    faults: OnceLock<Faults>,
    queue: Mutex<BinaryHeap<Reverse<Due>>>,
    next_due_id: AtomicU64,
    wake: Condvar,
    /// Set when the system starts: its core, and whether a thread must drive the queue.
    owner: OnceLock<(Weak<SystemCore>, bool)>,
    driver: Mutex<Option<JoinHandle<()>>>,
    counters: Counters,
    /// Sequence numbers of injected messages (their own space: the top bit set).
    inject_seq: AtomicU64,
    /// The system's topics ([`crate::node`]).
    pub(crate) topics: crate::node::Topics,
}

impl SystemHarness {
    /// Called when the system starts: `realtime` says whether a thread drives the queue.
    pub(crate) fn attach(&self, core: Weak<SystemCore>, realtime: bool) {
        let _ = self.owner.set((core, realtime));
    }

    /// Whether a message tap may sit on `h`'s path. Without message taps: one load. With
    /// some: each tap has a filter word with, in three fields, the bit of its source system,
    /// destination module and message type (every bit of a field it leaves open), and a
    /// message goes to the taps only when its own three bits are all set in one tap's word.
    /// So a path no tap can take costs a few loads and masks (one cache line) even while
    /// other paths here are tapped; values that share a bit (ids 21 apart) or taps past the
    /// eighth (merged into one word) only send a message to the taps, which then find none
    /// for it.
    #[inline(always)]
    pub(crate) fn tapped_for(&self, h: &Header) -> bool {
        // Acquire: the slots were written before the count that covers them.
        let used = self.filters_used.load(Ordering::Acquire);
        used != 0 && self.tapped_slow(h, used)
    }

    /// [`SystemHarness::tapped_for`] once some message tap exists here.
    #[inline]
    fn tapped_slow(&self, h: &Header, used: usize) -> bool {
        let key = path_key(h);
        self.filters[..used.min(FILTERS)]
            .iter()
            .any(|f| f.load(Ordering::Relaxed) & key == key)
    }

    /// Whether any message tap is placed here (one load): when not, no message is tapped.
    #[inline(always)]
    pub(crate) fn tapping(&self) -> bool {
        self.filters_used.load(Ordering::Acquire) != 0
    }

    /// Whether a topic tap is placed here (one relaxed load).
    #[inline(always)]
    pub(crate) fn topic_tapped(&self) -> bool {
        self.topic_tapped.load(Ordering::Relaxed)
    }

    /// Whether faults are scheduled here (one relaxed load).
    #[inline(always)]
    pub(crate) fn faulted(&self) -> bool {
        self.faulted.load(Ordering::Relaxed)
    }

    pub(crate) fn add_tap(
        &self,
        target: Target,
        action: TapAction,
        window: Option<(Time, Time)>,
    ) -> Result<u64, TapError> {
        let mut taps = self.taps.write();
        if matches!(action, TapAction::Replace) {
            let clash = taps.iter().any(|t| {
                matches!(t.action, TapAction::Replace)
                    && same_path(&t.target, &target)
                    && windows_meet(t.window, window)
            });
            if clash {
                return Err(TapError::AlreadyReplaced {
                    path: format!("{target:?}"),
                });
            }
        }
        let id = self.next_tap.fetch_add(1, Ordering::Relaxed);
        let mut v: Vec<_> = taps.iter().cloned().collect();
        v.push(Arc::new(TapEntry {
            id,
            target,
            action,
            window,
        }));
        *taps = v.into();
        self.set_gates(&taps);
        Ok(id)
    }

    pub(crate) fn remove_tap(&self, id: u64) {
        let mut taps = self.taps.write();
        let v: Vec<_> = taps.iter().filter(|t| t.id != id).cloned().collect();
        *taps = v.into();
        self.set_gates(&taps);
    }

    fn set_gates(&self, taps: &[Arc<TapEntry>]) {
        // A new number from a process-wide counter: no two lists of taps of any system share
        // one, so a thread's cached copy is never taken for another's.
        self.version.store(
            TAP_VERSIONS.fetch_add(1, Ordering::Relaxed),
            Ordering::Release,
        );
        // One tap a slot; past the last, merged into it (wider, never narrower). Each slot is
        // written once, in order, and a tap that stays only moves to an earlier slot, so a
        // delivery reading the slots meanwhile still finds every tap that stays.
        let mut slots = [0u64; FILTERS];
        let mut used = 0;
        for bits in taps.iter().filter_map(|t| match &t.target {
            Target::Messages(m) => Some(m.filter_bits()),
            Target::Topic(_) => None,
        }) {
            slots[used.min(FILTERS - 1)] |= bits;
            used += 1;
        }
        for (slot, bits) in self.filters.iter().zip(slots) {
            slot.store(bits, Ordering::Relaxed);
        }
        let topic = taps.iter().any(|t| matches!(t.target, Target::Topic(_)));
        self.filters_used
            .store(used.min(FILTERS), Ordering::Release);
        self.topic_tapped.store(topic, Ordering::Release);
    }

    fn snapshot(&self) -> TapList {
        self.taps.read().clone()
    }

    pub(crate) fn stats(&self) -> HarnessStats {
        let c = &self.counters;
        let l = |a: &AtomicU64| a.load(Ordering::Relaxed);
        HarnessStats {
            tapped: l(&c.tapped),
            dropped: l(&c.dropped),
            delayed: l(&c.delayed),
            duplicated: l(&c.duplicated),
            modified: l(&c.modified),
            replaced: l(&c.replaced),
            injected: l(&c.injected),
            fault_dropped: l(&c.fault_dropped),
            fault_delayed: l(&c.fault_delayed),
            lost_on_close: l(&c.lost_on_close),
        }
    }

    /// Runs the taps of this system's message paths over a message arriving for one of its
    /// modules, then delivers it (now, later, several times, or not at all). `link`: the link
    /// it came on (None: handed over in this process). Returns what the inbox answered, or
    /// `Delivered` when the harness took the message over.
    #[cold]
    #[inline(never)]
    pub(crate) fn on_delivery(
        &self,
        core: &SystemCore,
        module: Option<&ModuleCore>,
        header: Header,
        payload: PayloadBuf,
        now: Time,
        source: Source,
    ) -> AckStatus {
        self.with_taps(|taps| {
            self.run_message_taps(taps, core, module, header, payload, now, source)
        })
    }

    /// Calls `f` with this system's taps: through this thread's weak reference to the list
    /// while the taps have not changed since (no lock: the common case of a thread
    /// delivering to one system), else from a fresh snapshot, which the thread then keeps a
    /// weak reference to.
    #[inline]
    fn with_taps<R>(&self, f: impl FnOnce(&[Arc<TapEntry>]) -> R) -> R {
        let version = self.version.load(Ordering::Acquire);
        let cached = TAPS_SEEN.with(|cache| match cache.try_borrow() {
            Ok(c) if c.0 == version => c.1.as_ref().and_then(Weak::upgrade),
            _ => None,
        });
        if let Some(taps) = cached {
            return f(&taps);
        }
        let snapshot = self.snapshot();
        TAPS_SEEN.with(|cache| {
            if let Ok(mut c) = cache.try_borrow_mut() {
                *c = (version, Some(Arc::downgrade(&snapshot)));
            }
        });
        f(&snapshot)
    }

    #[allow(clippy::too_many_arguments)] // one delivery's description
    fn run_message_taps(
        &self,
        taps: &[Arc<TapEntry>],
        core: &SystemCore,
        module: Option<&ModuleCore>,
        header: Header,
        payload: PayloadBuf,
        now: Time,
        source: Source,
    ) -> AckStatus {
        let mut msg: Option<TapMessage> = None;
        let mut delay = Duration::ZERO;
        let mut copies = 0u32;
        let mut payload = Some(payload);
        for t in taps.iter() {
            let Target::Messages(m) = &t.target else {
                continue;
            };
            if !m.matches(&header) || !t.active(now) {
                continue;
            }
            let msg = msg.get_or_insert_with(|| {
                bump(&self.counters.tapped, 1);
                TapMessage {
                    header: Some(header),
                    topic: None,
                    time: now,
                    body: Body::Bytes(payload.take().unwrap_or_default()),
                    modified: false,
                }
            });
            match self.apply(&t.action, msg, &mut delay, &mut copies) {
                Some(()) => {}
                None => return AckStatus::Delivered,
            }
        }
        let (header, payload) = match (msg, payload) {
            (None, Some(p)) => return core.arrive_untapped(module, header, p, now, source),
            (Some(m), _) => match m.body {
                Body::Bytes(b) => (m.header.unwrap_or(header), b),
                Body::Value(_) => {
                    // A modify function put a topic value on a message path: it cannot be
                    // delivered as a message.
                    bump(&self.counters.dropped, 1);
                    return AckStatus::Delivered;
                }
            },
            (None, None) => return AckStatus::Delivered,
        };
        if delay.is_zero() {
            for _ in 0..copies {
                core.deliver_untapped(header, payload.clone(), now, None);
            }
            if m_header_changed(&header, module) {
                core.deliver_untapped(header, payload, now, None)
            } else {
                core.arrive_untapped(module, header, payload, now, source)
            }
        } else {
            bump(&self.counters.delayed, 1);
            for _ in 0..=copies {
                self.hold(
                    now + delay,
                    Held::Deliver {
                        header,
                        payload: payload.clone(),
                    },
                );
            }
            AckStatus::Delivered
        }
    }

    /// Applies one tap's action; None: the message is gone (dropped or replaced).
    fn apply(
        &self,
        action: &TapAction,
        msg: &mut TapMessage,
        delay: &mut Duration,
        copies: &mut u32,
    ) -> Option<()> {
        let verdict = match action {
            TapAction::Observe(f) => {
                f(msg);
                TapVerdict::Pass
            }
            TapAction::Drop => TapVerdict::Drop,
            TapAction::Delay(d) => TapVerdict::Delay(*d),
            TapAction::Duplicate(n) => TapVerdict::Duplicate(*n),
            TapAction::Modify(f) => {
                let v = f(msg);
                if std::mem::take(&mut msg.modified) {
                    bump(&self.counters.modified, 1);
                }
                v
            }
            TapAction::Replace => {
                bump(&self.counters.replaced, 1);
                return None;
            }
        };
        match verdict {
            TapVerdict::Pass => {}
            TapVerdict::Drop => {
                bump(&self.counters.dropped, 1);
                return None;
            }
            TapVerdict::Delay(d) => *delay += d,
            TapVerdict::Duplicate(n) => {
                bump(&self.counters.duplicated, u64::from(n));
                *copies += n;
            }
        }
        Some(())
    }

    /// Runs the taps of topic `topic` over a published value; returns the values to deliver
    /// now (none, one, or copies) and holds delayed ones back.
    #[cold]
    #[inline(never)]
    pub(crate) fn on_publish(
        &self,
        topic: &Arc<str>,
        value: TopicValue,
        now: Time,
    ) -> Option<(TopicValue, u32)> {
        self.with_taps(|taps| self.run_topic_taps(taps, topic, value, now))
    }

    fn run_topic_taps(
        &self,
        taps: &[Arc<TapEntry>],
        topic: &Arc<str>,
        value: TopicValue,
        now: Time,
    ) -> Option<(TopicValue, u32)> {
        let mut msg: Option<TapMessage> = None;
        let mut delay = Duration::ZERO;
        let mut copies = 0u32;
        let mut value = Some(value);
        for t in taps.iter() {
            let Target::Topic(name) = &t.target else {
                continue;
            };
            if name != topic || !t.active(now) {
                continue;
            }
            let msg = msg.get_or_insert_with(|| {
                bump(&self.counters.tapped, 1);
                TapMessage {
                    header: None,
                    topic: Some(topic.clone()),
                    time: now,
                    body: Body::Value(value.take().expect("taken once")),
                    modified: false,
                }
            });
            self.apply(&t.action, msg, &mut delay, &mut copies)?;
        }
        let value = match (msg, value) {
            (None, Some(v)) => v,
            (Some(m), _) => match m.body {
                Body::Value(v) => v,
                Body::Bytes(b) => Arc::new(b.to_vec()) as TopicValue,
            },
            (None, None) => return None,
        };
        if delay.is_zero() {
            return Some((value, copies));
        }
        bump(&self.counters.delayed, 1);
        for _ in 0..=copies {
            self.hold(
                now + delay,
                Held::Topic {
                    topic: topic.clone(),
                    value: value.clone(),
                },
            );
        }
        None
    }
}

fn same_path(a: &Target, b: &Target) -> bool {
    match (a, b) {
        (Target::Topic(x), Target::Topic(y)) => x == y,
        (Target::Messages(x), Target::Messages(y)) => x.overlaps(y),
        _ => false,
    }
}

fn windows_meet(a: Option<(Time, Time)>, b: Option<(Time, Time)>) -> bool {
    match (a, b) {
        (Some((a0, a1)), Some((b0, b1))) => a0 < b1 && b0 < a1,
        _ => true,
    }
}

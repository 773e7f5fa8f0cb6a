//! The real-time driver: one [`SystemCore`] per opened system drives its sans-IO router with
//! the wall clock. Sends run on the caller's thread up to the link's send call; frames run on
//! the link's receive thread (or the sender's thread for in-process links); a timer thread per
//! system handles retransmission deadlines; callbacks run on a thread per module.

use rustc_hash::FxHashMap as HashMap;
use std::panic::AssertUnwindSafe;
use std::sync::atomic::{AtomicBool, AtomicU64, Ordering};
use std::sync::{Arc, Condvar, Mutex, MutexGuard, OnceLock, RwLock, Weak};
use std::thread::JoinHandle;
use std::time::{Duration, Instant};

use hetcomm_config::InboxConfig;
use hetcomm_core::wire::{AckStatus, TO_ALL_SYSTEM};
use hetcomm_core::{
    FrameBuf, Header, MessageType, ModuleId, PayloadBuf, SystemId, Time, TypeRegistry,
};
use hetcomm_link::{FrameSink, Link, LinkError, Peer};
use hetcomm_router::{
    Delivery, DeliveryToken, Event, Outcome, Router, SendId, Transmit, TransmitError,
};
use smallvec::SmallVec;

use crate::inbox::{Entry, Inbox, PushError};
use crate::observe::{Observers, OutcomeRecord, ReceiptRecord, RouteKind, Via};
use crate::reactor::{leading_here, Reactor};
use crate::received::{Envelope, RawMessage};
use crate::ticket::{OutcomeSlot, TicketSlot};
use crate::transports::Hubs;
use crossbeam_utils::CachePadded;

/// Where a system's router gets `now` from: the wall clock in the real runtime, a virtual
/// clock under the simulator.
pub trait Clock: Send + Sync + 'static {
    /// The current time.
    fn now(&self) -> Time;
}

/// The wall clock: microseconds since the UNIX epoch.
#[derive(Clone, Copy, Debug, Default)]
pub struct WallClock;

impl Clock for WallClock {
    fn now(&self) -> Time {
        Time::now_wall()
    }
}

/// The one process-wide copy of a system or module name.
///
/// Every received message and every ticket names a system; with names shared as `Arc<str>`,
/// each would bump a reference count that the sending and receiving threads both touch (a
/// cache line moving between cores per message). Names are few and live as long as the
/// fleets using them, so they are kept once for the life of the process instead: the memory
/// is bounded by the number of distinct names ever opened.
pub(crate) fn intern(name: &str) -> &'static str {
    static NAMES: OnceLock<Mutex<rustc_hash::FxHashSet<&'static str>>> = OnceLock::new();
    let mut names = NAMES
        .get_or_init(Default::default)
        .lock()
        .unwrap_or_else(|e| e.into_inner());
    if let Some(known) = names.get(name) {
        return known;
    }
    let leaked: &'static str = Box::leak(name.to_owned().into_boxed_str());
    names.insert(leaked);
    leaked
}

/// Friendly names of the fleet's systems and modules, shared by every system of a process.
#[derive(Debug)]
pub(crate) struct Directory {
    pub systems: IdNames,
    pub system_ids: HashMap<String, SystemId>,
    pub modules: IdNames,
    pub module_ids: HashMap<String, ModuleId>,
}

impl Directory {
    pub(crate) fn system_name(&self, id: SystemId) -> &'static str {
        self.systems.get(id.0)
    }
    pub(crate) fn module_name(&self, id: ModuleId) -> &'static str {
        self.modules.get(id.0)
    }
}

/// Names by numeric id: a table indexed by the id for the small ids fleets use (every
/// received message looks up two names), a map for the rest.
#[derive(Debug, Default)]
pub(crate) struct IdNames {
    dense: Vec<Option<&'static str>>,
    sparse: HashMap<u16, &'static str>,
}

/// Ids below this are looked up in [`IdNames`]' table (8 KiB on 64-bit machines at most).
const DENSE_IDS: usize = 512;

impl IdNames {
    fn get(&self, id: u16) -> &'static str {
        match self.dense.get(usize::from(id)) {
            Some(Some(name)) => name,
            _ => self
                .sparse
                .get(&id)
                .copied()
                .unwrap_or_else(|| intern(&format!("#{id}"))),
        }
    }
}

impl FromIterator<(u16, &'static str)> for IdNames {
    fn from_iter<I: IntoIterator<Item = (u16, &'static str)>>(iter: I) -> Self {
        let mut names = IdNames::default();
        for (id, name) in iter {
            let i = usize::from(id);
            if i < DENSE_IDS {
                if names.dense.len() <= i {
                    names.dense.resize(i + 1, None);
                }
                names.dense[i] = Some(name);
            } else {
                names.sparse.insert(id, name);
            }
        }
        names
    }
}

pub(crate) type Callback = Arc<dyn Fn(RawMessage) + Send + Sync>;

/// One module of one system: its inbox, its callbacks and their thread.
pub(crate) struct ModuleCore {
    pub id: ModuleId,
    pub name: &'static str,
    pub inbox: Inbox,
    callback_inbox: Inbox,
    callbacks: RwLock<HashMap<MessageType, Callback>>,
    callback_any: RwLock<Option<Callback>>,
    has_callbacks: AtomicBool,
    /// Under simulation callbacks run on the simulator's thread, at the delivery, so runs are
    /// repeatable; otherwise on the module's callback thread.
    inline_callbacks: bool,
    dispatcher: Mutex<Option<JoinHandle<()>>>,
    /// Callback invocations that panicked or failed to decode.
    pub callback_failures: AtomicU64,
    /// This module's thread is blocked reading links as the reactor's leader: a message put
    /// into its inbox by another thread must interrupt it.
    leading: AtomicBool,
}

impl ModuleCore {
    fn new(id: ModuleId, name: &'static str, inbox: InboxConfig) -> Self {
        ModuleCore {
            id,
            name,
            inbox: Inbox::new(inbox),
            callback_inbox: Inbox::new(inbox),
            callbacks: RwLock::new(HashMap::default()),
            callback_any: RwLock::new(None),
            has_callbacks: AtomicBool::new(false),
            inline_callbacks: false,
            dispatcher: Mutex::new(None),
            callback_failures: AtomicU64::new(0),
            leading: AtomicBool::new(false),
        }
    }

    fn wants_callback(&self, ty: MessageType) -> bool {
        self.has_callbacks.load(Ordering::Acquire)
            && (self
                .callbacks
                .read()
                .unwrap_or_else(|e| e.into_inner())
                .contains_key(&ty)
                || self
                    .callback_any
                    .read()
                    .unwrap_or_else(|e| e.into_inner())
                    .is_some())
    }

    /// Registers a callback for one type (or every type when `ty` is None) and starts the
    /// module's callback thread on first use.
    pub(crate) fn set_callback(
        self: &Arc<Self>,
        ty: Option<MessageType>,
        cb: Callback,
        directory: Arc<Directory>,
    ) {
        match ty {
            Some(ty) => {
                self.callbacks
                    .write()
                    .unwrap_or_else(|e| e.into_inner())
                    .insert(ty, cb);
            }
            None => *self.callback_any.write().unwrap_or_else(|e| e.into_inner()) = Some(cb),
        }
        self.has_callbacks.store(true, Ordering::Release);
        if self.inline_callbacks {
            return;
        }
        let mut dispatcher = self.dispatcher.lock().unwrap_or_else(|e| e.into_inner());
        if dispatcher.is_none() {
            let module = Arc::downgrade(self);
            let name = format!("hetcomm-cb-{}", self.name);
            let spawned = std::thread::Builder::new()
                .name(name)
                .spawn(move || dispatch_callbacks(module, directory));
            // Spawning only fails when the OS is out of threads; then callbacks stay queued
            // and counted as failures rather than the process aborting.
            match spawned {
                Ok(handle) => *dispatcher = Some(handle),
                Err(_) => {
                    self.callback_failures.fetch_add(1, Ordering::Relaxed);
                }
            }
        }
    }

    fn close(&self) {
        self.inbox.close();
        self.callback_inbox.close();
        join_unless_current(&self.dispatcher);
    }
}

impl ModuleCore {
    /// Runs the callback registered for this entry's type (or the catch-all).
    fn run_callback(&self, directory: &Directory, entry: Entry) {
        let ty = entry.header.message_type;
        let cb = self
            .callbacks
            .read()
            .unwrap_or_else(|e| e.into_inner())
            .get(&ty)
            .cloned()
            .or_else(|| {
                self.callback_any
                    .read()
                    .unwrap_or_else(|e| e.into_inner())
                    .clone()
            });
        let Some(cb) = cb else { return };
        let raw = raw_message(directory, entry);
        // A panicking callback must not take the dispatcher (and every later message) down.
        if std::panic::catch_unwind(AssertUnwindSafe(|| cb(raw))).is_err() {
            self.callback_failures.fetch_add(1, Ordering::Relaxed);
        }
    }
}

/// Joins a helper thread taken out of its slot, unless that thread is the caller (a system
/// closed from its own callback or timer thread cannot wait for itself).
fn join_unless_current(slot: &Mutex<Option<JoinHandle<()>>>) {
    let handle = slot.lock().unwrap_or_else(|e| e.into_inner()).take();
    if let Some(h) = handle {
        if h.thread().id() != std::thread::current().id() {
            let _ = h.join();
        }
    }
}

fn dispatch_callbacks(module: Weak<ModuleCore>, directory: Arc<Directory>) {
    loop {
        let Some(m) = module.upgrade() else { return };
        let entry = match m.callback_inbox.take_timeout(|_| true, None) {
            Ok(Some(e)) => e,
            _ => return, // closed and drained
        };
        m.run_callback(&directory, entry);
    }
}

pub(crate) fn raw_message(directory: &Directory, e: Entry) -> RawMessage {
    RawMessage {
        envelope: Envelope {
            header: e.header,
            source_system: directory.system_name(e.header.source.system),
            source_module: directory.module_name(e.header.source.module),
            received_at: e.received_at,
        },
        payload: e.payload,
    }
}

/// Frames larger than this are never held for batching (see [`SystemCore::transmit`]).
const BATCH_FRAME_MAX: usize = 8 * 1024;
const _: () = assert!(hetcomm_router::SPLIT_PAYLOAD_MIN > BATCH_FRAME_MAX);

/// The batching policy of one link. A frame goes out at once when the link was idle for
/// the linger time, so sporadic messages never wait; while frames come faster than that,
/// they are held and leave together when the link's batch is full, when the oldest has waited
/// the linger time (checked at the next send, or by the timer thread), or when a thread of
/// the system is about to wait.
pub(crate) struct Batching {
    /// 0: never hold.
    linger_us: u64,
    /// When the last data frame was handed to this link (µs, the system's clock).
    last_send: AtomicU64,
    /// When the last acknowledgement was.
    last_ack: AtomicU64,
    /// When the oldest frame still held was held (0: nothing held).
    held_since: AtomicU64,
    /// Frames held back to share a datagram or write ([`crate::SystemStats::held_frames`]).
    held: AtomicU64,
}

impl Batching {
    fn new(linger_us: u32) -> Self {
        Batching {
            linger_us: u64::from(linger_us),
            last_send: AtomicU64::new(0),
            last_ack: AtomicU64::new(0),
            held_since: AtomicU64::new(0),
            held: AtomicU64::new(0),
        }
    }

    /// Whether held frames should go now (and marks them gone): any held frame when `now`
    /// is None, else frames held for the linger time.
    fn take_due(&self, now: Option<Time>) -> bool {
        let since = self.held_since.load(Ordering::Relaxed);
        if since == 0 {
            return false;
        }
        if let Some(now) = now {
            if now.as_micros().saturating_sub(since) < self.linger_us {
                return false;
            }
        }
        self.held_since
            .compare_exchange(since, 0, Ordering::Relaxed, Ordering::Relaxed)
            .is_ok()
    }
}

/// Which idle test a frame takes ([`SystemCore::transmit`]). Acknowledgements keep their
/// own: a stream's acknowledgements share datagrams, while the one acknowledgement of a
/// request goes at once and does not make the answer after it count as busy traffic (which
/// would hold the answer and wake the batching timer).
#[derive(Clone, Copy)]
pub(crate) enum Traffic {
    /// Messages (first transmissions and retransmissions).
    Data,
    /// Acknowledgements.
    Ack,
}

#[derive(Default)]
struct TimerState {
    deadline: Option<Time>,
    shutdown: bool,
}

#[derive(Default)]
struct Timer {
    state: Mutex<TimerState>,
    wake: Condvar,
}

impl Timer {
    fn arm(&self, next: Option<Time>) {
        let Some(next) = next else { return };
        let mut s = self.state.lock().unwrap_or_else(|e| e.into_inner());
        if s.deadline.is_none_or(|d| next < d) {
            s.deadline = Some(next);
            self.wake.notify_one();
        }
    }
}

/// One opened system.
pub(crate) struct SystemCore {
    pub id: SystemId,
    pub name: &'static str,
    pub directory: Arc<Directory>,
    pub registry: Arc<RwLock<TypeRegistry>>,
    /// [`TypeRegistry::id`] of `registry`, readable without its lock.
    pub registry_id: u64,
    pub modules: HashMap<ModuleId, Arc<ModuleCore>>,
    pub clock: Arc<dyn Clock>,
    router: Mutex<Router<Arc<OutcomeSlot>>>,
    links: OnceLock<Vec<Arc<dyn Link>>>,
    /// Per link: when small frames are held back to share a write (see [`Batching`]).
    batching: OnceLock<Vec<Batching>>,
    timer: Timer,
    timer_thread: Mutex<Option<JoinHandle<()>>>,
    closed: AtomicBool,
    /// Frames being handled right now: shutdown lets them finish (their acknowledgements go
    /// out) before it closes the links.
    in_progress: std::sync::atomic::AtomicUsize,
    /// Destinations reached over in-process links, handed messages directly.
    direct: OnceLock<DirectRoutes>,
    /// Reads the links that a waiting thread can drive (see [`crate::reactor`]).
    reactor: OnceLock<Arc<Reactor>>,
    reactor_thread: Mutex<Option<JoinHandle<()>>>,
    /// Messages other systems of this process put straight into this one's inboxes.
    /// Bumped by other systems' threads for every message they hand over: on lines of its
    /// own, away from what this system's threads read.
    pub direct_received: CachePadded<AtomicU64>,
    /// Messages for a module id this system's fleet file does not have (the sender's fleet
    /// file differs), dropped (and refused, when an acknowledgement was asked for).
    pub unknown_module: AtomicU64,
    /// Who sees every send, receipt and outcome ([`crate::observe`]).
    pub(crate) observers: Observers,
    /// Taps, scheduled faults and topics ([`crate::harness`], [`crate::node`]).
    pub(crate) harness: crate::harness::SystemHarness,
}

/// The in-process links of a system, through which a message skips framing, checksums and
/// the destination's router: both ends are in this process, the link is reliable, ordered
/// and synchronous, so the sender's thread can put the message into the destination inbox
/// itself and know the outcome at once.
pub(crate) struct DirectRoutes {
    hubs: Hubs,
    /// Per link index: the in-process transport's name, or None for other links.
    names: Vec<Option<String>>,
    /// Destinations resolved so far (re-resolved when one closes and reopens).
    cache: Mutex<HashMap<SystemId, Weak<SystemCore>>>,
}

impl SystemCore {
    pub(crate) fn new(
        id: SystemId,
        directory: Arc<Directory>,
        registry: Arc<RwLock<TypeRegistry>>,
        modules: Vec<(ModuleId, InboxConfig)>,
        router: Router<Arc<OutcomeSlot>>,
        clock: Arc<dyn Clock>,
        inline_callbacks: bool,
    ) -> Arc<Self> {
        let modules = modules
            .into_iter()
            .map(|(mid, inbox)| {
                let name = directory.module_name(mid);
                let mut module = ModuleCore::new(mid, name, inbox);
                module.inline_callbacks = inline_callbacks;
                (mid, Arc::new(module))
            })
            .collect();
        let registry_id = registry.read().unwrap_or_else(|e| e.into_inner()).id();
        Arc::new(SystemCore {
            id,
            name: directory.system_name(id),
            directory,
            registry_id,
            registry,
            modules,
            clock,
            router: Mutex::new(router),
            links: OnceLock::new(),
            batching: OnceLock::new(),
            timer: Timer::default(),
            timer_thread: Mutex::new(None),
            closed: AtomicBool::new(false),
            in_progress: std::sync::atomic::AtomicUsize::new(0),
            direct: OnceLock::new(),
            direct_received: CachePadded::default(),
            unknown_module: AtomicU64::new(0),
            reactor: OnceLock::new(),
            reactor_thread: Mutex::new(None),
            observers: Observers::default(),
            harness: Default::default(),
        })
    }

    /// Installs the links (once) and, unless a simulator drives time, starts the timer
    /// thread.
    pub(crate) fn start(
        self: &Arc<Self>,
        links: Vec<Arc<dyn Link>>,
        linger_us: Vec<u32>,
        timer_thread: bool,
    ) -> std::io::Result<()> {
        self.harness.attach(Arc::downgrade(self), timer_thread);
        let reactor = Reactor::new(&links)?;
        let batching = links
            .iter()
            .zip(linger_us.iter().chain(std::iter::repeat(&0)))
            .map(|(l, &us)| Batching::new(if l.batches() { us } else { 0 }))
            .collect();
        let _ = self.batching.set(batching);
        {
            // Frames on links that vouch for their bytes need a CRC of the header only.
            let mut router = self.router();
            for (i, l) in links.iter().enumerate() {
                router.set_link_checksums_payload(i, l.checksums_payload());
            }
        }
        let _ = self.links.set(links);
        if !timer_thread {
            return Ok(());
        }
        if let Some(reactor) = reactor {
            let _ = self.reactor.set(reactor.clone());
            let weak = Arc::downgrade(self);
            let handle = std::thread::Builder::new()
                .name(format!("hetcomm-rx-{}", self.name))
                .spawn(move || reactor.run_background(weak))?;
            *self
                .reactor_thread
                .lock()
                .unwrap_or_else(|e| e.into_inner()) = Some(handle);
        }
        let weak = Arc::downgrade(self);
        let handle = std::thread::Builder::new()
            .name(format!("hetcomm-timer-{}", self.name))
            .spawn(move || run_timer(weak))?;
        *self.timer_thread.lock().unwrap_or_else(|e| e.into_inner()) = Some(handle);
        Ok(())
    }

    /// Enables direct hand-over on the links that `names` marks as in-process (see
    /// [`DirectRoutes`]).
    pub(crate) fn set_direct(&self, hubs: Hubs, names: Vec<Option<String>>) {
        if names.iter().any(Option::is_some) {
            let _ = self.direct.set(DirectRoutes {
                hubs,
                names,
                cache: Mutex::new(HashMap::default()),
            });
        }
    }

    /// The destination system when a send to `to` over `link` can be handed over directly.
    pub(crate) fn direct_peer(&self, link: usize, to: SystemId) -> Option<Arc<SystemCore>> {
        if self.harness.faulted() {
            // Scheduled faults act on frames: every send takes the link.
            return None;
        }
        let d = self.direct.get()?;
        let name = d.names.get(link)?.as_ref()?;
        let mut cache = d.cache.lock().unwrap_or_else(|e| e.into_inner());
        if let Some(c) = cache.get(&to).and_then(Weak::upgrade) {
            if !c.is_closed() {
                return Some(c);
            }
        }
        let c = d.hubs.system(name, to)?;
        cache.insert(to, Arc::downgrade(&c));
        Some(c)
    }

    /// Takes the next message `accept` agrees to from `module`'s inbox, waiting up to
    /// `timeout` (None: forever). While it waits, the thread reads the links itself when it
    /// can (see [`crate::reactor`]). `Err(header)`: the next message was refused and stays.
    pub(crate) fn take_waiting(
        &self,
        module: &ModuleCore,
        accept: impl Fn(&Header) -> bool,
        timeout: Option<Duration>,
    ) -> Result<Option<Entry>, Header> {
        // Whatever this system held back for batching goes out before its thread waits
        // (typically for the answer to it).
        self.flush_held(None);
        let Some(reactor) = self.reactor.get() else {
            return module.inbox.take_timeout(accept, timeout);
        };
        // The deadline is computed only once the inbox turned out empty: a receiver keeping up
        // with a stream finds a message at once nearly every time, and reading the clock
        // is a noticeable part of taking a small message.
        let mut deadline: Option<Option<Instant>> = None;
        loop {
            match module.inbox.try_take(&accept) {
                Ok(None) => {}
                other => return other,
            }
            // (Links that batch are links with a readable side, so they have a reactor.)
            self.idle_before_blocking();
            let deadline = *deadline.get_or_insert_with(|| timeout.map(|t| Instant::now() + t));
            let left = match deadline {
                None => Duration::MAX,
                Some(d) => {
                    let left = d.saturating_duration_since(Instant::now());
                    if left.is_zero() {
                        return Ok(None);
                    }
                    left
                }
            };
            if self.is_closed() {
                return Ok(None);
            }
            if reactor.try_lead() {
                module.leading.store(true, Ordering::SeqCst);
                // A message may have arrived between `try_take` and raising the flag.
                if module.inbox.is_empty() && !spin_on_links(reactor, module, left) {
                    reactor.turn(left);
                }
                module.leading.store(false, Ordering::SeqCst);
                reactor.end_module_turn();
            } else {
                // Someone else reads; it queues what comes. Ask again soon: the leader may
                // be the background thread stepping aside for us.
                reactor.follow(true);
                let r = module
                    .inbox
                    .take_timeout(&accept, Some(left.min(Duration::from_micros(500))));
                reactor.follow(false);
                match r {
                    Ok(None) => {}
                    other => return other,
                }
            }
        }
    }

    /// Puts a message handed over directly by another system of this process into its
    /// module's inbox. `now` is the sender's clock reading: one process, one wall clock.
    /// `module`: this system's module the message is for, looked up by the caller (None:
    /// there is no such module).
    pub(crate) fn deliver_direct(
        &self,
        module: Option<&ModuleCore>,
        header: Header,
        payload: PayloadBuf,
        now: Time,
    ) -> AckStatus {
        self.direct_received.fetch_add(1, Ordering::Relaxed);
        if self.harness.tapped_for(&header) {
            return self.harness.on_delivery(
                self,
                module,
                header,
                payload,
                now,
                Source::SameProcess,
            );
        }
        if self.observers.active() {
            return self.deliver_observed(module, header, payload, now, Source::SameProcess);
        }
        self.deliver_to(module, header, payload, now, Source::SameProcess)
    }

    /// The router's next retransmission deadline.
    pub(crate) fn next_deadline(&self) -> Option<Time> {
        self.router().poll_timeout()
    }

    /// Runs due retransmission timers (the simulator's timer thread).
    pub(crate) fn fire_timers(&self) {
        let now = self.clock.now();
        self.flush_held(Some(now));
        // A batch held after this timer was armed (for an earlier deadline) is due later: the
        // timer keeps one deadline, so arm it again.
        self.timer.arm(self.next_flush());
        let mut router = self.router();
        router.handle_timeout(now);
        self.pump(router);
    }

    /// Puts frames held for batching on their links: all of them (`None`), or those held
    /// for at least their link's linger by `Some(now)`.
    pub(crate) fn flush_held(&self, due_at: Option<Time>) {
        let (Some(links), Some(batching)) = (self.links.get(), self.batching.get()) else {
            return;
        };
        for (link, b) in links.iter().zip(batching) {
            if b.take_due(due_at) {
                // A frame lost here is counted by the link; acknowledged sends retransmit.
                let _ = link.flush();
            }
        }
    }

    /// Counts the links as idle, as a thread of this system is about to block for a
    /// message: the first frame after the wait (typically the answer to what arrives, or the
    /// next request) goes at once instead of being held. A request–answer exchange so holds
    /// nothing and never arms the batching timer, whose wake-ups would land on the
    /// exchange's path; a stream sent, or taken, without blocking still batches.
    fn idle_before_blocking(&self) {
        for b in self.batching.get().into_iter().flatten() {
            b.last_send.store(0, Ordering::Relaxed);
            b.last_ack.store(0, Ordering::Relaxed);
        }
    }

    /// Frames held back for batching so far, all links together.
    pub(crate) fn held_frames(&self) -> u64 {
        self.batching
            .get()
            .into_iter()
            .flatten()
            .map(|b| b.held.load(Ordering::Relaxed))
            .sum()
    }

    /// When the oldest batch still held is due.
    fn next_flush(&self) -> Option<Time> {
        self.batching
            .get()?
            .iter()
            .filter_map(|b| {
                let since = b.held_since.load(Ordering::Relaxed);
                (since != 0).then(|| Time::from_micros(since + b.linger_us))
            })
            .min()
    }

    /// Puts one frame, `frame` followed by `body`, on link `index`, holding it back to share a
    /// write with the next ones when the link batches and is busy (see [`Batching`]).
    #[allow(clippy::too_many_arguments)] // one frame's whole description
    fn transmit(
        &self,
        index: usize,
        link: &dyn Link,
        to: SystemId,
        frame: &[u8],
        body: &[u8],
        now: Time,
        traffic: Traffic,
    ) -> Result<(), LinkError> {
        let Some(b) = self.batching.get().and_then(|v| v.get(index)) else {
            return link.send_parts(to, frame, body);
        };
        if b.linger_us == 0 {
            return link.send_parts(to, frame, body);
        }
        let stamp = match traffic {
            Traffic::Data => &b.last_send,
            Traffic::Ack => &b.last_ack,
        };
        let last = stamp.swap(now.as_micros(), Ordering::Relaxed);
        if frame.len() + body.len() > BATCH_FRAME_MAX {
            // A large frame fills a write on its own: holding it would only cost a timer
            // wake-up. It goes now, after whatever is held for the same peer. (Only such
            // frames come in two pieces: SPLIT_PAYLOAD_MIN > BATCH_FRAME_MAX.)
            return link.send_parts(to, frame, body);
        }
        debug_assert!(body.is_empty(), "small frames come whole");
        if now.as_micros().saturating_sub(last) >= b.linger_us {
            // The link was idle: this frame goes now (with anything still held for this
            // peer before it), so sporadic traffic never waits. Frames held for other peers
            // stay on the timer.
            return link.send(to, frame);
        }
        let result = link.send_held(to, frame);
        b.held.fetch_add(1, Ordering::Relaxed);
        let since = b.held_since.load(Ordering::Relaxed);
        if since == 0 {
            b.held_since
                .store(now.as_micros().max(1), Ordering::Relaxed);
            // The timer thread sends the batch should nothing else come along.
            self.timer
                .arm(Some(Time::from_micros(now.as_micros() + b.linger_us)));
        } else if b.take_due(Some(now)) {
            let _ = link.flush();
        }
        result
    }

    /// Puts the frame `frame` + `body` on link `index` (see [`SystemCore::transmit`]), in the
    /// router's terms.
    pub(crate) fn transmit_on(
        &self,
        index: usize,
        to: SystemId,
        frame: &[u8],
        body: &[u8],
        now: Time,
        traffic: Traffic,
    ) -> Result<(), TransmitError> {
        if self.harness.faulted()
            && self
                .harness
                .fault_frame(self.id, index, to, frame, body, now)
        {
            return Ok(());
        }
        match self.links().get(index) {
            Some(link) => self
                .transmit(index, &**link, to, frame, body, now, traffic)
                .map_err(|e| transmit_error(&self.directory, e)),
            None => Err(TransmitError::Other("no such link".into())),
        }
    }

    pub(crate) fn router(&self) -> MutexGuard<'_, Router<Arc<OutcomeSlot>>> {
        self.router.lock().unwrap_or_else(|e| e.into_inner())
    }

    pub(crate) fn is_closed(&self) -> bool {
        self.closed.load(Ordering::Acquire)
    }

    pub(crate) fn links(&self) -> &[Arc<dyn Link>] {
        self.links.get().map(|v| v.as_slice()).unwrap_or(&[])
    }

    /// A sink for link `index`: frames it receives enter this system's router.
    pub(crate) fn sink(self: &Arc<Self>, index: usize) -> Arc<dyn FrameSink> {
        Arc::new(SystemSink {
            core: Arc::downgrade(self),
            link: index,
        })
    }

    /// Performs everything the router asks for, until it has nothing more: frames onto links,
    /// deliveries into inboxes, outcomes into tickets, and the timer re-armed. The router lock
    /// is never held while a link or an inbox is called (an in-process link re-enters
    /// another system's router on this same thread).
    pub(crate) fn pump<'a>(&'a self, router: MutexGuard<'a, Router<Arc<OutcomeSlot>>>) {
        let now = self.clock.now();
        self.pump_at(router, now);
    }

    /// [`SystemCore::pump`] with the clock already read (by a caller that read it
    /// microseconds ago: reading it is a noticeable part of a small message's cost).
    pub(crate) fn pump_at<'a>(
        &'a self,
        mut router: MutexGuard<'a, Router<Arc<OutcomeSlot>>>,
        first_now: Time,
    ) {
        // One message usually makes one transmit, delivery or outcome per round: keep them on
        // the stack.
        let mut transmits: SmallVec<[Transmit; 4]> = SmallVec::new();
        // A batch datagram's frames are handled in one go (see `SystemSink::on_frames`).
        let mut deliveries: SmallVec<[Delivery; 16]> = SmallVec::new();
        let mut events: SmallVec<[Event<Arc<OutcomeSlot>>; 4]> = SmallVec::new();
        let mut delivery_results: SmallVec<[(DeliveryToken, AckStatus); 2]> = SmallVec::new();
        let mut transmit_results: SmallVec<[(Transmit, Result<(), TransmitError>); 4]> =
            SmallVec::new();
        // Per transmit, while observed: which attempt of its send it is (0 for an ack).
        let mut attempts: SmallVec<[u32; 4]> = SmallVec::new();
        // While observed: the destinations of each native broadcast's frame among them.
        let mut broadcast_dests: SmallVec<[Vec<SystemId>; 1]> = SmallVec::new();
        let mut now = first_now;
        let mut first = true;
        loop {
            // One clock read per round: the calls below are microseconds apart.
            if !first {
                now = self.clock.now();
            }
            first = false;
            let observed = self.observers.active();
            while let Some(t) = router.poll_transmit(now) {
                if observed {
                    attempts.push(t.send.and_then(|id| router.attempts(id)).unwrap_or(0));
                    if t.to == TO_ALL_SYSTEM {
                        let b = t.send.map_or(0, |id| id.wire_seq());
                        broadcast_dests.push(router.broadcast_destinations(b));
                    }
                }
                transmits.push(t);
            }
            while let Some(d) = router.poll_delivery() {
                deliveries.push(d);
            }
            while let Some(e) = router.poll_event() {
                events.push(e);
            }
            let next = router.poll_timeout();
            drop(router);
            self.timer.arm(next);
            if transmits.is_empty() && deliveries.is_empty() && events.is_empty() {
                return;
            }
            for Event::Outcome { id, token, outcome } in events.drain(..) {
                self.end_send(id, outcome, Some(token), now);
            }
            for d in deliveries.drain(..) {
                let token = d.token;
                let status = self.deliver(d, now);
                if let Some(token) = token {
                    delivery_results.push((token, status));
                }
            }
            for (i, tx) in transmits.drain(..).enumerate() {
                // Only sends need their result: an acknowledgement lost here is counted by
                // the link, and its sender retransmits and is acknowledged again.
                let traffic = match tx.send {
                    Some(_) => Traffic::Data,
                    None => Traffic::Ack,
                };
                if tx.to == TO_ALL_SYSTEM && !broadcast_dests.is_empty() {
                    let dests = broadcast_dests.remove(0);
                    self.observers
                        .send_broadcast_frame(&tx.frame, &dests, now, tx.link);
                } else if let Some(&attempt) = attempts.get(i).filter(|&&a| a > 0) {
                    self.observers.send_frame(
                        &tx.frame,
                        &[],
                        now,
                        RouteKind::Routed,
                        tx.link,
                        attempt,
                    );
                }
                let result = self.transmit_on(tx.link, tx.to, &tx.frame, &[], now, traffic);
                if tx.send.is_some() {
                    transmit_results.push((tx, result));
                }
            }
            attempts.clear();
            broadcast_dests.clear();
            if delivery_results.is_empty() && transmit_results.is_empty() {
                // Nothing to feed back (timers were armed above).
                return;
            }
            router = self.router();
            for (token, status) in delivery_results.drain(..) {
                router.delivery_result(now, token, status);
            }
            for (tx, result) in transmit_results.drain(..) {
                router.transmit_result(now, tx, result);
            }
        }
    }

    /// Puts a delivery that came through the router (from a link) into its module's inbox
    /// (or callback queue).
    fn deliver(&self, d: Delivery, now: Time) -> AckStatus {
        let module = self.modules.get(&d.header.destination.module);
        let source = Source::Link(d.link);
        if self.harness.tapped_for(&d.header) {
            return self.harness.on_delivery(
                self,
                module.map(|m| &**m),
                d.header,
                d.payload,
                now,
                source,
            );
        }
        if self.observers.active() {
            return self.deliver_observed(module.map(|m| &**m), d.header, d.payload, now, source);
        }
        self.deliver_to(module.map(|m| &**m), d.header, d.payload, now, source)
    }

    /// Puts a message that passed this system's taps (or that the harness injected or held
    /// back) into its module's inbox. `link`: the link it came on (None: from this process,
    /// or from the harness, which never waits for room).
    pub(crate) fn deliver_untapped(
        &self,
        header: Header,
        payload: PayloadBuf,
        now: Time,
        link: Option<usize>,
    ) -> AckStatus {
        let module = self.modules.get(&header.destination.module).map(|m| &**m);
        let source = match link {
            Some(l) => Source::Link(l),
            None => Source::Harness,
        };
        self.deliver_passed(module, header, payload, now, source)
    }

    /// [`SystemCore::deliver_untapped`] with the module already looked up and the message's
    /// own source (a message that passed its taps unchanged in time).
    pub(crate) fn deliver_passed(
        &self,
        module: Option<&ModuleCore>,
        header: Header,
        payload: PayloadBuf,
        now: Time,
        source: Source,
    ) -> AckStatus {
        if self.observers.active() {
            return self.deliver_observed(module, header, payload, now, source);
        }
        self.deliver_to(module, header, payload, now, source)
    }

    /// Puts a frame the harness held back (a scheduled latency) on link `index`.
    pub(crate) fn send_held_frame(
        &self,
        index: usize,
        to: SystemId,
        frame: &[u8],
    ) -> Result<(), LinkError> {
        if self.is_closed() {
            return Err(LinkError::Closed);
        }
        match self.links().get(index) {
            Some(link) => link.send(to, frame),
            None => Err(LinkError::Closed),
        }
    }

    /// Where every send's outcome goes, whichever way the send went: the observers see it,
    /// then the ticket gets it (`slot`, or a ticket made ready with it, returned).
    #[inline(always)]
    pub(crate) fn end_send(
        &self,
        id: SendId,
        outcome: Outcome,
        slot: Option<Arc<OutcomeSlot>>,
        now: Time,
    ) -> TicketSlot {
        match slot {
            Some(slot) => {
                if self.observers.active() {
                    self.observe_outcome(id, &outcome, now);
                }
                slot.complete(outcome);
                TicketSlot::Pending(slot)
            }
            None => {
                // Made first, so the outcome is not moved again after the observers saw it.
                let ready = TicketSlot::Ready(outcome);
                if self.observers.active() {
                    if let TicketSlot::Ready(outcome) = &ready {
                        self.observe_outcome(id, outcome, now);
                    }
                }
                ready
            }
        }
    }

    /// [`SystemCore::end_send`]'s report, out of the way of the unobserved path.
    #[cold]
    #[inline(never)]
    fn observe_outcome(&self, id: SendId, outcome: &Outcome, now: Time) {
        self.observers.outcome(&OutcomeRecord {
            id,
            outcome,
            time: now,
        });
    }

    /// [`SystemCore::deliver_to`] and a report of the receipt to the observers (every
    /// receipt, from a link or handed over directly, is reported here). The payload is
    /// copied for the observers: the inbox takes the message.
    #[cold]
    #[inline(never)]
    fn deliver_observed(
        &self,
        module: Option<&ModuleCore>,
        header: Header,
        payload: PayloadBuf,
        now: Time,
        source: Source,
    ) -> AckStatus {
        let copy = payload.clone();
        let status = self.deliver_to(module, header, payload, now, source);
        self.observers.receipt(&ReceiptRecord {
            header,
            payload: &copy,
            time: now,
            via: match source {
                Source::Link(link) => Via::Link(link),
                Source::SameProcess | Source::Harness => Via::Direct,
            },
            status,
        });
        status
    }

    /// Puts a message into `module`'s inbox, or hands it to the module's callbacks (None:
    /// there is no such module). Only a sender of this process waits for room under the
    /// `block` policy; a link is never stopped. (Callers report it: [`Self::deliver_observed`].)
    fn deliver_to(
        &self,
        module: Option<&ModuleCore>,
        header: Header,
        payload: PayloadBuf,
        now: Time,
        source: Source,
    ) -> AckStatus {
        let Some(module) = module else {
            self.unknown_module.fetch_add(1, Ordering::Relaxed);
            return AckStatus::UnknownModule;
        };
        let entry = Entry {
            header,
            payload,
            received_at: now,
        };
        let wants_callback = module.wants_callback(header.message_type);
        if wants_callback && module.inline_callbacks {
            module.run_callback(&self.directory, entry);
            return AckStatus::Delivered;
        }
        let inbox = if wants_callback {
            &module.callback_inbox
        } else {
            &module.inbox
        };
        let pushed = match source {
            Source::SameProcess => inbox.push(entry),
            Source::Link(_) | Source::Harness => inbox.push_from_link(entry),
        };
        match pushed {
            Ok(()) => {
                if !wants_callback && module.leading.load(Ordering::SeqCst) && !leading_here() {
                    if let Some(r) = self.reactor.get() {
                        r.kick();
                    }
                }
                AckStatus::Delivered
            }
            Err(PushError::Full) | Err(PushError::Closed) => AckStatus::InboxFull,
        }
    }

    /// Stops the timer, fails unresolved sends, closes inboxes and drops the links.
    pub(crate) fn shutdown(&self) {
        if self.closed.swap(true, Ordering::AcqRel) {
            return;
        }
        self.harness.close();
        // Let frames already inside the router finish, so that a message just delivered is
        // also acknowledged; bounded, since a frame's handling may be stuck on a full inbox.
        let deadline = std::time::Instant::now() + std::time::Duration::from_secs(1);
        while self.in_progress.load(Ordering::Acquire) > 0 && std::time::Instant::now() < deadline {
            std::thread::sleep(std::time::Duration::from_millis(1));
        }
        {
            let mut s = self.timer.state.lock().unwrap_or_else(|e| e.into_inner());
            s.shutdown = true;
            self.timer.wake.notify_all();
        }
        join_unless_current(&self.timer_thread);
        if let Some(r) = self.reactor.get() {
            r.shutdown();
        }
        join_unless_current(&self.reactor_thread);
        let mut router = self.router();
        router.shutdown();
        let mut ended = Vec::new();
        while let Some(Event::Outcome { id, token, outcome }) = router.poll_event() {
            ended.push((id, token, outcome));
        }
        drop(router);
        let now = self.clock.now();
        for (id, token, outcome) in ended {
            self.end_send(id, outcome, Some(token), now);
        }
        for m in self.modules.values() {
            m.close();
        }
    }
}

/// Where a message being delivered comes from: it decides whether a full `block` inbox may
/// make the deliverer wait.
#[derive(Clone, Copy)]
pub(crate) enum Source {
    /// Handed over by a sender of this process, on its own thread: it may wait for room.
    SameProcess,
    /// From a link (this index), through the router: refused at once when there is no room.
    Link(usize),
    /// Put there by the harness (held back, duplicated or injected): refused at once when
    /// there is no room, as from a link.
    Harness,
}

/// A leading module set to spin ([`crate::Module::set_wait_spin`]) looks at its links
/// without sleeping, up to its spin time (and `left`), until a message is queued (true).
/// A reply that comes meanwhile is read at once instead of after a wake-up, which costs
/// several microseconds when it crosses CPUs. Each look yields the CPU, so a peer sharing
/// this CPU still runs.
fn spin_on_links(reactor: &Reactor, module: &ModuleCore, left: Duration) -> bool {
    let spin = module.inbox.spin().min(left);
    if spin.is_zero() {
        return false;
    }
    let start = Instant::now();
    loop {
        reactor.poll_now();
        if !module.inbox.is_empty() {
            return true;
        }
        if start.elapsed() >= spin {
            return false;
        }
        std::thread::yield_now();
    }
}

/// A link's refusal in the router's terms. The outcome it ends up in belongs to a ticket that
/// names its destination, so the text says why, not who again; where a peer is named, it is by
/// its name in the fleet, not its id.
fn transmit_error(directory: &Directory, e: LinkError) -> TransmitError {
    match e {
        LinkError::Unreachable { reason, .. } => TransmitError::Unreachable(reason),
        LinkError::TooLarge { .. } => TransmitError::TooLarge(e.to_string()),
        LinkError::Congested { peer, reason } => TransmitError::Congested(format!(
            "link to {} is congested: {reason}",
            directory.system_name(peer)
        )),
        other => TransmitError::Other(other.to_string()),
    }
}

struct SystemSink {
    core: Weak<SystemCore>,
    link: usize,
}

impl SystemSink {
    /// Gives arriving frames to the open system's router (`handle`, with one clock reading),
    /// then carries out what they caused.
    fn handle(&self, handle: impl FnOnce(&mut Router<Arc<OutcomeSlot>>, Time)) {
        let Some(core) = self.core.upgrade() else {
            return;
        };
        if core.is_closed() {
            return;
        }
        let now = core.clock.now();
        let mut router = core.router();
        handle(&mut router, now);
        core.pump_at(router, now);
    }
}

/// The system a link saw a frame come from, as the router takes it.
fn peer_system(from: Peer) -> Option<SystemId> {
    match from {
        Peer::System(id) => Some(id),
        Peer::Unknown => None,
    }
}

impl FrameSink for SystemSink {
    fn on_frame(&self, frame: &[u8], from: Peer) {
        self.on_frames(&mut std::iter::once(frame), from);
    }

    /// The frames of one batch datagram: one clock reading, one router lock and one pump for
    /// all of them instead of one each (they arrived at the same moment).
    fn on_frames(&self, frames: &mut dyn Iterator<Item = &[u8]>, from: Peer) {
        let peer = peer_system(from);
        self.handle(|router, now| {
            for frame in frames {
                router.handle_frame_from(now, self.link, peer, frame);
            }
        });
    }

    /// A large frame in a buffer of its own: the router delivers its payload in that buffer.
    fn on_frame_owned(&self, frame: FrameBuf, from: Peer) {
        let peer = peer_system(from);
        self.handle(|router, now| router.handle_frame_owned_from(now, self.link, peer, frame));
    }

    fn takes_frames(&self) -> bool {
        true
    }
}

/// The timer thread: sleeps until the router's next deadline (or until [`Timer::arm`] brings
/// it forward), then fires it. Shutdown sets the flag and wakes it.
fn run_timer(core: Weak<SystemCore>) {
    while let Some(c) = core.upgrade() {
        let mut s = c.timer.state.lock().unwrap_or_else(|e| e.into_inner());
        if s.shutdown {
            return;
        }
        let now = c.clock.now();
        match s.deadline {
            Some(d) if d <= now => {
                s.deadline = None;
                drop(s);
                c.fire_timers();
            }
            Some(d) => drop(c.timer.wake.wait_timeout(s, d.saturating_since(now))),
            None => drop(c.timer.wake.wait(s)),
        }
    }
}

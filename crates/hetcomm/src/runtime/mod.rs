//! The real-time driver: one [`SystemCore`] per opened system drives its sans-IO router with
//! the monotonic clock (wall-clock time only stamps messages: see [`Clock`]). Sends run on the caller's thread up to the link's send call; frames run on
//! the link's receive thread (or the sender's thread for in-process links); a timer thread per
//! system handles retransmission deadlines; callbacks run on a thread per module.

use parking_lot::{Condvar, Mutex, MutexGuard, RwLock};
use rustc_hash::FxHashMap as HashMap;
use std::panic::AssertUnwindSafe;
use std::sync::atomic::{AtomicBool, AtomicU64, Ordering};
use std::sync::{Arc, OnceLock, Weak};
use std::thread::JoinHandle;
use std::time::{Duration, Instant};

use hetcomm_config::InboxConfig;
use hetcomm_core::wire::AckStatus;
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
use crate::ticket::{OutcomeSlot, SlotPool, TicketSlot};
use crate::transports::Hubs;
use crossbeam_utils::CachePadded;

#[cfg(test)]
mod clock_tests;
mod deliver;
mod direct;
mod intercept;
mod relay;
mod sink;
mod transmit;

pub(crate) use deliver::Source;
use intercept::RoundNotes;
pub(crate) use intercept::{Leaving, Seen};
pub(crate) use sink::Opening;
use sink::SystemSink;
pub(crate) use transmit::Batching;

/// Where a system's driver gets the time: [`SystemClock`] in the real runtime, a virtual
/// clock under the simulator.
///
/// Two times, never mixed. [`Clock::now`] is monotonic and times everything: it is the
/// router's `now` (retransmission and in-order hold deadlines, RTT samples, delivery
/// latencies), batching's linger, the harness's schedules and the time of observers'
/// records. [`Clock::wall`] turns one reading of it into the time that crosses hosts: the
/// header's timestamp of a send, and a received message's `received_at` (so that
/// `received_at - timestamp` is a one-way latency). Each path reads `now` once and asks
/// `wall` for the stamp, so a send costs one clock read.
pub trait Clock: Send + Sync + 'static {
    /// The current monotonic time (never stepped).
    fn now(&self) -> Time;
    /// The wall-clock time at `now`, a reading of [`Clock::now`] just taken on this thread.
    fn wall(&self, now: Time) -> Time;
}

/// The real runtime's clock: `now` from the monotonic clock ([`Time::now_mono`]), stamps on
/// the wall clock, microseconds since the UNIX epoch ([`Time::wall_at`]). A step of the
/// system clock (NTP, chrony, an operator) shows in stamps within 100 ms and moves no timer.
#[derive(Clone, Copy, Debug, Default)]
pub struct SystemClock;

impl Clock for SystemClock {
    fn now(&self) -> Time {
        Time::now_mono()
    }
    fn wall(&self, now: Time) -> Time {
        Time::wall_at(now)
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
    let mut names = NAMES.get_or_init(Default::default).lock();
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
    /// The module asked for its callbacks at the delivery ([`crate::Module::set_inline_callbacks`]);
    /// one delivered while this thread already runs an inline callback still goes to the
    /// callback thread (an in-process ping–pong would otherwise recurse without end).
    pub(crate) inline_requested: AtomicBool,
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
            inline_requested: AtomicBool::new(false),
            dispatcher: Mutex::new(None),
            callback_failures: AtomicU64::new(0),
            leading: AtomicBool::new(false),
        }
    }

    /// Whether any callback is registered (messages of some type may bypass the inbox).
    pub(crate) fn has_callbacks(&self) -> bool {
        self.has_callbacks.load(Ordering::Acquire)
    }

    fn wants_callback(&self, ty: MessageType) -> bool {
        self.has_callbacks.load(Ordering::Acquire)
            && (self.callbacks.read().contains_key(&ty) || self.callback_any.read().is_some())
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
                self.callbacks.write().insert(ty, cb);
            }
            None => *self.callback_any.write() = Some(cb),
        }
        self.has_callbacks.store(true, Ordering::Release);
        if self.inline_callbacks {
            return;
        }
        let mut dispatcher = self.dispatcher.lock();
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

    /// Runs the callback for `entry` here and now if this module's callbacks are inline;
    /// gives the entry back otherwise (for the callback thread).
    pub(crate) fn run_inline(&self, directory: &Directory, entry: Entry) -> Option<Entry> {
        if self.inline_callbacks {
            self.run_callback(directory, entry);
            return None;
        }
        if !self.inline_requested.load(Ordering::Acquire)
            || IN_INLINE_CALLBACK.with(std::cell::Cell::get)
        {
            return Some(entry);
        }
        IN_INLINE_CALLBACK.with(|c| c.set(true));
        self.run_callback(directory, entry);
        IN_INLINE_CALLBACK.with(|c| c.set(false));
        None
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
            .get(&ty)
            .cloned()
            .or_else(|| self.callback_any.read().clone());
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
    let handle = slot.lock().take();
    if let Some(h) = handle {
        if h.thread().id() != std::thread::current().id() {
            let _ = h.join();
        }
    }
}

thread_local! {
    /// Set while this thread runs a callback inline ([`ModuleCore::run_inline`]).
    static IN_INLINE_CALLBACK: std::cell::Cell<bool> = const { std::cell::Cell::new(false) };
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

struct Timer {
    state: Mutex<TimerState>,
    /// `state.deadline` in nanoseconds (`u64::MAX`: none), readable without the lock: nearly
    /// every pump finds the timer already armed for an earlier time, and taking the lock to
    /// see that moves its line between the cores of the sending and the receiving thread.
    /// Written only under the lock; a reader that sees a stale value at worst takes the lock.
    armed: AtomicU64,
    wake: Condvar,
    /// Under simulation: the simulator's queue of wake-ups, which takes the deadlines the
    /// timer thread would otherwise wait for.
    sim: OnceLock<crate::sim::SimWake>,
}

impl Default for Timer {
    fn default() -> Timer {
        Timer {
            state: Mutex::default(),
            armed: AtomicU64::new(u64::MAX),
            wake: Condvar::new(),
            sim: OnceLock::new(),
        }
    }
}

impl Timer {
    fn arm(&self, next: Option<Time>) {
        let Some(next) = next else { return };
        // Armed for no later (the timer thread clears a deadline before it pumps the router,
        // so a deadline the router had before that pump is in what the pump re-arms).
        if self.armed.load(Ordering::Acquire) <= next.0 {
            return;
        }
        let mut s = self.state.lock();
        if s.deadline.is_none_or(|d| next < d) {
            self.set_deadline(&mut s, Some(next));
            match self.sim.get() {
                Some(sim) => sim.timer(next),
                None => {
                    self.wake.notify_one();
                }
            }
        }
    }

    /// Sets the deadline, under its lock, and its lock-free mirror.
    fn set_deadline(&self, s: &mut TimerState, deadline: Option<Time>) {
        s.deadline = deadline;
        self.armed
            .store(deadline.map_or(u64::MAX, |d| d.0), Ordering::Release);
    }
}

/// Frames of presettled transmits ([`hetcomm_router::Transmit::presettled`]) that their links
/// took, with the time each was handed over, until whoever next locks the router hands them
/// back (every lock goes through [`SystemCore::router`]). A stream of acknowledged sends then
/// takes the router's lock once per send instead of twice; the second lock was the one the
/// thread reading acknowledgements contended for. This lock is taken by the sending thread
/// and the next router holder only, and not at all while nothing is waiting.
#[derive(Default)]
struct TakenBack {
    frames: Mutex<Vec<(Transmit, Time)>>,
    /// Whether `frames` may hold any (set and cleared under its lock).
    waiting: AtomicBool,
}

impl TakenBack {
    fn push(&self, taken: impl IntoIterator<Item = (Transmit, Time)>) {
        let mut frames = self.frames.lock();
        frames.extend(taken);
        self.waiting.store(true, Ordering::Release);
    }

    fn return_to(&self, router: &mut Router<Arc<OutcomeSlot>>) {
        if !self.waiting.load(Ordering::Acquire) {
            return;
        }
        let mut frames = self.frames.lock();
        for (tx, at) in frames.drain(..) {
            router.transmit_result(at, tx, Ok(()));
        }
        self.waiting.store(false, Ordering::Release);
    }
}

/// One opened system.
pub(crate) struct SystemCore {
    /// This system itself, for what outlives a call (a relay receipt's verdict, given later
    /// on a link's thread).
    this: Weak<SystemCore>,
    pub id: SystemId,
    pub name: &'static str,
    pub directory: Arc<Directory>,
    pub registry: Arc<RwLock<TypeRegistry>>,
    /// [`TypeRegistry::id`] of `registry`, readable without its lock.
    pub registry_id: u64,
    pub modules: HashMap<ModuleId, Arc<ModuleCore>>,
    pub clock: Arc<dyn Clock>,
    router: Mutex<Router<Arc<OutcomeSlot>>>,
    /// Outcome slots of ended sends, for the next ones ([`SlotPool`]).
    pub(crate) slots: SlotPool,
    /// Frames of presettled transmits their links took, on their way back to the router
    /// ([`TakenBack`]).
    taken_back: TakenBack,
    /// Frames that arrived before `start`, held for the router ([`Opening`]).
    pub(crate) opening: Opening,
    links: OnceLock<Vec<Arc<dyn Link>>>,
    /// The fleet-file name of each link's transport, by link index (what tickets name).
    link_names: OnceLock<Vec<&'static str>>,
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
    /// The last path switches ([`crate::switches`]).
    pub(crate) path_log: crate::switches::PathLog,
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
        let registry_id = registry.read().id();
        Arc::new_cyclic(|this| SystemCore {
            this: this.clone(),
            id,
            name: directory.system_name(id),
            directory,
            registry_id,
            registry,
            modules,
            clock,
            router: Mutex::new(router),
            slots: SlotPool::default(),
            taken_back: TakenBack::default(),
            opening: Opening::default(),
            links: OnceLock::new(),
            link_names: OnceLock::new(),
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
            path_log: Default::default(),
            harness: Default::default(),
        })
    }

    /// Installs the links (once), hands the router the frames that arrived while the system
    /// opened ([`Opening`]) and, unless a simulator drives time, starts the timer thread.
    /// The router must be the system's real one by now.
    /// Names each link by its transport's fleet-file name (link index order), for tickets.
    pub(crate) fn set_link_names(&self, names: Vec<&'static str>) {
        let _ = self.link_names.set(names);
    }

    /// The fleet-file name of link `link`'s transport.
    pub(crate) fn link_name(&self, link: usize) -> Option<&'static str> {
        self.link_names.get().and_then(|n| n.get(link)).copied()
    }

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
        // After the links are in: what the held frames cause (acknowledgements) goes out.
        self.release_opening_backlog();
        if !timer_thread {
            return Ok(());
        }
        if let Some(reactor) = reactor {
            let _ = self.reactor.set(reactor.clone());
            let weak = Arc::downgrade(self);
            let handle = std::thread::Builder::new()
                .name(format!("hetcomm-rx-{}", self.name))
                .spawn(move || reactor.run_background(weak))?;
            *self.reactor_thread.lock() = Some(handle);
        }
        let weak = Arc::downgrade(self);
        let handle = std::thread::Builder::new()
            .name(format!("hetcomm-timer-{}", self.name))
            .spawn(move || run_timer(weak))?;
        *self.timer_thread.lock() = Some(handle);
        Ok(())
    }

    /// The router's next retransmission deadline.
    pub(crate) fn next_deadline(&self) -> Option<Time> {
        self.router().poll_timeout()
    }

    /// Hands this system's wake-ups to the simulator from now on: the deadlines it arms, and
    /// the times its harness holds items until. What was armed before is forgotten (the
    /// simulator asks for the current deadline itself).
    pub(crate) fn attach_sim(&self, wake: crate::sim::SimWake) {
        self.timer.set_deadline(&mut self.timer.state.lock(), None);
        let _ = self.timer.sim.set(wake);
    }

    /// Under simulation: tells the simulator that the harness holds an item until `at`.
    pub(crate) fn sim_held(&self, at: Time) {
        if let Some(sim) = self.timer.sim.get() {
            sim.held(at);
        }
    }

    /// Under simulation: the simulator took its wake-ups for this system up to `up_to`
    /// (fired or found stale), so the next deadline armed is passed on again.
    pub(crate) fn sim_timer_taken(&self, up_to: Time) {
        let mut s = self.timer.state.lock();
        if s.deadline.is_some_and(|d| d <= up_to) {
            self.timer.set_deadline(&mut s, None);
        }
    }

    /// Arms the timer for `next` (the router's deadline, or a batch's), unless it is
    /// already armed for an earlier time.
    pub(crate) fn arm_timer(&self, next: Option<Time>) {
        self.timer.arm(next);
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

    pub(crate) fn router(&self) -> MutexGuard<'_, Router<Arc<OutcomeSlot>>> {
        let mut router = self.router.lock();
        self.taken_back.return_to(&mut router);
        router
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
            let mut s = self.timer.state.lock();
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
        while let Some(Event::Outcome {
            id,
            token,
            outcome,
            path,
        }) = router.poll_event()
        {
            ended.push((id, token, outcome, path));
        }
        drop(router);
        let now = self.clock.now();
        for (id, token, outcome, path) in ended {
            let transport = path.and_then(|p| self.link_name(p.link));
            self.end_send(id, outcome, transport, Some(token), now);
        }
        for m in self.modules.values() {
            m.close();
        }
    }
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
    // Links whose queue can be looked at directly are read without a system call, and their
    // senders skip waking them meanwhile (`Readable::set_spinning`).
    reactor.set_spinning(true);
    let found = loop {
        reactor.poll_spinning();
        if !module.inbox.is_empty() {
            break true;
        }
        if start.elapsed() >= spin {
            break false;
        }
        std::thread::yield_now();
    };
    reactor.set_spinning(false);
    found
}

/// The timer thread: sleeps until the router's next deadline (or until [`Timer::arm`] brings
/// it forward), then fires it. Shutdown sets the flag and wakes it.
fn run_timer(core: Weak<SystemCore>) {
    while let Some(c) = core.upgrade() {
        let mut s = c.timer.state.lock();
        if s.shutdown {
            return;
        }
        let now = c.clock.now();
        match s.deadline {
            Some(d) if d <= now => {
                c.timer.set_deadline(&mut s, None);
                drop(s);
                c.fire_timers();
            }
            Some(d) => {
                c.timer.wake.wait_for(&mut s, d.saturating_since(now));
            }
            None => c.timer.wake.wait(&mut s),
        }
    }
}

//! Virtual-time simulation: a whole fleet in one thread, driven by the same routers and the
//! same runtime code as the real thing, with every link replaced by a simulated one. Time only
//! moves when [`SimFleet::run_until`] moves it, so a run is faster than real time and
//! bit-for-bit repeatable for a seed.
//!
//! What each transport becomes under simulation: an `emulated` transport applies its link
//! model ([`hetcomm_link::emulation::LinkModel`]: loss, latency, bandwidth, range, outages) in
//! virtual time; every other kind becomes an ideal link that delivers at the same virtual
//! instant (still as a separate event, after the sender's call returns).
//!
//! Layers go over simulated links exactly as over real ones: `transports::open_link` opens
//! the simulated link in place of the real one and puts the transport's layer stack over it
//! (`hetcomm_link::layer`). The emulation layer leaves a simulated link alone, since the
//! simulator applies the same model itself, in virtual time (below).
//!
//! Observers ([`crate::Comm::observe`] on a [`SimFleet::system`]) see every send, receipt
//! and outcome here exactly as in real time, stamped with the virtual clock, on the
//! simulator's thread.
//!
//! Attacks on a simulated link: [`SimFleet::record_frames`] keeps a copy of every frame the
//! systems send (sealed, on a secured transport), and [`SimFleet::inject_frame`] puts any
//! bytes on a link as an outsider would, so forged, replayed and tampered frames can be
//! tried against a simulated fleet, deterministically (`crates/hetcomm/tests/security_sim.rs`).
//!
//! Autonomy code runs between calls to [`SimFleet::run_until`] (polling with `try_recv` /
//! `has_message`, reading outcomes with [`crate::Ticket::try_outcome`]) or in callbacks, which
//! run on the simulator's thread at the moment of delivery. Blocking calls (`recv`,
//! `Ticket::wait`) would wait for time that never passes: don't use them under simulation.

use parking_lot::{Mutex, RwLock};
use std::cmp::Reverse;
use std::collections::{BTreeMap, BinaryHeap, HashMap};
use std::sync::atomic::{AtomicU64, Ordering};
use std::sync::Arc;

use hetcomm_config::Fleet;
use hetcomm_core::{SystemId, Time};
use hetcomm_link::emulation::{DropReason, LinkModel, PositionTable, Verdict};
use hetcomm_link::{FrameSink, Link, LinkCaps, LinkError, Peer};

use crate::comm::{Comm, LocalFleet, OpenEnv};
use crate::error::OpenError;
use crate::runtime::{Clock, SystemCore};
use crate::transports::Hubs;

/// A clock that only the simulator moves.
#[derive(Debug, Default)]
pub struct VirtualClock(AtomicU64);

impl VirtualClock {
    fn set(&self, t: Time) {
        self.0.store(t.as_micros(), Ordering::SeqCst);
    }
}

/// One clock for both times: virtual time is never stepped, and messages are stamped with
/// it as well (the simulated hosts share it).
impl Clock for VirtualClock {
    fn now(&self) -> Time {
        Time(self.0.load(Ordering::SeqCst))
    }
    fn wall(&self, now: Time) -> Time {
        now
    }
}

/// How an emulated link's losses look to the sender under simulation.
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq)]
pub enum LossVisibility {
    /// Lost frames vanish silently, as on a real radio: only acknowledgements reveal them.
    #[default]
    Silent,
    /// The transport tells the sender a frame was lost (the send call fails), as the thesis's
    /// Bluetooth driver reported failed transmissions; the router then retries.
    Reported,
}

/// Options of a simulation.
#[derive(Clone, Debug)]
pub struct SimOptions {
    /// Seeds every emulated link (mixed with each transport's own `seed`).
    pub seed: u64,
    /// Whether lost frames are reported to the sender.
    pub losses: LossVisibility,
    /// Retransmission timing for every router (None: the defaults).
    pub timing: Option<hetcomm_router::Timing>,
}

impl Default for SimOptions {
    fn default() -> Self {
        SimOptions {
            seed: 0,
            losses: LossVisibility::Silent,
            timing: None,
        }
    }
}

/// Frames the simulated network dropped, by reason.
#[derive(Clone, Debug, Default, PartialEq, Eq)]
pub struct SimNetStats {
    /// Frames put on simulated links.
    pub frames_sent: u64,
    /// Frames delivered to a system (duplicates count twice).
    pub frames_delivered: u64,
    /// Drops, by reason name (`loss`, `burst-loss`, `out-of-range`, …).
    pub dropped: BTreeMap<String, u64>,
    /// Frames corrupted in flight (the receiver's checksum drops them).
    pub corrupted: u64,
}

struct FrameEvent {
    to: SystemId,
    transport: usize,
    frame: Vec<u8>,
}

/// A frame in flight, ordered by arrival time, ties in the order they were scheduled.
struct Scheduled {
    at: Time,
    id: u64,
    event: FrameEvent,
}

impl PartialEq for Scheduled {
    fn eq(&self, other: &Self) -> bool {
        (self.at, self.id) == (other.at, other.id)
    }
}
impl Eq for Scheduled {}
impl PartialOrd for Scheduled {
    fn partial_cmp(&self, other: &Self) -> Option<std::cmp::Ordering> {
        Some(self.cmp(other))
    }
}
impl Ord for Scheduled {
    fn cmp(&self, other: &Self) -> std::cmp::Ordering {
        (self.at, self.id).cmp(&(other.at, other.id))
    }
}

/// Wake-ups the systems asked for, by system index (position in [`SimFleet::systems`]):
/// their routers' deadlines and the times their harnesses hold items until. The systems push
/// them as they arm them ([`SimWake`]), so the simulator finds the next one without asking
/// every system at every event (which made a step cost the fleet's size). An entry may be
/// stale (the deadline was cancelled or moved): the simulator checks it against the system
/// before it acts on it.
#[derive(Default)]
struct SimWakeups {
    timers: Mutex<BinaryHeap<Reverse<(Time, usize)>>>,
    held: Mutex<BinaryHeap<Reverse<(Time, usize)>>>,
}

/// One system's way to its simulator's wake-ups ([`crate::runtime::SystemCore::attach_sim`]).
pub(crate) struct SimWake {
    wakeups: Arc<SimWakeups>,
    index: usize,
}

impl SimWake {
    /// The system's router has a deadline at `at`.
    pub(crate) fn timer(&self, at: Time) {
        self.wakeups.timers.lock().push(Reverse((at, self.index)));
    }

    /// The system's harness holds something until `at`.
    pub(crate) fn held(&self, at: Time) {
        self.wakeups.held.lock().push(Reverse((at, self.index)));
    }
}

/// The simulated network: pending frame arrivals, the link models and the endpoints.
pub(crate) struct SimNet {
    seed: u64,
    losses: LossVisibility,
    clock: Arc<VirtualClock>,
    next_event: AtomicU64,
    queue: Mutex<BinaryHeap<Reverse<Scheduled>>>,
    /// (transport index, system) → (sink, link index at that system).
    sinks: RwLock<HashMap<(usize, SystemId), Arc<dyn FrameSink>>>,
    models: Vec<Option<Mutex<LinkModel>>>,
    positions: PositionTable,
    stats: Mutex<SimNetStats>,
    /// Transport names, by index (for injection and recording).
    transports: Vec<String>,
    /// The frames sent while recording is on ([`SimFleet::record_frames`]).
    recorded: Mutex<Option<Vec<SimFrame>>>,
}

/// A frame a system put on a simulated link, as [`SimFleet::record_frames`] keeps it.
#[derive(Clone, Debug, PartialEq, Eq)]
pub struct SimFrame {
    /// The transport's name.
    pub transport: String,
    /// The system that sent it.
    pub from: SystemId,
    /// The system it was sent to.
    pub to: SystemId,
    /// When it was sent (virtual time).
    pub at: Time,
    /// Its bytes as the link got them: after the sender's layers, so sealed on a secured
    /// transport.
    pub bytes: Vec<u8>,
}

/// Why [`SimFleet::inject_frame`] could not put a frame on a link.
#[derive(Debug, thiserror::Error)]
#[non_exhaustive]
pub enum InjectError {
    /// The fleet has no transport of that name.
    #[error("no transport named `{0}` in the simulated fleet")]
    UnknownTransport(String),
    /// The fleet has no system of that name, or it has no link on the transport.
    #[error("system `{system}` has no link on transport `{transport}` in the simulation")]
    NotOnTransport {
        /// The system named.
        system: String,
        /// The transport named.
        transport: String,
    },
}

impl SimNet {
    /// A deterministic incarnation per system and seed.
    pub(crate) fn incarnation(&self, system: SystemId) -> u32 {
        let x = self
            .seed
            .wrapping_mul(0x9E37_79B9_7F4A_7C15)
            .wrapping_add(system.0 as u64 + 1);
        (x ^ (x >> 29)) as u32 | 1
    }

    fn push(&self, at: Time, ev: FrameEvent) {
        let id = self.next_event.fetch_add(1, Ordering::Relaxed);
        self.queue
            .lock()
            .push(Reverse(Scheduled { at, id, event: ev }));
    }

    fn next_frame_time(&self) -> Option<Time> {
        self.queue.lock().peek().map(|Reverse(s)| s.at)
    }

    fn pop_due(&self, now: Time) -> Option<FrameEvent> {
        let mut q = self.queue.lock();
        match q.peek() {
            Some(Reverse(s)) if s.at <= now => q.pop().map(|Reverse(s)| s.event),
            _ => None,
        }
    }

    /// Opens the simulated link of `transport` for `local`.
    pub(crate) fn open(
        self: &Arc<Self>,
        transport: usize,
        local: SystemId,
        sink: Arc<dyn FrameSink>,
    ) -> Arc<dyn Link> {
        self.sinks.write().insert((transport, local), sink);
        let max = hetcomm_core::wire::HEADER_LEN + hetcomm_core::wire::MAX_PAYLOAD;
        let lossy = self.models[transport].is_some();
        Arc::new(SimLink {
            net: self.clone(),
            transport,
            local,
            caps: LinkCaps {
                max_frame: max,
                mtu: max,
                reliable: !lossy,
                ordered: !lossy,
                broadcast: false,
            },
        })
    }

    fn count_drop(&self, reason: DropReason) {
        *self
            .stats
            .lock()
            .dropped
            .entry(format!("{reason:?}"))
            .or_default() += 1;
    }
}

struct SimLink {
    net: Arc<SimNet>,
    transport: usize,
    local: SystemId,
    caps: LinkCaps,
}

impl Link for SimLink {
    fn caps(&self) -> LinkCaps {
        self.caps
    }

    fn send(&self, to: SystemId, frame: &[u8]) -> Result<(), LinkError> {
        let net = &self.net;
        if !net.sinks.read().contains_key(&(self.transport, to)) {
            return Err(LinkError::Unreachable {
                peer: to,
                reason: "no such system in the simulation".into(),
            });
        }
        net.stats.lock().frames_sent += 1;
        let now = net.clock.now();
        if let Some(recorded) = net.recorded.lock().as_mut() {
            recorded.push(SimFrame {
                transport: net.transports[self.transport].clone(),
                from: self.local,
                to,
                at: now,
                bytes: frame.to_vec(),
            });
        }
        let Some(model) = &net.models[self.transport] else {
            net.push(
                now,
                FrameEvent {
                    to,
                    transport: self.transport,
                    frame: frame.to_vec(),
                },
            );
            return Ok(());
        };
        let distance = net.positions.distance(self.local, to);
        let verdict = model
            .lock()
            .on_frame(now, self.local, to, frame.len(), distance);
        match verdict {
            Verdict::Drop(reason) => {
                net.count_drop(reason);
                if reason == DropReason::Mtu {
                    return Err(LinkError::TooLarge {
                        len: frame.len(),
                        max: frame.len() - 1,
                    });
                }
                match net.losses {
                    LossVisibility::Silent => Ok(()),
                    LossVisibility::Reported => Err(LinkError::Unreachable {
                        peer: to,
                        reason: format!("transmission failed ({reason:?})"),
                    }),
                }
            }
            Verdict::Deliver { first, duplicate } => {
                for d in std::iter::once(first).chain(duplicate) {
                    let mut bytes = frame.to_vec();
                    if let Some(flip) = d.corrupt {
                        flip.apply(&mut bytes);
                        net.stats.lock().corrupted += 1;
                    }
                    net.push(
                        d.at,
                        FrameEvent {
                            to,
                            transport: self.transport,
                            frame: bytes,
                        },
                    );
                }
                Ok(())
            }
        }
    }
}

/// A whole fleet in virtual time.
pub struct SimFleet {
    fleet: LocalFleet,
    net: Arc<SimNet>,
    cores: Vec<Arc<SystemCore>>,
    wakeups: Arc<SimWakeups>,
}

impl SimFleet {
    /// Opens every system of `fleet` on simulated links, at virtual time zero.
    pub fn open(fleet: Fleet, options: SimOptions) -> Result<SimFleet, OpenError> {
        let clock = Arc::new(VirtualClock::default());
        let mut models = Vec::with_capacity(fleet.transports.len());
        for t in &fleet.transports {
            // The model the kind's layer applies in real time, applied here in virtual time.
            let model = match crate::transports::registry().factory(t.kind) {
                Some(factory) => factory
                    .sim_model(t, options.seed.wrapping_mul(0x2545_F491_4F6C_DD1D))
                    .map_err(|e| OpenError::transport(&t.name, "(simulation)", e))?,
                None => None,
            };
            let model = model.map(Mutex::new);
            models.push(model);
        }
        let positions = PositionTable::new();
        let net = Arc::new(SimNet {
            seed: options.seed,
            losses: options.losses,
            clock: clock.clone(),
            next_event: AtomicU64::new(0),
            queue: Mutex::new(BinaryHeap::new()),
            sinks: RwLock::new(HashMap::new()),
            models,
            positions: positions.clone(),
            stats: Mutex::new(SimNetStats::default()),
            transports: fleet.transports.iter().map(|t| t.name.clone()).collect(),
            recorded: Mutex::new(None),
        });
        let env = OpenEnv {
            hubs: Hubs::default(),
            registry: Default::default(),
            clock,
            sim: Some(net.clone()),
            positions,
            epoch: std::time::Instant::now(),
            timing: options.timing,
            keys: crate::security::KeySource::for_simulation(&fleet, options.seed),
            shapes: Default::default(),
        };
        let fleet = LocalFleet::open_in(Arc::new(fleet), env)?;
        let cores: Vec<Arc<SystemCore>> = fleet
            .systems()
            .iter()
            .map(|c| c.handle.core.clone())
            .collect();
        let wakeups = Arc::new(SimWakeups::default());
        for (index, core) in cores.iter().enumerate() {
            core.attach_sim(SimWake {
                wakeups: wakeups.clone(),
                index,
            });
            if let Some(at) = core.harness.next_due() {
                core.sim_held(at);
            }
        }
        Ok(SimFleet {
            fleet,
            net,
            cores,
            wakeups,
        })
    }

    /// The current virtual time.
    pub fn now(&self) -> Time {
        self.net.clock.now()
    }

    /// One system by name.
    pub fn system(&self, name: &str) -> Result<Comm, OpenError> {
        self.fleet.system(name)
    }

    /// Every system, by id.
    pub fn systems(&self) -> &[Comm] {
        self.fleet.systems()
    }

    /// Positions for distance-dependent links (a virtual environment updates them).
    pub fn positions(&self) -> &PositionTable {
        &self.net.positions
    }

    /// What the simulated network did.
    pub fn net_stats(&self) -> SimNetStats {
        let s = self.net.stats.lock().clone();
        s
    }

    /// Starts (`true`) or stops keeping a copy of every frame the systems put on simulated
    /// links, as the link gets it (sealed, on a secured transport), before the link model
    /// loses, delays or corrupts it. Off by default. For tests that replay or tamper with
    /// real traffic ([`SimFleet::inject_frame`]); recording changes nothing in the run.
    pub fn record_frames(&self, on: bool) {
        let mut recorded = self.net.recorded.lock();
        match (on, recorded.is_some()) {
            (true, false) => *recorded = Some(Vec::new()),
            (false, _) => *recorded = None,
            (true, true) => {}
        }
    }

    /// The frames recorded since the last call (recording stays on).
    pub fn take_recorded(&self) -> Vec<SimFrame> {
        self.net
            .recorded
            .lock()
            .as_mut()
            .map(std::mem::take)
            .unwrap_or_default()
    }

    /// Puts `bytes` on the simulated link of `transport` as if an outsider on that link sent
    /// them to system `to` (a forged, replayed or tampered frame): they arrive at the current
    /// virtual time, when the simulation next runs ([`SimFleet::run_until`]), after the
    /// frames already due then; the link model does not touch them (no loss, delay or
    /// corruption). They go through `to`'s layers (the security layer on a secured
    /// transport) and its router exactly as a frame from the link would, and are counted in
    /// [`SimNetStats::frames_delivered`] but not in `frames_sent`.
    pub fn inject_frame(&self, transport: &str, to: &str, bytes: &[u8]) -> Result<(), InjectError> {
        let index = self
            .net
            .transports
            .iter()
            .position(|t| t == transport)
            .ok_or_else(|| InjectError::UnknownTransport(transport.to_string()))?;
        let not_on = || InjectError::NotOnTransport {
            system: to.to_string(),
            transport: transport.to_string(),
        };
        let id = self.system(to).map_err(|_| not_on())?.id();
        if !self.net.sinks.read().contains_key(&(index, id)) {
            return Err(not_on());
        }
        self.net.push(
            self.now(),
            FrameEvent {
                to: id,
                transport: index,
                frame: bytes.to_vec(),
            },
        );
        Ok(())
    }

    /// Runs every frame arrival and timer due up to `until`, in time order (ties in the order
    /// they were scheduled), then leaves the clock at `until`.
    pub fn run_until(&self, until: Time) {
        self.run(until);
        if until > self.now() {
            self.net.clock.set(until);
        }
    }

    /// Runs until nothing is scheduled (every frame delivered, every timer fired, so every
    /// send has ended) or until `limit`, whichever comes first; the clock stays at the last
    /// event.
    pub fn run_idle(&self, limit: Time) {
        self.run(limit);
    }

    fn run(&self, until: Time) {
        // Deadlines are pushed as they are armed, by the routers' pumps; this catches one
        // armed some other way since the last run (the program's calls between two runs).
        // Nothing is pushed twice (`Timer::arm`).
        for core in &self.cores {
            core.arm_timer(core.next_deadline());
        }
        loop {
            let next_frame = self.net.next_frame_time();
            let next_timer = self.next_timer();
            // What the harness holds back (taps' delays, faults' latency, scheduled
            // injections) is due like a timer.
            let next_held = self.next_held();
            let next_timer = match (next_timer, next_held) {
                (Some(a), Some(b)) => Some(a.min(b)),
                (a, b) => a.or(b),
            };
            let next = match (next_frame, next_timer) {
                (Some(a), Some(b)) => a.min(b),
                (a, b) => match a.or(b) {
                    Some(t) => t,
                    None => break,
                },
            };
            if next > until {
                break;
            }
            let now = next.max(self.now());
            self.net.clock.set(now);
            if next_frame.is_some_and(|t| t <= now) {
                while let Some(ev) = self.net.pop_due(now) {
                    let sink = self.net.sinks.read().get(&(ev.transport, ev.to)).cloned();
                    if let Some(sink) = sink {
                        self.net.stats.lock().frames_delivered += 1;
                        sink.on_frame(&ev.frame, Peer::Unknown);
                    }
                }
            } else if next_held.is_some_and(|t| t <= now) {
                for i in take_due(&self.wakeups.held, now) {
                    let core = &self.cores[i];
                    core.harness.fire_due(core, now);
                    if let Some(at) = core.harness.next_due() {
                        core.sim_held(at);
                    }
                }
            } else {
                for i in take_due(&self.wakeups.timers, now) {
                    let core = &self.cores[i];
                    core.sim_timer_taken(now);
                    if core.next_deadline().is_some_and(|d| d <= now) {
                        // Re-arms through the router's pump.
                        core.fire_timers();
                    }
                    core.arm_timer(core.next_deadline());
                }
            }
        }
    }

    /// The earliest router deadline of any system. Entries that are no longer a system's
    /// deadline (acknowledged sends, moved deadlines) are dropped on the way, and the
    /// system's real deadline armed in their place.
    fn next_timer(&self) -> Option<Time> {
        loop {
            let (at, i) = {
                let mut q = self.wakeups.timers.lock();
                let &Reverse((at, i)) = q.peek()?;
                let actual = self.cores[i].next_deadline();
                if actual == Some(at) {
                    return Some(at);
                }
                q.pop();
                (at, i)
            };
            // Outside the queue's lock: arming pushes into it.
            let core = &self.cores[i];
            core.sim_timer_taken(at);
            core.arm_timer(core.next_deadline());
        }
    }

    /// The earliest time any system's harness holds something until (stale entries dropped,
    /// as in [`SimFleet::next_timer`]).
    fn next_held(&self) -> Option<Time> {
        let mut q = self.wakeups.held.lock();
        loop {
            let &Reverse((at, i)) = q.peek()?;
            let actual = self.cores[i].harness.next_due();
            if actual == Some(at) {
                return Some(at);
            }
            q.pop();
            if let Some(t) = actual {
                q.push(Reverse((t, i)));
            }
        }
    }
}

/// The systems with a wake-up due by `now` in `queue`, each once, in index order (the order
/// the simulator has always fired them in); their entries are taken out.
fn take_due(queue: &Mutex<BinaryHeap<Reverse<(Time, usize)>>>, now: Time) -> Vec<usize> {
    let mut due = Vec::new();
    let mut q = queue.lock();
    while let Some(&Reverse((at, i))) = q.peek() {
        if at > now {
            break;
        }
        q.pop();
        due.push(i);
    }
    drop(q);
    due.sort_unstable();
    due.dedup();
    due
}

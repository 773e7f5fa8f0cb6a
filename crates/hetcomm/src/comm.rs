//! Opening systems: [`Comm`] is one system of a fleet; [`LocalFleet`] is every system of a
//! fleet in this process.

use parking_lot::RwLock;
use std::collections::{BTreeSet, HashMap};
use std::path::Path;
use std::sync::Arc;

use hetcomm_config::{DeliveryMode, Fleet};
use hetcomm_core::{Message, SystemId, Time, TypeRegistry, TypeRegistryError};

use hetcomm_link::LinkStats;
use hetcomm_router::{Route, Router, RouterConfig, RouterStats};

use crate::error::OpenError;
use crate::inbox::InboxStats;
use crate::module::Module;
use crate::observe::{Observer, ObserverHandle};
use crate::runtime::{intern, Clock, Directory, SystemClock, SystemCore};
use crate::security::{KeySource, OpenOptions};
use crate::sim::SimNet;
use crate::transports::{open_link, Hubs};

/// How systems are opened: with real links and the system clock, or inside a simulation.
#[derive(Clone)]
pub(crate) struct OpenEnv {
    pub hubs: Hubs,
    pub registry: Arc<RwLock<TypeRegistry>>,
    pub clock: Arc<dyn Clock>,
    /// Present under simulation: every link is a simulated one.
    pub sim: Option<Arc<SimNet>>,
    /// Shared by the emulated links of one process, so distance-dependent loss sees the
    /// positions a virtual environment publishes.
    pub positions: hetcomm_link::emulation::PositionTable,
    /// The instant emulated links count their outage schedules from.
    pub epoch: std::time::Instant,
    /// Retransmission timing override.
    pub timing: Option<hetcomm_router::Timing>,
    /// Where secured transports get their keys.
    pub keys: KeySource,
    /// The message types the program declared ([`OpenOptions::message`]).
    pub shapes: hetcomm_link::shape::MessageShapes,
}

impl OpenEnv {
    pub(crate) fn real(hubs: Hubs) -> Self {
        OpenEnv {
            hubs,
            registry: Default::default(),
            clock: Arc::new(SystemClock),
            sim: None,
            positions: Default::default(),
            epoch: std::time::Instant::now(),
            timing: None,
            keys: KeySource::Fleet { private_key: None },
            shapes: Default::default(),
        }
    }
}

/// Shuts its system down when the last [`Comm`] or [`Module`] handle goes.
pub(crate) struct SystemHandle {
    pub core: Arc<SystemCore>,
    pub fleet: Arc<Fleet>,
    /// Per link: (transport name, where it listens, if it does).
    pub endpoints: Vec<(String, Option<String>)>,
    /// The number of the last switch [`Comm::path_changes`] returned.
    pub path_cursor: std::sync::atomic::AtomicU64,
    /// The fleet last applied by a reload (`fleet` until one is): what the next is compared
    /// with ([`Comm::reload`]).
    pub loaded: parking_lot::Mutex<Arc<Fleet>>,
}

impl Drop for SystemHandle {
    fn drop(&mut self) {
        self.core.shutdown();
    }
}

/// One opened system of a fleet: the autonomy code's handle to the communication layer.
/// Cheap to clone; the system closes when the last handle (including [`Module`]s) is dropped.
///
/// ```
/// # use hetcomm::*;
/// let fleet = hetcomm::config::parse_str(r#"
///     [systems]
///     Alpha = 0
///     Charlie = 1
///     [modules]
///     Plan = 0
///     [transports.wired]
///     kind = "inproc"
///     [table]
///     columns = ["Alpha", "Charlie"]
///     Alpha = ["X", "wired"]
///     Charlie = ["wired", "X"]
/// "#, "doc.toml", None).unwrap();
/// let local = LocalFleet::open(fleet).unwrap();
/// let alpha = local.system("Alpha").unwrap().module("Plan").unwrap();
/// let charlie = local.system("Charlie").unwrap().module("Plan").unwrap();
/// let outcome = alpha.send_raw("Charlie", "Plan", MessageType(9), &[0xc0], Default::default()).unwrap().wait();
/// assert!(matches!(outcome, Outcome::Delivered { .. }));
/// assert!(charlie.has_message());
/// ```
#[derive(Clone)]
pub struct Comm {
    pub(crate) handle: Arc<SystemHandle>,
}

/// A destination's sends moved from one transport to another ([`Comm::path_changes`]).
#[derive(Clone, Debug, PartialEq, Eq)]
pub struct PathSwitch {
    /// The destination system's name.
    pub to: String,
    /// The transport its sends took until then.
    pub from: String,
    /// The transport they take from then on.
    pub now: String,
    /// When the router decided it, on the system's (monotonic) clock.
    pub at: Time,
    /// This system's switches so far, this one included (1 for the first).
    pub number: u64,
}

/// Why [`Comm::set_transports`] changed nothing.
#[derive(Debug, Clone, PartialEq, Eq, thiserror::Error)]
#[non_exhaustive]
pub enum PathsError {
    /// No system of that name in the fleet.
    #[error("no system `{0}` in the fleet")]
    UnknownSystem(String),
    /// The table says X from this system to that one.
    #[error("the communication table allows no traffic to `{0}` (X)")]
    NoTraffic(String),
    /// No transport was given.
    #[error("give at least one transport")]
    Empty,
    /// A transport the pair's table cell does not list.
    #[error("transport `{transport}` does not carry traffic to `{to}`: its table cell lists `{listed}` (a transport outside the cell is neither open here nor accepted by the peer's security layer)")]
    NotListed {
        /// The transport given.
        transport: String,
        /// The destination.
        to: String,
        /// What the cell lists.
        listed: String,
    },
}

/// One transport that may carry a pair's traffic, as the router sees it ([`Comm::paths`]).
#[derive(Clone, Debug, PartialEq, Eq)]
pub struct PathStatus {
    /// The transport's name in the fleet file.
    pub transport: String,
    /// Whether sends may take it (false while it is judged down: docs/failover.md).
    pub up: bool,
    /// Whether sends take it now.
    pub active: bool,
    /// The smoothed round-trip time measured on it, once measured.
    pub srtt: Option<std::time::Duration>,
    /// Its retransmission timeout now (before back-off): from its RTT once measured, the
    /// router's initial timeout until then.
    pub rto: std::time::Duration,
}

/// Everything counted about one system.
#[derive(Clone, Debug)]
pub struct SystemStats {
    /// Router counters (sends, outcomes, retransmissions, drops).
    pub router: RouterStats,
    /// Per module: (name, inbox counters).
    pub inboxes: Vec<(String, InboxStats)>,
    /// Per link: (transport name, counters). A link's `frames_dropped` here also counts
    /// the frames it delivered while the system was opening that did not fit what the system
    /// holds for its router meanwhile (4096 frames, 16 MiB): frames that arrive before
    /// [`Comm::open`] returns are otherwise handed to the router when it is ready.
    pub links: Vec<(String, LinkStats)>,
    /// Callback invocations that panicked or could not decode their message.
    pub callback_failures: u64,
    /// Frames this system's links held back for a moment to share a datagram or write with
    /// the frames after them (see `batch_linger_us`); 0 while every frame went at once.
    pub held_frames: u64,
    /// Messages dropped because they were for a module id this system's fleet file does not
    /// have: the sender's fleet file differs from this one.
    pub unknown_module: u64,
    /// The last path switches (up to 16, oldest first; `router.path_changes` counts them
    /// all): which destination's sends moved from which transport to which, and when.
    pub path_switches: Vec<PathSwitch>,
}

impl Comm {
    /// Loads a fleet file and opens one system of it.
    pub fn open(path: impl AsRef<Path>, system: &str) -> Result<Comm, OpenError> {
        Self::open_with(path, system, OpenOptions::new())
    }

    /// [`Comm::open`] with options (this system's private key, for a secured fleet).
    pub fn open_with(
        path: impl AsRef<Path>,
        system: &str,
        options: OpenOptions,
    ) -> Result<Comm, OpenError> {
        let path = path.as_ref();
        let fleet = crate::transports::load_fleet(path)?;
        let key = std::fs::canonicalize(path)
            .unwrap_or_else(|_| path.to_path_buf())
            .display()
            .to_string();
        let mut env = OpenEnv::real(Hubs::for_fleet_key(&key));
        env.keys = KeySource::Fleet {
            private_key: options.private_key,
        };
        env.shapes = options.shapes;
        Self::open_fleet_with(Arc::new(fleet), system, &env)
    }

    /// Opens one system of an already loaded fleet. In-process transports of systems opened
    /// this way meet only if they share `fleet.source` (the same file).
    pub fn open_fleet(fleet: &Fleet, system: &str) -> Result<Comm, OpenError> {
        Self::open_fleet_options(fleet, system, OpenOptions::new())
    }

    /// [`Comm::open_fleet`] with options (this system's private key, for a secured fleet).
    pub fn open_fleet_options(
        fleet: &Fleet,
        system: &str,
        options: OpenOptions,
    ) -> Result<Comm, OpenError> {
        let key = fleet
            .source
            .as_ref()
            .map(|p| p.display().to_string())
            .unwrap_or_else(|| format!("{:?}", fleet.name));
        let mut env = OpenEnv::real(Hubs::for_fleet_key(&key));
        env.keys = KeySource::Fleet {
            private_key: options.private_key,
        };
        env.shapes = options.shapes;
        Self::open_fleet_with(Arc::new(fleet.clone()), system, &env)
    }

    pub(crate) fn open_fleet_with(
        fleet: Arc<Fleet>,
        system: &str,
        env: &OpenEnv,
    ) -> Result<Comm, OpenError> {
        let directory = Arc::new(directory(&fleet));
        let me = fleet
            .system_by_name(system)
            .ok_or_else(|| unknown_system(system, fleet.systems.iter().map(|s| s.name.as_str())))?
            .id;
        // The links this system needs: every transport that carries traffic from or to it,
        // fallbacks included.
        let mut used: Vec<usize> = fleet
            .table_entries()
            .filter(|&(s, d, _)| s == me || d == me)
            .map(|(_, _, t)| t)
            .collect::<BTreeSet<_>>()
            .into_iter()
            .collect();
        used.sort_unstable();
        let link_index: HashMap<usize, usize> =
            used.iter().enumerate().map(|(i, &t)| (t, i)).collect();

        let modules = fleet.modules.iter().map(|m| (m.id, m.inbox)).collect();
        // The router is built after the links (it needs their frame limits), so start with a
        // placeholder that has no routes. No frame reaches it: links may deliver as soon as
        // they are open, but the system holds what arrives until `start`, which hands it to
        // the real router installed below (`runtime::Opening`).
        let incarnation = match &env.sim {
            // Deterministic under simulation: the same seed gives the same frames.
            Some(net) => net.incarnation(me),
            None => new_incarnation(),
        };
        let core = SystemCore::new(
            me,
            directory,
            env.registry.clone(),
            modules,
            Router::new(RouterConfig::new(me, incarnation, vec![])),
            env.clock.clone(),
            env.sim.is_some(),
        );
        let mut links = Vec::with_capacity(used.len());
        let mut endpoints = Vec::with_capacity(used.len());
        let mut direct = Vec::with_capacity(used.len());
        for (i, &t) in used.iter().enumerate() {
            let opened = open_link(&fleet, t, me, core.sink(i), env)?;
            links.push(opened.link);
            endpoints.push((fleet.transports[t].name.clone(), opened.local_address));
            if let Some(name) = &opened.direct {
                env.hubs.register(name, &core);
            }
            direct.push(opened.direct);
        }
        core.set_direct(env.hubs.clone(), direct);
        core.set_link_names(
            used.iter()
                .map(|&t| crate::runtime::intern(&fleet.transports[t].name))
                .collect(),
        );
        let routes: Vec<(SystemId, Route)> = fleet
            .table
            .iter()
            .filter(|((s, _), _)| *s == me)
            .map(|(&(_, dst), &t)| {
                let def = &fleet.transports[t];
                let link = link_index[&t];
                // A message must fit every path it may take: the smallest frame limit of the
                // cell's transports.
                let max_frame = fleet
                    .fallbacks
                    .get(&(me, dst))
                    .into_iter()
                    .flatten()
                    .map(|f| links[link_index[f]].caps().max_frame)
                    .fold(links[link].caps().max_frame, usize::min);
                (
                    dst,
                    Route {
                        link,
                        tag: def.tag,
                        acknowledged: def.delivery == DeliveryMode::Acknowledged,
                        attempts: def.attempts.max(1),
                        max_frame,
                        max_in_flight: def.max_in_flight.max(1),
                        max_in_flight_bytes: def.max_in_flight_bytes.max(1),
                    },
                )
            })
            .collect();
        let mut config = RouterConfig::new(me, incarnation, routes);
        config.known_systems = fleet.systems.iter().map(|s| s.id).collect();
        // The other transports of each cell, in order of preference: the router fails over
        // to them (docs/failover.md).
        let path_of = |t: usize| hetcomm_router::Path {
            link: link_index[&t],
            tag: fleet.transports[t].tag,
        };
        config.fallbacks = fleet
            .fallbacks
            .iter()
            .filter(|((s, _), _)| *s == me)
            .flat_map(|(&(_, dst), rest)| rest.iter().map(move |&t| (dst, path_of(t))))
            .collect();
        // Who may send here, on which link: a frame every system of a transport receives
        // (a native broadcast) is taken only where the table allows it.
        config.inbound = fleet
            .table_entries()
            .filter(|&(_, d, _)| d == me)
            .filter_map(|(s, _, t)| link_index.get(&t).map(|&l| (s, l)))
            .collect();
        config.ordered_sources = fleet
            .table
            .iter()
            .filter(|((_, d), &t)| *d == me && fleet.transports[t].ordered)
            .map(|((s, _), _)| *s)
            .collect();
        // Pairs with several transports fail over and back by what the router sees too
        // (a route of one transport is not judged: docs/failover.md).
        config.health = hetcomm_router::Health::failover();
        if let Some(timing) = env.timing {
            config.timing = timing;
        }
        *core.router() = Router::new(config);
        let linger = used
            .iter()
            .map(|&t| fleet.transports[t].batch_linger_us)
            .collect();
        core.start(links, linger, env.sim.is_none())
            .map_err(|e| OpenError::transport("(timer)", system, e))?;
        let comm = Comm {
            handle: Arc::new(SystemHandle {
                core,
                loaded: parking_lot::Mutex::new(fleet.clone()),
                fleet,
                endpoints,
                path_cursor: Default::default(),
            }),
        };
        crate::harness::scenario::install_fleet_taps(&comm)?;
        Ok(comm)
    }

    /// This system's friendly name.
    pub fn name(&self) -> &str {
        self.handle.core.name
    }

    /// This system's id.
    pub fn id(&self) -> SystemId {
        self.handle.core.id
    }

    /// The transports this system has open: (transport name, where it listens — e.g.
    /// `udp://127.0.0.1:40123` —, or None for transports without an address).
    pub fn endpoints(&self) -> &[(String, Option<String>)] {
        &self.handle.endpoints
    }

    /// The fleet it belongs to.
    pub fn fleet(&self) -> &Fleet {
        &self.handle.fleet
    }

    /// A handle to one of this system's modules.
    pub fn module(&self, name: &str) -> Result<Module, OpenError> {
        let core = &self.handle.core;
        let module = core
            .directory
            .module_ids
            .get(name)
            .and_then(|id| core.modules.get(id))
            .ok_or_else(|| OpenError::UnknownModule {
                name: name.to_string(),
                known: self
                    .handle
                    .fleet
                    .modules
                    .iter()
                    .map(|m| m.name.as_str())
                    .collect::<Vec<_>>()
                    .join(", "),
            })?;
        Ok(Module {
            sys: self.handle.clone(),
            core: module.clone(),
        })
    }

    /// Registers a message type; fails if another type already has its id. Sending,
    /// receiving or subscribing to a type registers it too.
    pub fn register<M: Message>(&self) -> Result<(), TypeRegistryError> {
        self.handle.core.registry.write().register::<M>()
    }

    /// Registers `observer` to see every send, receipt and outcome of this system, whichever
    /// way each message goes (router, unacknowledged fast path, in-process hand-over), in
    /// real time and under simulation ([`crate::observe`]). Several observers may be
    /// registered; each stays until its handle is dropped or
    /// [`removed`](ObserverHandle::remove). While none is registered, observing costs one
    /// relaxed atomic load per send, receipt and outcome.
    ///
    /// ```
    /// use std::sync::atomic::{AtomicU64, Ordering};
    /// use std::sync::Arc;
    /// use hetcomm::observe::{Observer, OutcomeRecord, SendRecord};
    /// # use hetcomm::*;
    /// # let fleet = hetcomm::config::parse_str(r#"
    /// #     [systems]
    /// #     Alpha = 0
    /// #     Charlie = 1
    /// #     [modules]
    /// #     Plan = 0
    /// #     [transports.wired]
    /// #     kind = "inproc"
    /// #     [table]
    /// #     columns = ["Alpha", "Charlie"]
    /// #     Alpha = ["X", "wired"]
    /// #     Charlie = ["wired", "X"]
    /// # "#, "doc.toml", None).unwrap();
    /// # let local = LocalFleet::open(fleet).unwrap();
    ///
    /// /// Counts sends and delivered outcomes.
    /// #[derive(Default)]
    /// struct Counter {
    ///     sends: AtomicU64,
    ///     delivered: AtomicU64,
    /// }
    ///
    /// impl Observer for Counter {
    ///     fn on_send(&self, _: &SendRecord<'_>) {
    ///         self.sends.fetch_add(1, Ordering::Relaxed);
    ///     }
    ///     fn on_outcome(&self, r: &OutcomeRecord<'_>) {
    ///         if r.outcome.is_success() {
    ///             self.delivered.fetch_add(1, Ordering::Relaxed);
    ///         }
    ///     }
    /// }
    ///
    /// let alpha = local.system("Alpha").unwrap();
    /// let counter = Arc::new(Counter::default());
    /// let handle = alpha.observe(counter.clone());
    /// let plan = alpha.module("Plan").unwrap();
    /// plan.send_raw("Charlie", "Plan", MessageType(9), &[1], Default::default()).unwrap().wait();
    /// assert_eq!(counter.sends.load(Ordering::Relaxed), 1);
    /// assert_eq!(counter.delivered.load(Ordering::Relaxed), 1);
    ///
    /// drop(handle); // unregistered: later sends are not seen
    /// plan.send_raw("Charlie", "Plan", MessageType(9), &[2], Default::default()).unwrap().wait();
    /// assert_eq!(counter.sends.load(Ordering::Relaxed), 1);
    /// ```
    pub fn observe(&self, observer: Arc<dyn Observer>) -> ObserverHandle {
        ObserverHandle::register(&self.handle.core, observer)
    }

    /// The changes of the transport each destination's sends take, oldest first, since the
    /// last call of this (on any clone of this handle; at most the last 1024;
    /// `SystemStats::router.path_changes` counts them all). Only pairs whose table cell lists
    /// several transports change (docs/failover.md). Other consumers are not affected: a
    /// [`Comm::watch_paths`] or an [`Observer::on_path_change`](crate::Observer::on_path_change)
    /// sees every switch too.
    pub fn path_changes(&self) -> Vec<PathSwitch> {
        use std::sync::atomic::Ordering;
        let after = self.handle.path_cursor.load(Ordering::Acquire);
        let (list, newest) = self.handle.core.path_log.since(after);
        // Two threads calling at once may both get a switch; neither misses one.
        self.handle.path_cursor.fetch_max(newest, Ordering::AcqRel);
        list
    }

    /// A queue of this system's path switches from now on, for a consumer of its own (each
    /// watch sees every switch, whatever others read): an [`Observer`] underneath.
    pub fn watch_paths(&self) -> crate::PathWatch {
        crate::PathWatch::new(&self.handle.core)
    }

    /// The transports that may carry this system's traffic to `system`, in order of
    /// preference, with what the router knows of each: whether it is up and whether sends
    /// take it now. Empty when the table says X (or there is no such system).
    pub fn paths(&self, system: &str) -> Vec<PathStatus> {
        let core = &self.handle.core;
        let Some(id) = self.handle.fleet.system_by_name(system).map(|s| s.id) else {
            return Vec::new();
        };
        let paths = core.router().paths(id);
        paths
            .into_iter()
            .map(|p| PathStatus {
                transport: core.link_name(p.path.link).unwrap_or("?").to_string(),
                up: p.up,
                active: p.active,
                srtt: p.srtt,
                rto: p.rto,
            })
            .collect()
    }

    /// Changes, while running, the transports that carry this system's traffic to
    /// `system`, in order of preference (the first is taken while it is healthy; see
    /// docs/failover.md). Each must be one the fleet file lists for that pair (its table
    /// cell): those are the links this system opened for it, and the ones the peer's
    /// security layer accepts the pair's frames on. A reorder or a subset of the cell,
    /// then, e.g. `["wired"]` to move a pair off its Wi-Fi now, or `["wifi", "wired"]` to
    /// bring it back. Sends waiting for an acknowledgement on a transport left out go again
    /// on the new first choice. Nothing changes when the call is refused.
    pub fn set_transports(&self, system: &str, transports: &[&str]) -> Result<(), PathsError> {
        let fleet = &self.handle.fleet;
        let core = &self.handle.core;
        let to = fleet
            .system_by_name(system)
            .ok_or_else(|| PathsError::UnknownSystem(system.to_string()))?
            .id;
        let listed: Vec<&str> = fleet
            .transports_for(core.id, to)
            .into_iter()
            .map(|i| fleet.transports[i].name.as_str())
            .collect();
        if listed.is_empty() {
            return Err(PathsError::NoTraffic(system.to_string()));
        }
        if transports.is_empty() {
            return Err(PathsError::Empty);
        }
        let mut paths = Vec::with_capacity(transports.len());
        for &name in transports {
            let link = (0..)
                .map_while(|l| core.link_name(l).map(|n| (l, n)))
                .find(|(_, n)| *n == name)
                .map(|(l, _)| l)
                .filter(|_| listed.contains(&name))
                .ok_or_else(|| PathsError::NotListed {
                    transport: name.to_string(),
                    to: system.to_string(),
                    listed: listed.join(","),
                })?;
            let tag = fleet.transport(name).map_or(0, |t| t.tag);
            paths.push(hetcomm_router::Path { link, tag });
        }
        let now = core.clock.now();
        let mut router = core.router();
        router.set_paths(now, to, &paths);
        core.pump_at(router, now);
        Ok(())
    }

    /// Counters for this system.
    pub fn stats(&self) -> SystemStats {
        let core = &self.handle.core;
        let mut router = core.router().stats();
        // Messages other systems of this process handed over directly never pass this
        // system's router; they are still messages it received.
        router.received += core
            .direct_received
            .load(std::sync::atomic::Ordering::Relaxed);
        let mut inboxes: Vec<(String, InboxStats)> = core
            .modules
            .values()
            .map(|m| (m.name.to_string(), m.inbox.stats()))
            .collect();
        inboxes.sort_by(|a, b| a.0.cmp(&b.0));
        let links = core
            .links()
            .iter()
            .zip(&self.handle.endpoints)
            .enumerate()
            .map(|(i, (l, (name, _)))| {
                let mut stats = l.stats();
                stats.frames_dropped += core.opening.dropped(i);
                (name.clone(), stats)
            })
            .collect();
        let callback_failures = core
            .modules
            .values()
            .map(|m| {
                m.callback_failures
                    .load(std::sync::atomic::Ordering::Relaxed)
            })
            .sum();
        SystemStats {
            router,
            inboxes,
            links,
            callback_failures,
            held_frames: core.held_frames(),
            unknown_module: core
                .unknown_module
                .load(std::sync::atomic::Ordering::Relaxed),
            path_switches: core.path_log.last(16),
        }
    }
}

/// "No system named …", listing the fleet's systems.
fn unknown_system<'a>(name: &str, known: impl Iterator<Item = &'a str>) -> OpenError {
    OpenError::UnknownSystem {
        name: name.to_string(),
        known: known.collect::<Vec<_>>().join(", "),
    }
}

fn directory(fleet: &Fleet) -> Directory {
    Directory {
        systems: fleet
            .systems
            .iter()
            .map(|s| (s.id.0, intern(&s.name)))
            .collect(),
        system_ids: fleet
            .systems
            .iter()
            .map(|s| (s.name.clone(), s.id))
            .collect(),
        modules: fleet
            .modules
            .iter()
            .map(|m| (m.id.0, intern(&m.name)))
            .collect(),
        module_ids: fleet
            .modules
            .iter()
            .map(|m| (m.name.clone(), m.id))
            .collect(),
    }
}

/// A number that differs between starts of a process (time mixed with the process id), so a
/// restarted sender's sequence numbers are not taken for duplicates.
fn new_incarnation() -> u32 {
    use std::sync::atomic::{AtomicU32, Ordering};
    static COUNTER: AtomicU32 = AtomicU32::new(0);
    let t = std::time::SystemTime::now()
        .duration_since(std::time::UNIX_EPOCH)
        .unwrap_or_default();
    let mixed = (t.as_nanos() as u64)
        ^ ((std::process::id() as u64) << 32)
        ^ (COUNTER.fetch_add(1, Ordering::Relaxed) as u64).wrapping_mul(0x9E37_79B9_7F4A_7C15);
    (mixed ^ (mixed >> 32)) as u32
}

/// Every system of a fleet, opened in this process (the in-process transport connects them).
pub struct LocalFleet {
    systems: Vec<Comm>,
    positions: hetcomm_link::emulation::PositionTable,
}

impl LocalFleet {
    /// Opens every system of `fleet`. Secured transports use the fleet file's keys, or, when
    /// it names none, keys generated for this run (every system is in this process).
    pub fn open(fleet: Fleet) -> Result<LocalFleet, OpenError> {
        let mut env = OpenEnv::real(Hubs::default());
        env.keys = KeySource::for_local_fleet(&fleet);
        Self::open_in(Arc::new(fleet), env)
    }

    /// Opens only the named systems of `fleet` in this process; the others run elsewhere
    /// (their traffic must then use network transports). Unknown names are an error.
    pub fn open_systems(fleet: Fleet, names: &[&str]) -> Result<LocalFleet, OpenError> {
        Self::open_systems_with(fleet, names, OpenOptions::new())
    }

    /// [`LocalFleet::open_systems`] with options: the message types declared with
    /// [`OpenOptions::message`] are checked by every system's transports. A private key is
    /// one system's: it is used when `names` is that one system; with several, each system's
    /// key comes from the fleet file or the environment, as for `open_systems` (with every
    /// system of a fleet whose file names no keys, keys made for the run, as for
    /// [`LocalFleet::open`]).
    pub fn open_systems_with(
        fleet: Fleet,
        names: &[&str],
        options: OpenOptions,
    ) -> Result<LocalFleet, OpenError> {
        for name in names {
            if fleet.system_by_name(name).is_none() {
                return Err(unknown_system(
                    name,
                    fleet.systems.iter().map(|s| s.name.as_str()),
                ));
            }
        }
        let fleet = Arc::new(fleet);
        let mut env = OpenEnv::real(Hubs::default());
        if names.len() == 1 {
            env.keys = KeySource::Fleet {
                private_key: options.private_key,
            };
        } else if fleet
            .systems
            .iter()
            .all(|s| names.contains(&s.name.as_str()))
        {
            // Every system runs here: as for `LocalFleet::open`, keys made for the run serve
            // when the file names none (nobody outside the process can join).
            env.keys = KeySource::for_local_fleet(&fleet);
        }
        env.shapes = options.shapes;
        let systems = names
            .iter()
            .map(|name| Comm::open_fleet_with(fleet.clone(), name, &env))
            .collect::<Result<Vec<_>, _>>()?;
        Ok(LocalFleet {
            systems,
            positions: env.positions.clone(),
        })
    }

    pub(crate) fn open_in(fleet: Arc<Fleet>, env: OpenEnv) -> Result<LocalFleet, OpenError> {
        let systems = fleet
            .systems
            .iter()
            .map(|s| Comm::open_fleet_with(fleet.clone(), &s.name, &env))
            .collect::<Result<Vec<_>, _>>()?;
        Ok(LocalFleet {
            systems,
            positions: env.positions.clone(),
        })
    }

    /// Where systems are, for distance-dependent emulated links: a virtual environment sets
    /// positions here while the fleet runs.
    pub fn positions(&self) -> &hetcomm_link::emulation::PositionTable {
        &self.positions
    }

    /// Loads a fleet file and opens every system of it.
    pub fn open_file(path: impl AsRef<Path>) -> Result<LocalFleet, OpenError> {
        Self::open(crate::transports::load_fleet(path.as_ref())?)
    }

    /// One system by name.
    pub fn system(&self, name: &str) -> Result<Comm, OpenError> {
        self.systems
            .iter()
            .find(|c| c.name() == name)
            .cloned()
            .ok_or_else(|| unknown_system(name, self.systems.iter().map(|c| c.name())))
    }

    /// Every system, by id.
    pub fn systems(&self) -> &[Comm] {
        &self.systems
    }
}

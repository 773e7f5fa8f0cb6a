//! The `shm` link: a publisher and notifier per destination, a subscriber and listener of its
//! own (see the crate docs).

use parking_lot::Mutex;
use std::collections::HashMap;
use std::os::fd::RawFd;
use std::path::Path;
use std::sync::atomic::{AtomicBool, AtomicU64, Ordering};
use std::sync::Arc;

use hetcomm_core::SystemId;
use hetcomm_link::{FrameSink, Link, LinkCaps, LinkError, LinkStats, Peer, Readable};
use iceoryx2::port::listener::Listener;
use iceoryx2::port::notifier::Notifier;
use iceoryx2::port::publisher::Publisher;
use iceoryx2::port::subscriber::Subscriber;
use iceoryx2::port::{BackpressureAction, BackpressureInfo, LoanError};
use iceoryx2::prelude::*;
use iceoryx2::service::port_factory::publish_subscribe::PortFactory as PubSubFactory;

use crate::liveness::Liveness;
use crate::memory::{self, SHM_DIR};
use crate::settings::{service_name, BORROWED, LOANS};
use crate::spinning::{OwnFlag, PeerFlag};
use crate::{IpcService, ShmLinkConfig, ShmOpenError};

type Pub = Publisher<IpcService, [u8], ()>;
type Sub = Subscriber<IpcService, [u8], ()>;

/// One destination: its service and this link's ports on it.
struct Dest {
    name: String,
    service_name: String,
    publisher: Pub,
    notifier: Notifier<IpcService>,
    /// Whether the destination spins (then its notification is skipped).
    spinning: PeerFlag,
    service: PubSubFactory<IpcService, [u8], ()>,
}

/// Counters of a link.
#[derive(Default)]
pub(crate) struct Counters {
    sent: AtomicU64,
    received: AtomicU64,
    dropped: AtomicU64,
    congested: AtomicU64,
    unreachable: AtomicU64,
    oversize_received: AtomicU64,
    receive_errors: AtomicU64,
    pub(crate) peers_died: AtomicU64,
    pub(crate) cleanups_failed: AtomicU64,
    pub(crate) connects: AtomicU64,
}

/// What an `shm` link counted besides [`LinkStats`] ([`ShmLink::shm_stats`]).
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq)]
pub struct ShmStats {
    /// Sends refused because the destination's queue was full (each also in `frames_dropped`).
    pub congested: u64,
    /// Sends refused because nobody had the destination's service open.
    pub unreachable: u64,
    /// Samples received larger than `max_frame` (from a foreign publisher): dropped, counted.
    pub oversize_received: u64,
    /// Samples iceoryx2 could not hand over (a corrupted connection or segment): counted.
    pub receive_errors: u64,
    /// Peers this link found dead (their process gone without closing); one that another
    /// process cleaned up first is reported down but not counted here.
    pub peers_died: u64,
    /// Dead peers whose resources this link could not remove itself (another process, or
    /// iceoryx2 on a port update, removed them first; or they are another user's).
    pub cleanups_failed: u64,
}

/// A system's endpoint on an `shm` transport. See the crate docs.
pub struct ShmLink {
    local_service: String,
    dests: HashMap<SystemId, Dest>,
    subscriber: Sub,
    listener: Listener<IpcService>,
    /// A notifier on its own event service: wakes its own descriptor when a read stopped at
    /// its budget with samples left, so they are not left waiting for the next sender.
    self_wake: Notifier<IpcService>,
    fd: RawFd,
    /// This link's flag for its senders (`crate::spinning`), if iceoryx2 made one.
    own_flag: Option<OwnFlag>,
    /// A thread spins on this link now (`Readable::set_spinning`).
    spinning: AtomicBool,
    sink: Arc<dyn FrameSink>,
    counters: Arc<Counters>,
    liveness: Liveness,
    max_frame: usize,
    // Dropped last: the ports above belong to it.
    _node: Mutex<Node<IpcService>>,
}

/// Says what an iceoryx2 error means for a user, from its name.
fn explain(what: &str, service: &str, e: impl std::fmt::Debug) -> ShmOpenError {
    let code = format!("{e:?}");
    let hint = if code.contains("InsufficientPermissions") {
        "its files belong to another user (shared memory is owner-only): run every process of \
         the fleet as the same user, or remove the other user's leftovers"
    } else if code.contains("IncompatibleTypes") || code.contains("IncompatibleMessagingPattern") {
        "a service of that name exists with another payload type or pattern: something that is \
         not a hetcomm `shm` transport uses the name; change the transport's `prefix` or `fleet`"
    } else if code.contains("Corrupted") || code.contains("Undefined") {
        "its files in shared memory are damaged or not iceoryx2's; remove them (see \
         docs/shm.md, \"Leftovers\") or change the transport's `prefix`"
    } else if code.contains("DoesNotSupportRequested") || code.contains("IncompatibleOverflow") {
        "the service was created with other limits (`queue_depth`, `max_publishers`, \
         `max_subscribers`) than this process's fleet file has: give every process the same \
         fleet file"
    } else if code.contains("ExceedsMaxSupportedSubscribers")
        || code.contains("ExceedsMaxSupportedListeners")
    {
        "another process already has this system open on this transport (one process per \
         system), or raise `max_subscribers`"
    } else if code.contains("ExceedsMaxSupported") {
        "the service admits no more senders: raise the transport's `max_publishers`"
    } else {
        "see the cause; docs/shm.md lists what iceoryx2 needs"
    };
    ShmOpenError::Iceoryx(format!("shm {what} `{service}`: {code}: {hint}"))
}

impl ShmLink {
    /// Opens `config.local`'s endpoint: its node (after cleaning up dead nodes' leftovers),
    /// the subscriber and listener on its own service, a publisher and notifier on every
    /// other system's. Fails with what to do when shared memory is missing, too small or
    /// another user's, or when a service of the same name is not a compatible one.
    pub fn open(config: ShmLinkConfig, sink: Arc<dyn FrameSink>) -> Result<ShmLink, ShmOpenError> {
        let s = &config.settings;
        let local_name = config
            .systems
            .iter()
            .find(|(id, _)| *id == config.local)
            .map(|(_, n)| n.clone())
            .ok_or(ShmOpenError::UnknownSystem(config.local))?;
        quiet_iceoryx();
        let publishers = s.max_publishers.unwrap_or(config.systems.len() + 1);
        let dests_n = config.systems.len().saturating_sub(1) as u64;
        // What opening maps: a publisher's segment per destination, and its own service's
        // queues (small); grows later up to `publisher_bound` per publisher.
        let needed = (dests_n + 1) * s.publisher_initial() as u64;
        memory::check(Path::new(SHM_DIR), needed).map_err(ShmOpenError::Memory)?;
        let name = |system: &str| service_name(&s.prefix, &config.fleet, system);
        let local_service = name(&local_name);
        let node_name =
            NodeName::new(&local_service).map_err(|e| explain("node name", &local_service, e))?;
        let node = NodeBuilder::new()
            .name(&node_name)
            // The host program owns its signals (a Ctrl-C must reach it, not iceoryx2).
            .signal_handling_mode(SignalHandlingMode::Disabled)
            .create::<IpcService>()
            .map_err(|e| explain("node", &local_service, e))?;
        let counters = Arc::new(Counters::default());
        let names: HashMap<String, SystemId> = config
            .systems
            .iter()
            .map(|(id, n)| (name(n), *id))
            .collect();
        let liveness = Liveness::new(config.local, names, s.liveness_ms, counters.clone());
        // A process restarted after a crash: its predecessor's ports still hold places in the
        // services (and its subscriber the only subscriber's); remove them first.
        liveness.sweep(node.config(), None);
        let open_service =
            |service: &str| -> Result<PubSubFactory<IpcService, [u8], ()>, ShmOpenError> {
                let sn =
                    ServiceName::new(service).map_err(|e| explain("service name", service, e))?;
                node.service_builder(&sn)
                    .publish_subscribe::<[u8]>()
                    .enable_safe_overflow(false)
                    .history_size(0)
                    .subscriber_max_buffer_size(s.queue_depth)
                    .subscriber_max_borrowed_samples(BORROWED)
                    .max_publishers(publishers)
                    .max_subscribers(s.max_subscribers)
                    .max_nodes(publishers + s.max_subscribers)
                    .open_or_create()
                    .map_err(|e| explain("service", service, e))
            };
        let open_event = |service: &str| {
            let sn = ServiceName::new(service).map_err(|e| explain("service name", service, e))?;
            node.service_builder(&sn)
                .event()
                .max_notifiers(publishers + 1)
                .max_listeners(s.max_subscribers)
                .max_nodes(publishers + s.max_subscribers)
                .open_or_create()
                .map_err(|e| explain("event service", service, e))
        };
        let own = open_service(&local_service)?;
        let subscriber = own
            .subscriber_builder()
            .buffer_size(s.queue_depth)
            .create()
            .map_err(|e| explain("subscriber on", &local_service, e))?;
        let own_event = open_event(&local_service)?;
        let listener = own_event
            .listener_builder()
            .create()
            .map_err(|e| explain("listener on", &local_service, e))?;
        let self_wake = own_event
            .notifier_builder()
            .create()
            .map_err(|e| explain("notifier on", &local_service, e))?;
        // SAFETY: the descriptor is only read (polled) while the listener, which owns it,
        // lives: both belong to this link.
        let fd = unsafe { listener.file_descriptor().native_handle() };
        let nodes = publishers + s.max_subscribers;
        let own_flag = OwnFlag::open(&node, &local_service, publishers, nodes);
        let mut dests = HashMap::new();
        for (id, dest) in config.systems.iter().filter(|(id, _)| *id != config.local) {
            let service_name = name(dest);
            let service = open_service(&service_name)?;
            let publisher = service
                .publisher_builder()
                .initial_max_slice_len(s.initial_frame.min(s.max_frame))
                .allocation_strategy(AllocationStrategy::PowerOfTwo)
                .max_loaned_samples(LOANS)
                .backpressure_strategy(BackpressureStrategy::DiscardData)
                .set_backpressure_handler(wait_for_room(s.send_wait_ms))
                .create()
                .map_err(|e| explain("publisher on", &service_name, e))?;
            let notifier = open_event(&service_name)?
                .notifier_builder()
                .create()
                .map_err(|e| explain("notifier on", &service_name, e))?;
            let spinning = PeerFlag::default();
            spinning.try_open(&node, &service_name);
            dests.insert(
                *id,
                Dest {
                    name: dest.clone(),
                    service_name,
                    publisher,
                    notifier,
                    spinning,
                    service,
                },
            );
        }
        liveness.sweep(node.config(), Some(&*sink));
        Ok(ShmLink {
            local_service,
            dests,
            subscriber,
            listener,
            self_wake,
            fd,
            own_flag,
            spinning: AtomicBool::new(false),
            sink,
            counters,
            liveness,
            max_frame: s.max_frame,
            _node: Mutex::new(node),
        })
    }

    /// The name of this link's own service (`PREFIX/FLEET/<System>`), where frames for it go.
    pub fn service(&self) -> &str {
        &self.local_service
    }

    /// What the link counted besides [`LinkStats`].
    pub fn shm_stats(&self) -> ShmStats {
        let c = &self.counters;
        ShmStats {
            congested: c.congested.load(Ordering::Relaxed),
            unreachable: c.unreachable.load(Ordering::Relaxed),
            oversize_received: c.oversize_received.load(Ordering::Relaxed),
            receive_errors: c.receive_errors.load(Ordering::Relaxed),
            peers_died: c.peers_died.load(Ordering::Relaxed),
            cleanups_failed: c.cleanups_failed.load(Ordering::Relaxed),
        }
    }

    /// Looks for dead peers now if `liveness_ms` has passed since the last look, and opens
    /// the spinning flags of destinations that had none yet (they started after this link).
    fn upkeep(&self) {
        if self.liveness.due() {
            let node = self._node.lock();
            self.liveness.sweep(node.config(), Some(&*self.sink));
            for dest in self.dests.values() {
                dest.spinning.try_open(&node, &dest.service_name);
            }
        }
    }

    /// Writes the frame `head` + `body` into a sample loaned from `to`'s publisher and sends
    /// it: the one copy a frame costs on this link.
    fn put(&self, to: SystemId, head: &[u8], body: &[u8]) -> Result<(), LinkError> {
        let len = head.len() + body.len();
        if len > self.max_frame {
            return Err(LinkError::TooLarge {
                len,
                max: self.max_frame,
            });
        }
        let Some(dest) = self.dests.get(&to) else {
            return Err(LinkError::Unreachable {
                peer: to,
                reason: "not a system of this shm transport".into(),
            });
        };
        if self.liveness.is_dead(to) {
            // Back already? Look (rate-limited) before refusing.
            self.upkeep();
            if self.liveness.is_dead(to) {
                self.counters.unreachable.fetch_add(1, Ordering::Relaxed);
                return Err(LinkError::Unreachable {
                    peer: to,
                    reason: format!("{} is gone (its process died or closed)", dest.name),
                });
            }
        }
        let mut sample = match dest.publisher.loan_slice_uninit(len) {
            Ok(s) => s,
            Err(e) => return Err(self.loan_failed(to, dest, e)),
        };
        let buf = sample.payload_mut();
        // SAFETY: `buf` has exactly `len` bytes; both sources are valid for their lengths and
        // cannot overlap a freshly loaned sample. Every byte is written before `assume_init`.
        let sample = unsafe {
            let p = buf.as_mut_ptr() as *mut u8;
            std::ptr::copy_nonoverlapping(head.as_ptr(), p, head.len());
            std::ptr::copy_nonoverlapping(body.as_ptr(), p.add(head.len()), body.len());
            sample.assume_init()
        };
        match sample.send() {
            Ok(0) => Err(self.not_taken(to, dest)),
            Ok(_) => {
                self.counters.sent.fetch_add(1, Ordering::Relaxed);
                // A lost wake-up only delays the frame to the receiver's next upkeep; the
                // frame itself is in its queue. A spinning receiver finds it without one.
                if dest.spinning.needs_wake() {
                    let _ = dest.notifier.notify();
                }
                Ok(())
            }
            Err(e) => {
                self.counters.dropped.fetch_add(1, Ordering::Relaxed);
                Err(LinkError::Io(std::io::Error::other(format!(
                    "shm send to {} (`{}`): {e:?}",
                    dest.name, dest.service_name
                ))))
            }
        }
    }

    /// The error for a sample no subscriber took: nobody is there, or its queue is full.
    fn not_taken(&self, to: SystemId, dest: &Dest) -> LinkError {
        if dest.service.dynamic_config().number_of_subscribers() == 0 {
            self.counters.unreachable.fetch_add(1, Ordering::Relaxed);
            return LinkError::Unreachable {
                peer: to,
                reason: format!("{} has no endpoint on `{}`", dest.name, dest.service_name),
            };
        }
        // A full queue may be a dead reader's: look (rate-limited) so that it is cleaned up
        // and reported down instead of refusing forever.
        self.upkeep();
        self.counters.congested.fetch_add(1, Ordering::Relaxed);
        self.counters.dropped.fetch_add(1, Ordering::Relaxed);
        LinkError::Congested {
            peer: to,
            reason: format!(
                "{}'s queue on `{}` is full (it reads slower than it is sent to)",
                dest.name, dest.service_name
            ),
        }
    }

    /// The error for a sample that could not be loaned.
    fn loan_failed(&self, to: SystemId, dest: &Dest, e: LoanError) -> LinkError {
        self.counters.dropped.fetch_add(1, Ordering::Relaxed);
        match e {
            LoanError::OutOfMemory | LoanError::ExceedsMaxLoans => {
                self.counters.congested.fetch_add(1, Ordering::Relaxed);
                LinkError::Congested {
                    peer: to,
                    reason: format!(
                        "no free sample towards {} (`{}`): its reader holds them ({e:?})",
                        dest.name, dest.service_name
                    ),
                }
            }
            e => {
                let why = match memory::free_bytes(Path::new(SHM_DIR)) {
                    Ok((free, size)) if free < (self.max_frame as u64) * 2 => {
                        memory::too_small(Path::new(SHM_DIR), free, size, self.max_frame as u64)
                    }
                    _ => format!("iceoryx2 could not map a larger segment ({e:?})"),
                };
                LinkError::Io(std::io::Error::other(format!(
                    "shm send to {} (`{}`): {why}",
                    dest.name, dest.service_name
                )))
            }
        }
    }
}

thread_local! {
    /// True while this thread reads a link (`read_ready`): a send made there (the router's
    /// acknowledgement) must not wait for room, or two systems acknowledging each other with
    /// full queues would wait on each other.
    static READING: std::cell::Cell<bool> = const { std::cell::Cell::new(false) };
}

/// What a publisher does when the destination's queue is full: wait for room (yielding, then
/// sleeping briefly between looks) up to `wait_ms`, never on a reading thread; then give the
/// sample up, which [`ShmLink::put`] reports as congestion.
fn wait_for_room(wait_ms: u32) -> impl Fn(&BackpressureInfo) -> BackpressureAction + Send {
    let wait = std::time::Duration::from_millis(wait_ms as u64);
    move |info: &BackpressureInfo| {
        if READING.with(|r| r.get()) || info.elapsed_time >= wait {
            return BackpressureAction::DiscardData;
        }
        if info.retries < 64 {
            std::thread::yield_now();
        } else {
            std::thread::sleep(std::time::Duration::from_micros(20));
        }
        BackpressureAction::Retry
    }
}

/// iceoryx2 logs to stderr by default, at `Info` and above: a link's errors carry what it
/// says, so only its fatal messages are shown unless `IOX2_LOG_LEVEL` asks for more.
fn quiet_iceoryx() {
    static ONCE: std::sync::Once = std::sync::Once::new();
    ONCE.call_once(|| set_log_level_from_env_or(LogLevel::Fatal));
}

impl Link for ShmLink {
    fn caps(&self) -> LinkCaps {
        LinkCaps {
            max_frame: self.max_frame,
            mtu: self.max_frame,
            reliable: true,
            ordered: true,
            broadcast: false,
        }
    }

    fn send(&self, to: SystemId, frame: &[u8]) -> Result<(), LinkError> {
        self.put(to, frame, &[])
    }

    /// Head and body are copied straight into the loaned sample: no joined buffer.
    fn send_parts(&self, to: SystemId, head: &[u8], body: &[u8]) -> Result<(), LinkError> {
        self.put(to, head, body)
    }

    fn stats(&self) -> LinkStats {
        let c = &self.counters;
        LinkStats {
            frames_sent: c.sent.load(Ordering::Relaxed),
            frames_received: c.received.load(Ordering::Relaxed),
            frames_dropped: c.dropped.load(Ordering::Relaxed),
            connects: c.connects.load(Ordering::Relaxed),
            ..LinkStats::default()
        }
    }

    fn readable(&self) -> Option<&dyn Readable> {
        Some(self)
    }

    /// True: a sample is the sender's bytes in memory this host shares; nothing in between
    /// can alter them (docs/shm.md says what the permissions protect against).
    fn checksums_payload(&self) -> bool {
        true
    }
}

impl Readable for ShmLink {
    fn fd(&self) -> RawFd {
        self.fd
    }

    fn read_ready(&self, budget: usize) -> std::io::Result<usize> {
        // Events first, samples second: a sample sent after the last receive below comes
        // with a notification after this drain, so the descriptor polls readable again. A
        // spinning reader looks at the queue itself (`pending`): it leaves the events for
        // when it sleeps again, a system call saved per look.
        let spinning = self.spinning.load(Ordering::Relaxed);
        if !spinning {
            let _ = self.listener.try_wait(|_| {});
        }
        let was_reading = READING.with(|r| r.replace(true));
        let mut handed = 0;
        while handed < budget.max(1) {
            match self.subscriber.receive() {
                Ok(Some(sample)) => {
                    let frame: &[u8] = sample.payload();
                    if frame.len() > self.max_frame {
                        self.counters
                            .oversize_received
                            .fetch_add(1, Ordering::Relaxed);
                        self.counters.dropped.fetch_add(1, Ordering::Relaxed);
                        continue;
                    }
                    self.counters.received.fetch_add(1, Ordering::Relaxed);
                    // Read in place: the sink gets the bytes in shared memory, borrowed for
                    // the call; the sample goes back to its publisher when dropped.
                    self.sink.on_frame(frame, Peer::Unknown);
                    handed += 1;
                }
                Ok(None) => break,
                Err(_) => {
                    self.counters.receive_errors.fetch_add(1, Ordering::Relaxed);
                    self.counters.dropped.fetch_add(1, Ordering::Relaxed);
                    break;
                }
            }
        }
        READING.with(|r| r.set(was_reading));
        if !spinning && handed >= budget.max(1) && self.subscriber.has_samples().unwrap_or(false) {
            let _ = self.self_wake.notify();
        }
        self.upkeep();
        Ok(handed)
    }

    /// The queue itself, without a system call (None when iceoryx2 cannot tell: a
    /// connection to a publisher failed; the descriptor then decides).
    fn pending(&self) -> Option<bool> {
        self.subscriber.has_samples().ok()
    }

    /// Tells the senders (through the spinning flag) to skip or resume notifications. On
    /// `false`, a sample that came without one makes the descriptor readable (a notification
    /// to itself), so a reader that now sleeps on it wakes.
    fn set_spinning(&self, spinning: bool) {
        self.spinning.store(spinning, Ordering::Relaxed);
        let Some(flag) = &self.own_flag else {
            return;
        };
        flag.set(spinning);
        if !spinning && self.subscriber.has_samples().unwrap_or(true) {
            let _ = self.self_wake.notify();
        }
    }
}

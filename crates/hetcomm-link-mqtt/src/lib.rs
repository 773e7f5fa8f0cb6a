//! # hetcomm-link-mqtt — the `mqtt` transport kind
//!
//! Carries hetcomm frames as MQTT 5 publishes through a broker (mosquitto, EMQX, HiveMQ, …),
//! for sites where a broker is what the network lets through. One MQTT client per system,
//! with `rumqttc`'s `v5` client; this crate writes no MQTT itself.
//!
//! ## Topics
//!
//! With the transport's `prefix` (default `hetcomm`) and fleet level `FLEET` (the transport's
//! `fleet`, else the fleet file's `name`, else `fleet`):
//!
//! | topic | what |
//! |---|---|
//! | `PREFIX/FLEET/<System>` | frames for that system, one frame per publish, byte for byte (`docs/wire-format.md`) |
//! | `PREFIX/FLEET/@all` | native broadcasts: one publish of one frame (`FLAG_TO_ALL`) that every system receives ([`LinkCaps::broadcast`], unsecured transports only) |
//! | `PREFIX/FLEET/@presence/<System>` | retained `online` while its link is open, `offline` after it closed, `lost` (its last will) when its connection broke |
//!
//! System names never contain `/`, `+`, `#` or `@`, so these cannot clash. `docs/mqtt.md`
//! describes them for programs that are not hetcomm ([`data_topic`], [`broadcast_topic`],
//! [`presence_topic`]).
//!
//! ## What the link guarantees
//!
//! [`LinkCaps`]: neither reliable nor ordered. A QoS 1 PUBACK means the broker has the frame,
//! not that the destination got it (the broker drops what nobody subscribed to, and what it
//! holds when it restarts without persistence); hetcomm's acknowledgements decide delivery in
//! acknowledged mode, exactly as over UDP. The largest frame is what the broker's Maximum
//! Packet Size (in its CONNACK) leaves after the publish's own bytes, at most the wire
//! format's 16 MiB: a larger one is refused before it is published. Payloads arrive intact
//! (TCP or TLS to the broker and from it), so frames carry a header-only CRC
//! ([`Link::checksums_payload`]).
//!
//! ## Presence
//!
//! A send to a system whose last presence message this link heard live was `offline` or
//! `lost` fails at once ([`LinkError::Unreachable`], saying which); one not announced online
//! waits for it up to `presence_timeout_ms` the first time, then fails at once until it
//! comes. A system coming and going is reported through the link seam
//! ([`FrameSink::on_event`]: `LinkEvent::PeerUp`, so the router sends what waited for it at
//! once, and `PeerDown` when it leaves, so a pair with another transport fails over).
//!
//! ## The broker going away
//!
//! The client reconnects by itself (every 0.05 s to 0.5 s, to each of `brokers` in turn),
//! resubscribes when the broker kept no session (and learns every system's presence again),
//! and announces itself online again. While it
//! is disconnected a send waits up to `reconnect_wait_ms` for the connection, then fails,
//! naming the broker and why.
//!
//! ## The `mqtt_bridge` kind
//!
//! A second kind in this crate ([`bridge`]): a plain MQTT client speaking JSON (a VDA
//! 5050-style AGV or fleet manager) as a bridged robot, its topics mapped to (module, message
//! type) both ways in the fleet file, its JSON converted field by field.
//!
//! ## Threads
//!
//! One thread per link runs the MQTT client's event loop and hands received frames to the
//! [`FrameSink`] on it. A send made from there (the router's acknowledgement) never waits: for
//! presence (a system never announced gets it anyway: it has just sent us a frame), for the
//! connection, or for room in the client's queue (a full queue refuses the frame as
//! congested).

pub mod bridge;
mod event_loop;
pub mod factory;
mod presence;
mod receipts;
mod settings;
mod tls;

use parking_lot::{Condvar, Mutex};
use std::collections::HashMap;
use std::sync::atomic::{AtomicBool, AtomicU64, Ordering};
use std::sync::Arc;
use std::thread::JoinHandle;
use std::time::{Duration, Instant};

use hetcomm_core::wire::TO_ALL_SYSTEM;
use hetcomm_core::SystemId;
use hetcomm_link::{FrameSink, Link, LinkCaps, LinkError, LinkStats};
use rumqttc::v5::mqttbytes::QoS;
use rumqttc::v5::{Client, ClientError, Request};

pub use presence::{watch_all as watch_presence, Announced, PresenceEvent};
pub use settings::{validate_levels, Broker, MqttSettings, Qos};

use hetcomm_link::relay::{RelayPromise, RelayReceipt};
use presence::{Presence, Verdict};
use receipts::Receipts;

/// Registers the `mqtt` transport factory ([`factory::MqttFactory`]) and the `mqtt_bridge`
/// one ([`bridge::MqttBridgeFactory`]).
pub fn register_transports(registry: &mut hetcomm_link::registry::Registry) {
    registry.register(factory::MqttFactory);
    registry.register(bridge::MqttBridgeFactory);
}

/// Largest frame the link ever takes: the wire format's largest (16 MiB payload and the
/// 48-byte header); a broker's Maximum Packet Size may lower it ([`MqttLink::max_frame`]).
pub const MAX_FRAME: usize = hetcomm_core::wire::HEADER_LEN + hetcomm_core::wire::MAX_PAYLOAD;

/// The topic frames for system `name` are published on: `PREFIX/FLEET/<name>`.
pub fn data_topic(prefix: &str, fleet: &str, name: &str) -> String {
    format!("{prefix}/{fleet}/{name}")
}

/// The topic native broadcasts are published on: `PREFIX/FLEET/@all`.
pub fn broadcast_topic(prefix: &str, fleet: &str) -> String {
    format!("{prefix}/{fleet}/@all")
}

/// System `name`'s retained presence topic: `PREFIX/FLEET/@presence/<name>`.
pub fn presence_topic(prefix: &str, fleet: &str, name: &str) -> String {
    format!("{prefix}/{fleet}/@presence/{name}")
}

/// Bytes a publish of a frame on `topic` takes besides the frame, at most: the fixed header
/// (1 byte and a remaining length of up to 4), the topic (2-byte length and its bytes), the
/// packet id (2) and an empty property list (1).
pub fn publish_overhead(topic: &str) -> usize {
    overhead(topic.len())
}

/// [`publish_overhead`] for a topic of `topic_len` bytes.
fn overhead(topic_len: usize) -> usize {
    1 + 4 + 2 + topic_len + 2 + 1
}

/// Everything an `mqtt` link needs to open.
#[derive(Clone, Debug)]
pub struct MqttLinkConfig {
    /// The system the link is for.
    pub local: SystemId,
    /// Every system of the fleet, by id, with its name (the last level of its topics).
    pub systems: HashMap<SystemId, String>,
    /// The fleet's topic level (`PREFIX/FLEET/…`).
    pub fleet: String,
    /// The transport's settings.
    pub settings: MqttSettings,
}

/// Why an `mqtt` link could not open.
#[derive(Debug, thiserror::Error)]
#[non_exhaustive]
pub enum MqttOpenError {
    /// The local system is not among the configured systems.
    #[error("system {0} is not a system of this fleet")]
    UnknownSystem(SystemId),
    /// A setting that cannot be used (no broker, a topic level, a TLS file).
    #[error("mqtt setting: {0}")]
    Setting(String),
    /// No broker answered within `open_timeout_ms`.
    #[error("cannot reach the MQTT broker {brokers} within {timeout_ms} ms: {reason}")]
    Unreachable {
        /// The brokers tried.
        brokers: String,
        /// The time allowed.
        timeout_ms: u32,
        /// The last error.
        reason: String,
    },
    /// The broker answered and refused this client (credentials, authorisation, client id).
    #[error("the MQTT broker {broker} refused the connection: {reason}")]
    Refused {
        /// The broker.
        broker: String,
        /// Its reason code, in words.
        reason: String,
    },
}

/// The connection as the event loop last saw it.
#[derive(Default)]
pub(crate) struct Conn {
    /// Connected and subscribed: frames can go and come.
    pub(crate) ready: bool,
    /// The broker connected to (or last tried).
    pub(crate) broker: String,
    /// The broker's Maximum Packet Size, from its CONNACK.
    pub(crate) broker_max_packet: Option<u32>,
    /// Why the connection is not there, in words.
    pub(crate) last_error: Option<String>,
    /// The broker's refusal of this client, if that is why.
    pub(crate) refused: Option<String>,
    /// Another client took this system's client id over: the link stopped for good.
    pub(crate) taken_over: bool,
}

/// Counters of a link.
#[derive(Default)]
pub(crate) struct Counters {
    pub(crate) sent: AtomicU64,
    pub(crate) received: AtomicU64,
    pub(crate) dropped: AtomicU64,
    pub(crate) connects: AtomicU64,
    pub(crate) broker_acks: AtomicU64,
    pub(crate) no_subscribers: AtomicU64,
    pub(crate) broker_refusals: AtomicU64,
}

/// What a link's broker told it about its publishes ([`MqttLink::broker_stats`]).
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq)]
pub struct BrokerStats {
    /// QoS 1 publishes the broker acknowledged as taken and passed to a subscriber.
    pub acknowledged: u64,
    /// QoS 1 publishes the broker acknowledged with "no matching subscribers": nobody got them.
    pub no_subscribers: u64,
    /// QoS 1 publishes the broker refused (not authorised, quota exceeded, …): counted in
    /// `frames_dropped` too.
    pub refused: u64,
    /// Connections made to a broker (the first and every reconnection).
    pub connects: u64,
}

/// State the link and its event loop share.
pub(crate) struct Shared {
    pub(crate) local: SystemId,
    pub(crate) conn: Mutex<Conn>,
    pub(crate) changed: Condvar,
    pub(crate) presence: Presence,
    pub(crate) counters: Counters,
    pub(crate) closing: AtomicBool,
    pub(crate) sink: Arc<dyn FrameSink>,
    pub(crate) topics: Topics,
    /// System ids by name, for presence topics.
    pub(crate) names: HashMap<String, SystemId>,
    /// Whether this link takes broadcasts on the `@all` topic.
    pub(crate) broadcast: bool,
    /// What the broker said about each QoS 1 publish, for sends that wait on it.
    pub(crate) receipts: Receipts,
}

impl Shared {
    pub(crate) fn lock(&self) -> parking_lot::MutexGuard<'_, Conn> {
        self.conn.lock()
    }

    /// Waits until `settled` reads an answer off the connection's state, or `deadline`
    /// passes (then the state as it is, still locked).
    fn wait_for<T>(
        &self,
        deadline: Instant,
        settled: impl FnMut(&Conn) -> Option<T>,
    ) -> Result<T, parking_lot::MutexGuard<'_, Conn>> {
        wait_until(&self.conn, &self.changed, deadline, settled)
    }
}

/// Waits on `changed` until `settled` reads an answer off the state behind `lock`, or
/// `deadline` passes (then the state as it is, still locked). The link's and the bridge's
/// connection states both wait this way.
pub(crate) fn wait_until<'a, S, T>(
    lock: &'a Mutex<S>,
    changed: &Condvar,
    deadline: Instant,
    mut settled: impl FnMut(&S) -> Option<T>,
) -> Result<T, parking_lot::MutexGuard<'a, S>> {
    let mut state = lock.lock();
    loop {
        if let Some(answer) = settled(&state) {
            return Ok(answer);
        }
        let now = Instant::now();
        if now >= deadline {
            return Err(state);
        }
        changed.wait_for(&mut state, deadline - now);
    }
}

/// The topics one link uses.
pub(crate) struct Topics {
    /// Its own data topic.
    pub(crate) own: String,
    /// The broadcast topic.
    pub(crate) all: String,
    /// `PREFIX/FLEET/@presence/`.
    pub(crate) presence_prefix: String,
    /// Its own presence topic.
    pub(crate) own_presence: String,
}

/// One destination.
struct Dest {
    name: String,
    topic: String,
}

thread_local! {
    /// True on a link's event-loop thread (a sink answering a frame): sends made there must not
    /// wait, or the loop that would end the wait stops.
    static IN_EVENT_LOOP: std::cell::Cell<bool> = const { std::cell::Cell::new(false) };
}

/// Requests the client's queue holds before a send waits for room.
const QUEUE: usize = 1024;

/// A system's MQTT client: one connection to a broker, subscribed to its own topic, the
/// broadcast topic and the fleet's presence topics. See the crate docs.
pub struct MqttLink {
    shared: Arc<Shared>,
    client: Client,
    thread: Mutex<Option<JoinHandle<()>>>,
    dests: HashMap<SystemId, Dest>,
    settings: MqttSettings,
    /// The fleet level of its topics (`PREFIX/FLEET/…`).
    fleet: String,
    qos: QoS,
    max_frame: usize,
    address: String,
}

impl MqttLink {
    /// Connects `config.local`'s client and starts delivering the frames published on its
    /// topic to `sink`. Fails within `open_timeout_ms` when no broker answers, naming them,
    /// and at once when a broker refuses the client (its reason: bad username or password, not
    /// authorised, …).
    pub fn open(
        config: MqttLinkConfig,
        sink: Arc<dyn FrameSink>,
    ) -> Result<MqttLink, MqttOpenError> {
        let s = &config.settings;
        let local_name = config
            .systems
            .get(&config.local)
            .ok_or(MqttOpenError::UnknownSystem(config.local))?
            .clone();
        if s.brokers.is_empty() {
            return Err(MqttOpenError::Setting("no broker".into()));
        }
        for (what, level) in [("prefix", &s.prefix), ("fleet", &config.fleet)] {
            validate_levels(level)
                .map_err(|why| MqttOpenError::Setting(format!("`{what}` `{level}`: {why}")))?;
        }
        let (prefix, fleet) = (&s.prefix, &config.fleet);
        let broadcast = !config.systems.contains_key(&TO_ALL_SYSTEM);
        let topics = Topics {
            own: data_topic(prefix, fleet, &local_name),
            all: broadcast_topic(prefix, fleet),
            presence_prefix: format!("{prefix}/{fleet}/@presence/"),
            own_presence: presence_topic(prefix, fleet, &local_name),
        };
        let mut dests: HashMap<SystemId, Dest> = config
            .systems
            .iter()
            .filter(|(id, _)| **id != config.local)
            .map(|(id, name)| {
                let topic = data_topic(prefix, fleet, name);
                (
                    *id,
                    Dest {
                        name: name.clone(),
                        topic,
                    },
                )
            })
            .collect();
        if broadcast {
            dests.insert(
                TO_ALL_SYSTEM,
                Dest {
                    name: "every system".into(),
                    topic: topics.all.clone(),
                },
            );
        }
        let options = event_loop::options(s, fleet, &local_name, &topics)?;
        let address = format!("{}/{}", s.brokers[0], topics.own);
        let shared = Arc::new(Shared {
            local: config.local,
            conn: Mutex::new(Conn {
                broker: s.brokers[0].to_string(),
                ..Conn::default()
            }),
            changed: Condvar::new(),
            presence: Presence::new(config.local),
            counters: Counters::default(),
            closing: AtomicBool::new(false),
            sink,
            topics,
            names: config
                .systems
                .iter()
                .map(|(id, n)| (n.clone(), *id))
                .collect(),
            broadcast,
            receipts: Receipts::new(
                Duration::from_millis(s.reconnect_wait_ms as u64),
                s.brokers[0].to_string(),
            ),
        });
        let (client, connection) = Client::new(options[0].clone(), QUEUE);
        let filters = event_loop::filters(&shared, s.qos);
        let thread = {
            let (shared, client) = (shared.clone(), client.clone());
            let brokers = s.brokers.clone();
            std::thread::Builder::new()
                .name(format!("mqtt-{local_name}"))
                .spawn(move || {
                    event_loop::run(shared, client, connection, options, brokers, filters)
                })
                .map_err(|e| MqttOpenError::Setting(format!("cannot start a thread: {e}")))?
        };
        {
            // Ends the broker's receipts that wait past their bound (`receipts`).
            let shared = shared.clone();
            std::thread::Builder::new()
                .name(format!("mqtt-receipts-{local_name}"))
                .spawn(move || shared.receipts.run_expiry())
                .map_err(|e| MqttOpenError::Setting(format!("cannot start a thread: {e}")))?;
        }
        let link = MqttLink {
            shared,
            client,
            thread: Mutex::new(Some(thread)),
            dests,
            settings: s.clone(),
            fleet: config.fleet.clone(),
            qos: s.qos.mqtt(),
            max_frame: MAX_FRAME,
            address,
        };
        link.wait_open()
    }

    /// Waits for the first connection (connected and subscribed), or fails as the docs of
    /// [`MqttLink::open`] say.
    fn wait_open(mut self) -> Result<MqttLink, MqttOpenError> {
        let timeout_ms = self.settings.open_timeout_ms;
        let deadline = Instant::now() + Duration::from_millis(timeout_ms as u64);
        let shared = self.shared.clone();
        let settled = shared.wait_for(deadline, |c| match c.ready {
            true => Some(Ok(c.broker_max_packet)),
            false => c.refused.clone().map(|reason| {
                Err(MqttOpenError::Refused {
                    broker: c.broker.clone(),
                    reason,
                })
            }),
        });
        let result = match settled {
            Ok(result) => result,
            Err(conn) => Err(MqttOpenError::Unreachable {
                brokers: self.settings.broker_list(),
                timeout_ms,
                reason: conn
                    .last_error
                    .clone()
                    .unwrap_or_else(|| "no answer".into()),
            }),
        };
        match result {
            Ok(limit) => {
                self.max_frame = self.frame_limit(limit);
                Ok(self)
            }
            Err(e) => {
                self.abandon();
                Err(e)
            }
        }
    }

    /// Stops the event loop of a link that never opened, without waiting for it.
    fn abandon(&self) {
        self.shared.closing.store(true, Ordering::SeqCst);
        let _ = self.client.try_disconnect();
        self.thread.lock().take();
    }

    /// The largest frame a publish to any destination may carry under the broker limit `limit`.
    fn frame_limit(&self, limit: Option<u32>) -> usize {
        let longest = self
            .dests
            .values()
            .map(|d| d.topic.len())
            .max()
            .unwrap_or(0);
        match limit {
            Some(l) => (l as usize)
                .saturating_sub(overhead(longest))
                .min(MAX_FRAME),
            None => MAX_FRAME,
        }
    }

    /// The system this link is for.
    pub fn local(&self) -> SystemId {
        self.shared.local
    }

    /// Where this link is: its broker and topic (`mqtt://127.0.0.1:1883/hetcomm/fleet/A`).
    pub fn address(&self) -> String {
        self.address.clone()
    }

    /// The broker's Maximum Packet Size from its last CONNACK (None: it set none).
    pub fn broker_max_packet(&self) -> Option<u32> {
        self.shared.lock().broker_max_packet
    }

    /// The largest frame this link takes ([`LinkCaps::max_frame`]), from the broker's limit
    /// when it opened.
    pub fn max_frame(&self) -> usize {
        self.max_frame
    }

    /// Whether the client is connected to a broker and subscribed now.
    pub fn connected(&self) -> bool {
        self.shared.lock().ready
    }

    /// The systems announced online now, by id.
    pub fn presence(&self) -> Vec<SystemId> {
        self.shared.presence.online()
    }

    /// What the broker confirmed of this link's QoS 1 publishes.
    pub fn broker_stats(&self) -> BrokerStats {
        let c = &self.shared.counters;
        BrokerStats {
            acknowledged: c.broker_acks.load(Ordering::Relaxed),
            no_subscribers: c.no_subscribers.load(Ordering::Relaxed),
            refused: c.broker_refusals.load(Ordering::Relaxed),
            connects: c.connects.load(Ordering::Relaxed),
        }
    }

    /// The destination `to`, if a frame of `len` bytes may be published to it now.
    fn reachable(&self, to: SystemId, len: usize) -> Result<&Dest, LinkError> {
        let Some(dest) = self.dests.get(&to) else {
            return Err(LinkError::Unreachable {
                peer: to,
                reason: "not a system of this mqtt transport".into(),
            });
        };
        let limit = self.frame_limit(self.broker_max_packet());
        if len > limit {
            return Err(LinkError::TooLarge { len, max: limit });
        }
        if to == TO_ALL_SYSTEM {
            return Ok(dest);
        }
        let in_loop = IN_EVENT_LOOP.with(|c| c.get());
        let grace = Duration::from_millis(self.settings.presence_timeout_ms as u64);
        let topic = || presence_topic(&self.settings.prefix, &self.fleet, &dest.name);
        match self.shared.presence.verdict(to, grace, !in_loop) {
            Verdict::Go => Ok(dest),
            // On the event loop (answering a frame from it): it is probably there.
            Verdict::NotAnnounced(None) if in_loop => Ok(dest),
            Verdict::Gone(a) => Err(LinkError::Unreachable {
                peer: to,
                reason: format!(
                    "{} is offline: its presence topic `{}` says `{}`{}",
                    dest.name,
                    topic(),
                    String::from_utf8_lossy(a.payload()),
                    match a {
                        Announced::Lost => " (its last will: its connection to the broker broke)",
                        _ => " (its link closed)",
                    }
                ),
            }),
            Verdict::NotAnnounced(last) => Err(LinkError::Unreachable {
                peer: to,
                reason: format!(
                    "{} has not announced itself online on the broker: no `online` on `{}`{}",
                    dest.name,
                    topic(),
                    match last {
                        Some(a) => format!(
                            " (its last presence message, from before this system connected, says `{}`)",
                            String::from_utf8_lossy(a.payload())
                        ),
                        None => String::new(),
                    }
                ),
            }),
        }
    }

    /// Waits (up to `reconnect_wait_ms`, not at all on the event loop) for the connection.
    fn connected_or_wait(&self, to: SystemId) -> Result<(), LinkError> {
        let in_loop = IN_EVENT_LOOP.with(|c| c.get());
        let wait = match in_loop {
            true => Duration::ZERO,
            false => Duration::from_millis(self.settings.reconnect_wait_ms as u64),
        };
        let unreachable = |c: &Conn| {
            LinkError::Unreachable {
            peer: to,
            reason: format!(
                "the MQTT broker {} is unreachable ({}); waited {} ms for the connection to come back",
                c.broker,
                c.last_error.as_deref().unwrap_or("disconnected"),
                wait.as_millis(),
            ),
        }
        };
        let closing = &self.shared.closing;
        let settled = self.shared.wait_for(Instant::now() + wait, |c| {
            if c.ready {
                Some(Ok(()))
            } else if closing.load(Ordering::Relaxed) {
                Some(Err(LinkError::Closed))
            } else if c.taken_over {
                Some(Err(unreachable(c)))
            } else {
                None
            }
        });
        settled.unwrap_or_else(|conn| Err(unreachable(&conn)))
    }

    /// Publishes `frame` to `to`: checks, then queues it for the event loop (waiting for room
    /// up to `reconnect_wait_ms`, not at all on the event loop). `promise`: kept with the
    /// broker's PUBACK (QoS 1).
    fn publish(
        &self,
        to: SystemId,
        frame: Vec<u8>,
        promise: Option<RelayPromise>,
    ) -> Result<(), LinkError> {
        let dest = self.reachable(to, frame.len())?;
        self.connected_or_wait(to)?;
        let wait = Duration::from_millis(self.settings.reconnect_wait_ms as u64);
        queue_publish(
            &self.client,
            (dest.topic.clone(), self.qos),
            frame,
            (to, wait),
            &self.shared.closing,
            (&self.shared.receipts, promise),
        )?;
        self.shared.counters.sent.fetch_add(1, Ordering::Relaxed);
        Ok(())
    }
}

/// Queues a publish of `body` on `topic` for the event loop. While the client's queue is
/// full it waits, backing off, up to `wait` (not at all on the event loop's own thread,
/// which is the one that empties the queue); then the send is refused as congested. The
/// link closing ends the wait. `receipts`: the client's (the link's or the bridge's), with
/// the promise to keep with this publish's PUBACK.
pub(crate) fn queue_publish(
    client: &Client,
    (topic, qos): (String, QoS),
    body: Vec<u8>,
    (to, wait): (SystemId, Duration),
    closing: &AtomicBool,
    (receipts, mut promise): (&Receipts, Option<RelayPromise>),
) -> Result<(), LinkError> {
    let deadline = Instant::now() + wait;
    let in_loop = IN_EVENT_LOOP.with(|c| c.get());
    let mut payload = bytes::Bytes::from(body);
    let mut pause = Duration::from_micros(20);
    loop {
        let mut refused = None;
        let attempt = || match client.try_publish(topic.clone(), qos, false, payload) {
            Ok(()) => true,
            Err(e) => {
                refused = Some(e);
                false
            }
        };
        let queued = receipts.queue(qos, &mut promise, attempt);
        match refused {
            None => {
                debug_assert!(queued);
                return Ok(());
            }
            Some(ClientError::TryRequest(Request::Publish(p)))
            | Some(ClientError::Request(Request::Publish(p))) => payload = p.payload,
            Some(e) => {
                return Err(LinkError::Unreachable {
                    peer: to,
                    reason: format!("mqtt client: {e}"),
                })
            }
        }
        if closing.load(Ordering::Relaxed) {
            return Err(LinkError::Closed);
        }
        if in_loop || Instant::now() >= deadline {
            return Err(LinkError::Congested {
                peer: to,
                reason: format!("the MQTT client's queue of {QUEUE} requests is full"),
            });
        }
        std::thread::sleep(pause);
        pause = (pause * 2).min(Duration::from_millis(2));
    }
}

impl Link for MqttLink {
    fn caps(&self) -> LinkCaps {
        LinkCaps {
            max_frame: self.max_frame,
            mtu: self.max_frame,
            reliable: false,
            ordered: false,
            broadcast: self.shared.broadcast,
        }
    }

    fn send(&self, to: SystemId, frame: &[u8]) -> Result<(), LinkError> {
        self.publish(to, frame.to_vec(), None)
    }

    fn send_parts(&self, to: SystemId, head: &[u8], body: &[u8]) -> Result<(), LinkError> {
        self.publish(to, [head, body].concat(), None)
    }

    /// At QoS 1, a receipt kept with the broker's PUBACK for this publish: confirmed
    /// (*Success*), refused (*no matching subscribers*, or a refusal), or unanswered within
    /// `reconnect_wait_ms` (or lost with a connection to a broker that kept no session). At
    /// QoS 0 the broker confirms nothing: no receipt.
    fn send_relayed(
        &self,
        to: SystemId,
        head: &[u8],
        body: &[u8],
    ) -> Result<Option<RelayReceipt>, LinkError> {
        receipts::with_receipt(self.qos, |promise| {
            self.publish(to, [head, body].concat(), promise)
        })
    }

    /// True: the connections to and from the broker are TCP (or TLS over it), whose
    /// checksummed streams deliver a publish whole and unaltered or not at all, and a broker
    /// passes payloads on as they are.
    fn checksums_payload(&self) -> bool {
        true
    }

    fn stats(&self) -> LinkStats {
        let c = &self.shared.counters;
        LinkStats {
            frames_sent: c.sent.load(Ordering::Relaxed),
            frames_received: c.received.load(Ordering::Relaxed),
            frames_dropped: c.dropped.load(Ordering::Relaxed),
            connects: c.connects.load(Ordering::Relaxed),
            ..LinkStats::default()
        }
    }
}

impl Drop for MqttLink {
    fn drop(&mut self) {
        let ready = self.shared.lock().ready;
        self.shared.closing.store(true, Ordering::SeqCst);
        self.shared.receipts.close();
        self.shared.presence.close();
        self.shared.changed.notify_all();
        let thread = self.thread.lock().take();
        // Announce the close (retained), then disconnect normally: the broker then keeps the
        // last will to itself. Both go out in order before the loop ends (if the client is
        // disconnected, once it is connected again).
        let _ = self.shared.receipts.queue(QoS::AtLeastOnce, &mut None, || {
            self.client
                .try_publish(
                    self.shared.topics.own_presence.clone(),
                    QoS::AtLeastOnce,
                    true,
                    Announced::Offline.payload(),
                )
                .is_ok()
        });
        let _ = self.client.try_disconnect();
        // Disconnected, the loop ends after its current attempt: nothing to wait for.
        if let (true, Some(t)) = (ready, thread) {
            let _ = t.join();
        }
    }
}

//! # hetcomm-link-ros1 — the `ros1` transport kind
//!
//! Carries hetcomm frames over ROS 1 topics through a ROS master, with
//! [roslibrust](https://docs.rs/roslibrust) (a native Rust implementation of the ROS 1 master
//! XML-RPC API and TCPROS; this crate writes no ROS protocol itself).
//!
//! ## Topics and message type
//!
//! As in the thesis (§3.5, §4.3.2): every system subscribes to **one topic named after its
//! friendly name**, under the transport's optional namespace —
//! `namespace = "hetcomm"` gives `/hetcomm/Charlie`, no namespace gives `/Charlie`
//! ([`topic_name`]). To send to a system, a link publishes on that system's topic, with one
//! publisher per destination (all created when the link opens, as the thesis's `Setup` did).
//!
//! The message type is **`std_msgs/UInt8MultiArray`** (MD5 `82373f1612381bb6ee473b5cd6f5d89c`):
//! `layout` is left empty (no dimensions, `data_offset = 0`) and `data` holds **exactly one
//! hetcomm frame**, byte for byte as `docs/wire-format.md` describes (48-byte header, then the
//! MessagePack payload). Any ROS 1 program (rospy, roscpp, `rostopic`) can read and write it.
//! Messages whose `data` is empty are ignored; everything else goes to the [`FrameSink`] as is
//! (the router checks and drops malformed frames) with [`Peer::Unknown`]: the router reads the
//! sender from the frame header.
//!
//! ## Bridges
//!
//! The crate also has the `ros1_bridge` kind ([`bridge`]): an external ROS 1 robot (one that
//! runs ROS 1, not hetcomm) in the fleet through its own typed topics (docs/ros-bridges.md),
//! with the conversion shared with the ROS 2 bridge in `hetcomm_rosmsg`.
//!
//! ## What the link guarantees
//!
//! [`LinkCaps`]: `reliable = false`, `ordered = true`. A publisher/subscriber pair talks over one
//! TCP connection (ordered), but ROS 1 drops what is published before a subscriber's connection
//! is up (connections are made asynchronously after the master tells the subscriber about a new
//! publisher), and a subscriber that falls more than the queue size behind loses messages.
//!
//! So, as `rostopic pub` waits for its subscribers, a [`Link::send`] to a destination whose
//! subscriber has not yet been seen connected **waits for it** (at most
//! [`Ros1Config::connect_timeout`], fleet key `connect_timeout_ms`, default 500 ms) before the
//! frame is published, and fails with [`LinkError::Unreachable`] ("the subscriber of
//! /hetcomm/Bravo did not connect within 500 ms …") if it does not connect in time. The link
//! knows a subscriber is connected when:
//!
//! * the topic's subscriber is a hetcomm node (its name starts with `/hetcomm_`): the link
//!   publishes a **connection probe** on the topic (a message with empty `data` and one
//!   `layout.dim` entry labelled [`PROBE_LABEL`]; `size` = a random nonce, `stride` = the
//!   prober's system id) every [`Ros1Config::probe_interval`], and the destination's link
//!   answers on the prober's topic with [`PROBE_ACK_LABEL`] (same nonce, `stride` = its own
//!   id). The answer can only come back after the probe went through the very connection the
//!   frame will take, so nothing published after it is lost to connection set-up;
//! * otherwise (a rospy or roscpp node): the node's `getBusInfo` lists an inbound connection
//!   on the topic from this link's node.
//!
//! Once connected, sends do not wait. The supervision task forgets a destination's connection
//! when the set of nodes subscribed to its topic changes (the destination restarted), and a
//! re-registration forgets them all. The router's acknowledgements make delivery reliable on
//! top.
//!
//! ## The master
//!
//! * Opening fails within [`Ros1Config::open_timeout`] with [`OpenError::MasterUnreachable`]
//!   (naming the URI) when the master does not answer.
//! * While the link runs, a supervision task asks the master every
//!   [`Ros1Config::supervise_interval`] whether this link's subscription is still registered.
//!   If the master is gone, frames keep flowing over the TCPROS connections already made (ROS 1
//!   nodes talk peer to peer; the master only introduces them) and frames for destinations with
//!   no connection are lost (reported by the router as "no acknowledgement"). When a master
//!   answers again without our registration (it was restarted), the link re-registers: it
//!   creates a new ROS node with a fresh subscriber and publishers and drops the old one, so
//!   traffic resumes through the new master. [`LinkStats::connects`] counts registrations.
//!
//! ## Threads
//!
//! Each link owns a small tokio runtime (two worker threads named `hetcomm-ros1`), shut down
//! when the link is dropped, and one thread `hetcomm-ros1-rx` that hands received frames to
//! the [`FrameSink`] (so that a sink may send — an acknowledgement, a reply — and wait for a
//! connection without stalling the runtime that answers probes). [`Link::send`] queues the
//! frame for the runtime's publishing task (`try_send`; a full queue is
//! [`LinkError::Congested`]); it waits only for a destination that is not connected yet.
//!
//! ## Node names and the environment
//!
//! Each registration is a ROS node named `/hetcomm_<system>_<pid>_<n>` (unique, so that a
//! re-registration or a second link of the same system never makes the master shut the other
//! down). As every ROS 1 node, the link advertises itself under `ROS_HOSTNAME` (or `ROS_IP`, or
//! the machine's host name): set `ROS_HOSTNAME=127.0.0.1` for a master on the same machine.
//! `rosnode list`, `ping` and `kill` work on these nodes (a killed registration is replaced,
//! as after a master restart); `rosnode info` cannot list their connections, because
//! roslibrust's node answers `getBusInfo` with `501 Not Implemented` and offers no hook to
//! answer it here (roslibrust issue #202).

mod xmlrpc;

use std::cell::Cell;
use std::collections::{BTreeMap, HashMap};
use std::hash::{BuildHasher, Hasher};
use std::sync::atomic::{AtomicBool, AtomicU64, Ordering};
use std::sync::{Arc, Mutex};
use std::time::{Duration, Instant};

use hetcomm_config::Ros1Settings;
use hetcomm_core::SystemId;
use hetcomm_link::{FrameSink, Link, LinkCaps, LinkError, LinkStats, Peer};
use roslibrust::ros1::{MasterClient, NodeHandle, Publisher, Subscriber};
use tokio::sync::{mpsc, oneshot};

pub mod bridge;
pub mod factory;

/// Registers the `ros1` transport factory ([`factory::Ros1Factory`]) and the `ros1_bridge`
/// kind ([`bridge::Ros1BridgeFactory`]).
pub fn register_transports(registry: &mut hetcomm_link::registry::Registry) {
    registry.register(factory::Ros1Factory);
    registry.register(bridge::Ros1BridgeFactory::default());
}

/// The ROS message types this crate uses, generated by roslibrust's code generator from the
/// ROS 1 definitions copied into `msg/` (so their MD5 sums match every other ROS 1 node):
/// `std_msgs/UInt8MultiArray` for the transport, and the bridge's standard types.
#[allow(missing_docs, unused_imports, clippy::all)]
pub mod msgs {
    include!(concat!(env!("OUT_DIR"), "/ros_msgs.rs"));
}

use msgs::std_msgs::{MultiArrayDimension, MultiArrayLayout, UInt8MultiArray};

/// The ROS type name of the message that carries frames.
pub const MESSAGE_TYPE: &str = "std_msgs/UInt8MultiArray";

/// Largest frame a `ros1` link accepts: the wire format's largest frame (16 MiB payload plus
/// the 48-byte header).
pub const MAX_FRAME: usize = hetcomm_core::wire::HEADER_LEN + hetcomm_core::wire::MAX_PAYLOAD;

/// `layout.dim[0].label` of a connection probe (empty `data`; `size` = nonce, `stride` = the
/// prober's system id). A hetcomm link answers it with [`PROBE_ACK_LABEL`] on the prober's
/// topic.
pub const PROBE_LABEL: &str = "hetcomm_probe";

/// `layout.dim[0].label` of the answer to a connection probe (empty `data`; `size` = the
/// probe's nonce, `stride` = the answering system's id).
pub const PROBE_ACK_LABEL: &str = "hetcomm_probe_ack";

/// `layout.dim[0].label` of the prober's confirmation that an answer arrived (empty `data`;
/// `size` = the nonce, `stride` = the prober's id): the answer came over the answering link's
/// publisher, so that link's sends to the prober need not wait either.
pub const PROBE_CONFIRM_LABEL: &str = "hetcomm_probe_confirm";

/// Prefix of the ROS node names of hetcomm links (`/hetcomm_<system>_<pid>_<n>`): subscribers
/// named so answer connection probes.
const NODE_PREFIX: &str = "/hetcomm_";

/// Tunables of a `ros1` link.
#[derive(Clone, Debug)]
pub struct Ros1Config {
    /// Longest time `open` waits for the master (registration included) before failing.
    pub open_timeout: Duration,
    /// How often the supervision task checks the master and our registration.
    pub supervise_interval: Duration,
    /// Longest wait for one supervision call to the master.
    pub master_call_timeout: Duration,
    /// Queue size of each ROS publisher and of the subscription (messages).
    pub ros_queue_size: usize,
    /// Frames `send` can queue for the publishing task before it reports congestion.
    pub send_queue: usize,
    /// Longest time a send waits for the destination's subscriber to connect to this link's
    /// publisher before it fails with [`LinkError::Unreachable`]. The fleet file's
    /// `connect_timeout_ms` overrides it.
    pub connect_timeout: Duration,
    /// How often a waiting send probes the destination (or asks a foreign node's `getBusInfo`).
    pub probe_interval: Duration,
}

impl Default for Ros1Config {
    fn default() -> Self {
        Ros1Config {
            open_timeout: Duration::from_secs(3),
            supervise_interval: Duration::from_millis(500),
            master_call_timeout: Duration::from_secs(1),
            ros_queue_size: 1024,
            send_queue: 4096,
            connect_timeout: Duration::from_millis(500),
            probe_interval: Duration::from_millis(20),
        }
    }
}

/// Why a `ros1` link could not be opened.
#[derive(Debug, thiserror::Error)]
#[non_exhaustive]
pub enum OpenError {
    /// The master did not answer (or refused) within the open timeout.
    #[error("ROS master at {uri} is unreachable: {reason} (is `roscore` / `rosmaster --core` running? check the transport's `master_uri` or ROS_MASTER_URI)")]
    MasterUnreachable {
        /// The master URI tried.
        uri: String,
        /// What went wrong.
        reason: String,
    },
    /// The master answered but registering the node, subscriber or a publisher failed.
    #[error("registering with the ROS master at {uri} failed: {reason}")]
    Registration {
        /// The master URI.
        uri: String,
        /// What went wrong.
        reason: String,
    },
    /// A system name or the namespace is not a valid ROS graph name segment.
    #[error("`{name}` cannot be part of a ROS topic name: use letters, digits and `_`, starting with a letter")]
    InvalidName {
        /// The offending name.
        name: String,
    },
    /// The local system has no name in the map given to `open`.
    #[error("system {system} has no friendly name, so it has no ROS topic")]
    UnknownLocalSystem {
        /// The local system.
        system: SystemId,
    },
    /// The link's tokio runtime could not be started.
    #[error("starting the ROS link's runtime: {0}")]
    Runtime(#[from] std::io::Error),
}

fn valid_segment(s: &str) -> bool {
    let mut chars = s.chars();
    matches!(chars.next(), Some(c) if c.is_ascii_alphabetic())
        && chars.all(|c| c.is_ascii_alphanumeric() || c == '_')
}

/// The topic of the system named `name`: `/<namespace>/<name>`, or `/<name>` without a
/// namespace. The namespace may have several segments (`fleet/hetcomm`) and leading or
/// trailing slashes, which are ignored. Fails on names that are not ROS name segments.
pub fn topic_name(namespace: Option<&str>, name: &str) -> Result<String, OpenError> {
    if !valid_segment(name) {
        return Err(OpenError::InvalidName {
            name: name.to_string(),
        });
    }
    let mut topic = String::new();
    if let Some(ns) = namespace {
        for seg in ns.split('/').filter(|s| !s.is_empty()) {
            if !valid_segment(seg) {
                return Err(OpenError::InvalidName {
                    name: ns.to_string(),
                });
            }
            topic.push('/');
            topic.push_str(seg);
        }
    }
    topic.push('/');
    topic.push_str(name);
    Ok(topic)
}

/// Counters shared by the link and its tasks.
#[derive(Default)]
struct Counters {
    sent: AtomicU64,
    received: AtomicU64,
    dropped: AtomicU64,
    connects: AtomicU64,
    queued_bytes: AtomicU64,
}

/// Everything fixed for the life of a link.
struct Plan {
    master_uri: String,
    local: SystemId,
    local_name: String,
    own_topic: String,
    /// Every other system's topic.
    peer_topics: BTreeMap<SystemId, String>,
    config: Ros1Config,
}

/// What the link knows of one destination's subscriber.
#[derive(Default)]
struct Dest {
    /// Its subscriber was seen connected to our current publisher: sends do not wait.
    connected: AtomicBool,
    /// The nodes subscribed to its topic when the connection was seen (None: not asked yet;
    /// the supervision task fills it in); the supervision task forgets the connection when
    /// they change.
    subscribers: Mutex<Option<Vec<String>>>,
    /// Held by the one send that waits for the connection.
    gate: Mutex<()>,
    /// Frames queued for it since the last probe it answered: closing the link waits until
    /// a probe behind them is answered, so that they are not lost in the publisher's queue.
    unflushed: AtomicU64,
}

/// The subscribers of a destination's topic that its connection depends on: its hetcomm
/// nodes if it has any (a `rostopic echo` coming or going changes nothing), else all.
fn relevant(subscribers: Vec<String>) -> Vec<String> {
    if subscribers.iter().any(|n| n.starts_with(NODE_PREFIX)) {
        subscribers
            .into_iter()
            .filter(|n| n.starts_with(NODE_PREFIX))
            .collect()
    } else {
        subscribers
    }
}

/// What the link's tasks share with [`Ros1Link::send`] about connections.
struct Wiring {
    dests: BTreeMap<SystemId, Dest>,
    /// Probes waiting for their answer: nonce → (probed system, wake-up).
    pending: Mutex<HashMap<u32, (SystemId, oneshot::Sender<()>)>>,
    /// The publishing task's queue (frames, probes, answers, registration swaps).
    commands: mpsc::Sender<Command>,
    /// Received frames, to the thread that calls the sink; taken when the link closes, so that
    /// the thread ends once the receive tasks are gone.
    frames: Mutex<Option<mpsc::Sender<Vec<u8>>>>,
    /// For the XML-RPC calls roslibrust does not make.
    http: reqwest::Client,
}

impl Wiring {
    /// Records that `to`'s subscriber is connected (`subscribers`: the topic's subscribers).
    fn settle(&self, to: SystemId, subscribers: Vec<String>) {
        if let Some(dest) = self.dests.get(&to) {
            *dest.subscribers.lock().unwrap_or_else(|e| e.into_inner()) =
                Some(relevant(subscribers));
            dest.connected.store(true, Ordering::Release);
        }
    }

    /// Forgets every connection (a new registration has new publishers).
    fn forget_all(&self) {
        for d in self.dests.values() {
            d.connected.store(false, Ordering::Release);
        }
    }
}

/// One registration with a master: a ROS node, our subscription and a publisher per peer.
struct Registration {
    node_name: String,
    /// Keeps the ROS node alive (dropping the last handle unregisters it).
    _node: NodeHandle,
    client: MasterClient,
    publishers: HashMap<SystemId, Publisher<UInt8MultiArray>>,
    receive_task: tokio::task::JoinHandle<()>,
}

impl Drop for Registration {
    fn drop(&mut self) {
        self.receive_task.abort();
    }
}

fn node_counter() -> u64 {
    static NEXT: AtomicU64 = AtomicU64::new(0);
    NEXT.fetch_add(1, Ordering::Relaxed)
}

/// A nonce for a probe: random enough that two processes of the same system (which share a
/// topic, so both see every answer) never take each other's answers.
fn nonce() -> u32 {
    let mut h = std::collections::hash_map::RandomState::new().build_hasher();
    h.write_u64(node_counter());
    h.write_u32(std::process::id());
    h.write_u128(
        std::time::SystemTime::now()
            .duration_since(std::time::UNIX_EPOCH)
            .map_or(0, |d| d.as_nanos()),
    );
    h.finish() as u32
}

/// Registers a new node with the master: subscribes to our topic (frames to the receive
/// thread, probes answered) and advertises a publisher on every peer's topic.
async fn register(
    plan: &Plan,
    wiring: Arc<Wiring>,
    counters: Arc<Counters>,
) -> Result<Registration, OpenError> {
    let uri = &plan.master_uri;
    let node_name = format!(
        "{NODE_PREFIX}{}_{}_{}",
        plan.local_name,
        std::process::id(),
        node_counter()
    );
    let node = NodeHandle::new(uri, &node_name).await.map_err(|e| {
        let reason = e.to_string();
        match e {
            roslibrust::ros1::NodeError::RosMasterError(_)
            | roslibrust::ros1::NodeError::IoError(_) => OpenError::MasterUnreachable {
                uri: uri.clone(),
                reason,
            },
            _ => OpenError::Registration {
                uri: uri.clone(),
                reason,
            },
        }
    })?;
    let registration = |what: &str, e: &dyn std::fmt::Display| OpenError::Registration {
        uri: uri.clone(),
        reason: format!("{what}: {e}"),
    };
    let client_uri = node
        .get_client_uri()
        .await
        .map_err(|e| registration("node URI", &e))?;
    let client = MasterClient::new(uri.as_str(), client_uri, node_name.as_str())
        .await
        .map_err(|e| OpenError::MasterUnreachable {
            uri: uri.clone(),
            reason: e.to_string(),
        })?;
    let subscriber: Subscriber<UInt8MultiArray> = node
        .subscribe(&plan.own_topic, plan.config.ros_queue_size)
        .await
        .map_err(|e| registration(&format!("subscribing to {}", plan.own_topic), &e))?;
    let mut publishers = HashMap::new();
    for (&peer, topic) in &plan.peer_topics {
        let publisher = node
            .advertise::<UInt8MultiArray>(topic, plan.config.ros_queue_size, false)
            .await
            .map_err(|e| registration(&format!("advertising {topic}"), &e))?;
        publishers.insert(peer, publisher);
    }
    let frames = wiring
        .frames
        .lock()
        .unwrap_or_else(|e| e.into_inner())
        .clone()
        .ok_or_else(|| registration("receiving", &"the link is closing"))?;
    let receive_task = tokio::spawn(receive_loop(subscriber, wiring, frames, counters.clone()));
    counters.connects.fetch_add(1, Ordering::Relaxed);
    Ok(Registration {
        node_name,
        _node: node,
        client,
        publishers,
        receive_task,
    })
}

/// A probe or a probe's answer, if `msg` is one.
fn control(msg: &UInt8MultiArray) -> Option<(&str, u32, SystemId)> {
    if !msg.data.is_empty() {
        return None;
    }
    let d = msg.layout.dim.first()?;
    let from = SystemId(u16::try_from(d.stride).ok()?);
    Some((d.label.as_str(), d.size, from))
}

async fn receive_loop(
    mut subscriber: Subscriber<UInt8MultiArray>,
    wiring: Arc<Wiring>,
    frames: mpsc::Sender<Vec<u8>>,
    counters: Arc<Counters>,
) {
    while let Some(next) = subscriber.next().await {
        match next {
            Ok(msg) if msg.data.is_empty() => match control(&msg) {
                // Answer on the prober's topic, if it is a system of the fleet. A full queue
                // loses the answer; the prober probes again.
                Some((PROBE_LABEL, nonce, from)) if wiring.dests.contains_key(&from) => {
                    let _ = wiring.commands.try_send(Command::ProbeAck(from, nonce));
                }
                Some((PROBE_ACK_LABEL, nonce, from)) => {
                    let mut pending = wiring.pending.lock().unwrap_or_else(|e| e.into_inner());
                    if pending.get(&nonce).is_some_and(|(to, _)| *to == from) {
                        if let Some((_, wake)) = pending.remove(&nonce) {
                            // Queued before the waiting send's frame, so it arrives first.
                            let _ = wiring.commands.try_send(Command::Confirm(from, nonce));
                            let _ = wake.send(());
                        }
                    }
                }
                // Our answer to `from`'s probe reached it: our publisher to it is connected.
                Some((PROBE_CONFIRM_LABEL, _, from)) => {
                    // (A new process of that system: the subscribers the supervision task
                    // compares against are asked anew.)
                    if let Some(dest) = wiring.dests.get(&from) {
                        *dest.subscribers.lock().unwrap_or_else(|e| e.into_inner()) = None;
                        dest.connected.store(true, Ordering::Release);
                    }
                }
                // Other empty messages (e.g. `rostopic pub` with no data) are ignored.
                _ => {}
            },
            Ok(msg) => {
                counters.received.fetch_add(1, Ordering::Relaxed);
                if frames.send(msg.data).await.is_err() {
                    return;
                }
            }
            // The subscription's queue overflowed (we fell behind) or a message did not
            // deserialize as UInt8MultiArray.
            Err(_) => {
                counters.dropped.fetch_add(1, Ordering::Relaxed);
            }
        }
    }
}

/// What the publishing task receives.
enum Command {
    /// Publish a frame on a peer's topic.
    Frame(SystemId, Vec<u8>),
    /// Publish a connection probe (nonce) on a peer's topic.
    Probe(SystemId, u32),
    /// Answer a peer's probe (nonce) on its topic.
    ProbeAck(SystemId, u32),
    /// Tell a peer its answer (nonce) arrived.
    Confirm(SystemId, u32),
    /// Replace the registration (after a master restart).
    Swap(Registration),
}

/// An empty message whose layout carries a probe or an answer.
fn control_message(label: &str, nonce: u32, from: SystemId) -> UInt8MultiArray {
    UInt8MultiArray {
        layout: MultiArrayLayout {
            dim: vec![MultiArrayDimension {
                label: label.to_string(),
                size: nonce,
                stride: u32::from(from.0),
            }],
            data_offset: 0,
        },
        data: Vec::new(),
    }
}

/// Drops a registration off the async threads: roslibrust unregisters a dropped node from the
/// master with blocking HTTP calls.
fn retire(old: Registration) {
    drop(tokio::task::spawn_blocking(move || drop(old)));
}

/// Owns the current registration and publishes queued frames.
async fn publish_loop(
    mut registration: Registration,
    mut commands: mpsc::Receiver<Command>,
    local: SystemId,
    counters: Arc<Counters>,
    mut stop: oneshot::Receiver<()>,
) -> Registration {
    loop {
        let command = tokio::select! {
            biased;
            _ = &mut stop => break,
            c = commands.recv() => match c {
                Some(c) => c,
                None => break,
            },
        };
        let (to, msg) = match command {
            Command::Frame(to, frame) => {
                counters
                    .queued_bytes
                    .fetch_sub(frame.len() as u64, Ordering::Relaxed);
                let msg = UInt8MultiArray {
                    layout: MultiArrayLayout::default(),
                    data: frame,
                };
                (to, msg)
            }
            Command::Probe(to, nonce) => (to, control_message(PROBE_LABEL, nonce, local)),
            Command::ProbeAck(to, nonce) => (to, control_message(PROBE_ACK_LABEL, nonce, local)),
            Command::Confirm(to, nonce) => (to, control_message(PROBE_CONFIRM_LABEL, nonce, local)),
            Command::Swap(new) => {
                let old = std::mem::replace(&mut registration, new);
                retire(old);
                continue;
            }
        };
        let Some(publisher) = registration.publishers.get(&to) else {
            continue;
        };
        if publisher.publish(&msg).await.is_err() && !msg.data.is_empty() {
            counters.dropped.fetch_add(1, Ordering::Relaxed);
        }
    }
    registration
}

/// What the supervision task last saw of the master.
#[derive(Clone, Debug, PartialEq, Eq)]
pub enum MasterState {
    /// The master answers and knows this link's subscription.
    Registered,
    /// The master does not answer; the reason.
    Unreachable(String),
    /// The master answered without our registration and re-registering failed; the reason.
    Reregistering(String),
}

/// The current registration's names, as other nodes know it.
#[derive(Clone, Debug, Default)]
struct Identity {
    node_name: String,
    /// The node's XML-RPC URI (foreign subscribers name their publishers by it).
    uri: String,
}

struct Shared {
    plan: Plan,
    /// Nodes whose XML-RPC server has no `getBusInfo` (roslibrust nodes).
    without_bus_info: Mutex<std::collections::HashSet<String>>,
    /// The master's last answer to `getSystemState`, and when it came.
    graph_cache: Mutex<Option<(Instant, Arc<xmlrpc::Graph>)>>,
    counters: Arc<Counters>,
    wiring: Arc<Wiring>,
    master: Mutex<MasterState>,
    identity: Mutex<Identity>,
    closed: AtomicBool,
}

impl Shared {
    fn identity(&self) -> Identity {
        self.identity
            .lock()
            .unwrap_or_else(|e| e.into_inner())
            .clone()
    }

    /// Asks the master who subscribes to what.
    async fn graph(&self, timeout: Duration) -> Result<xmlrpc::Graph, String> {
        let me = self.identity().node_name;
        xmlrpc::call(
            &self.wiring.http,
            &self.plan.master_uri,
            "getSystemState",
            vec![me.into()],
            timeout,
        )
        .await
        .map_err(|e| e.to_string())
        .map(|v| {
            let graph = xmlrpc::Graph::from_value(&v);
            *self.graph_cache.lock().unwrap_or_else(|e| e.into_inner()) =
                Some((Instant::now(), Arc::new(graph.clone())));
            graph
        })
    }

    /// The master's last answer, if it is recent (one supervision interval).
    fn cached_graph(&self) -> Option<Arc<xmlrpc::Graph>> {
        let cache = self.graph_cache.lock().unwrap_or_else(|e| e.into_inner());
        let (at, graph) = cache.as_ref()?;
        (at.elapsed() <= self.plan.config.supervise_interval).then(|| graph.clone())
    }

    /// Whether `node`'s `getBusInfo` lists an inbound connection on `topic` from our node;
    /// None if the node does not implement `getBusInfo` (a roslibrust node, such as a hetcomm
    /// link: it answers probes instead), which is remembered.
    async fn bus_info_connected(&self, node: &str, topic: &str, timeout: Duration) -> Option<bool> {
        if self
            .without_bus_info
            .lock()
            .unwrap_or_else(|e| e.into_inner())
            .contains(node)
        {
            return None;
        }
        let me = self.identity();
        let http = &self.wiring.http;
        let args = vec![me.node_name.clone().into(), node.to_string().into()];
        let master = &self.plan.master_uri;
        let Ok(serde_xmlrpc::Value::String(uri)) =
            xmlrpc::call(http, master, "lookupNode", args, timeout).await
        else {
            return Some(false);
        };
        let args = vec![me.node_name.into()];
        match xmlrpc::call(http, &uri, "getBusInfo", args, timeout).await {
            Ok(info) => Some(xmlrpc::bus_info_has_inbound(&info, topic, &me.uri)),
            Err(e) if e.http_status == Some(501) => {
                let mut without = self
                    .without_bus_info
                    .lock()
                    .unwrap_or_else(|e| e.into_inner());
                without.insert(node.to_string());
                None
            }
            Err(_) => Some(false),
        }
    }
}

/// How often a waiting send asks the master again who subscribes to the destination's topic.
const GRAPH_REFRESH: Duration = Duration::from_millis(100);

/// Waits until `to`'s subscriber is connected to our publisher on its topic (see the crate
/// docs), at most `timeout`. Returns the topic's subscribers then (as last seen), or why it
/// gave up.
///
/// The master is not on the critical path of a hetcomm destination: the link probes at once
/// (and every probe interval) unless the master is known to list only foreign subscribers,
/// while it asks the master in the background who subscribes (a loaded master may take
/// longer than the whole timeout to answer).
async fn wait_connected(
    shared: Arc<Shared>,
    to: SystemId,
    timeout: Duration,
) -> Result<Vec<String>, String> {
    let start = Instant::now();
    let deadline = start + timeout;
    let plan = &shared.plan;
    let topic = plan
        .peer_topics
        .get(&to)
        .ok_or_else(|| "not a system of this fleet".to_string())?
        .clone();
    // hetcomm links of the destination register as `/hetcomm_<name>_<pid>_<n>`.
    let name = topic.rsplit('/').next().unwrap_or_default();
    let our_prefix = format!("{NODE_PREFIX}{name}_");
    let nonce = nonce();
    let (wake, mut answered) = oneshot::channel();
    shared
        .wiring
        .pending
        .lock()
        .unwrap_or_else(|e| e.into_inner())
        .insert(nonce, (to, wake));
    // What the master said last: None until it answered.
    let mut subscribers: Option<Vec<String>> = shared.cached_graph().map(|g| g.subscribers(&topic));
    let mut master_problem = None;
    let mut asking: Option<tokio::task::JoinHandle<Result<xmlrpc::Graph, String>>> = None;
    let mut asked: Option<Instant> = None;
    let outcome = loop {
        if asking.is_none()
            && asked.is_none_or(|t| t.elapsed() >= GRAPH_REFRESH)
            && Instant::now() < deadline
        {
            let shared = shared.clone();
            let left = deadline.saturating_duration_since(Instant::now());
            asked = Some(Instant::now());
            asking = Some(tokio::spawn(async move { shared.graph(left).await }));
        }
        // Probe while hetcomm nodes of the destination subscribe (or nobody knows yet), and
        // ask every other subscriber's getBusInfo; either way may show the connection.
        let known = subscribers.as_deref().unwrap_or_default();
        let ours = known.iter().any(|n| n.starts_with(&our_prefix));
        if subscribers.is_none() || ours {
            let probe = Command::Probe(to, nonce);
            if shared.wiring.commands.send(probe).await.is_err() {
                break Err("the link is closed".to_string());
            }
        }
        let mut by_bus_info = false;
        for node in known.iter().filter(|n| !n.starts_with(&our_prefix)) {
            let left = deadline.saturating_duration_since(Instant::now());
            let left = left.max(Duration::from_millis(1));
            if shared.bus_info_connected(node, &topic, left).await == Some(true) {
                by_bus_info = true;
                break;
            }
        }
        if by_bus_info {
            break Ok(());
        }
        let left = deadline.saturating_duration_since(Instant::now());
        if left.is_zero() {
            let why = match (&subscribers, master_problem.take()) {
                (None, Some(p)) => format!("the ROS master did not answer: {p}"),
                (None, None) => "the ROS master did not answer in time".to_string(),
                (Some(s), _) if s.is_empty() => format!("no node subscribes to {topic}"),
                (Some(s), _) if ours => format!(
                    "subscribed by {}; no answer to the connection probe",
                    s.join(", ")
                ),
                (Some(s), _) => format!(
                    "subscribed by {}; no getBusInfo lists a connection from this node",
                    s.join(", ")
                ),
            };
            let ms = timeout.as_millis();
            break Err(format!(
                "the subscriber of {topic} did not connect within {ms} ms ({why})"
            ));
        }
        let pause = tokio::time::sleep(plan.config.probe_interval.min(left));
        tokio::select! {
            Ok(()) = &mut answered => break Ok(()),
            graph = async { asking.as_mut().expect("guarded").await }, if asking.is_some() => {
                asking = None;
                match graph {
                    Ok(Ok(graph)) => {
                        subscribers = Some(graph.subscribers(&topic));
                        master_problem = None;
                    }
                    Ok(Err(e)) => master_problem = Some(e),
                    Err(e) => master_problem = Some(e.to_string()),
                }
            }
            _ = pause => {}
        }
    };
    if let Some(task) = asking {
        task.abort();
    }
    shared
        .wiring
        .pending
        .lock()
        .unwrap_or_else(|e| e.into_inner())
        .remove(&nonce);
    outcome.map(|()| subscribers.unwrap_or_default())
}

/// Probes `to` and waits (at most `timeout`) for the answer, which comes after everything
/// queued before the probe was read. A destination with no hetcomm subscriber answers no
/// probe: it gets [`FOREIGN_FLUSH_GRACE`] instead.
async fn wait_answer(shared: Arc<Shared>, to: SystemId, timeout: Duration) {
    let Some(topic) = shared.plan.peer_topics.get(&to) else {
        return;
    };
    let name = topic.rsplit('/').next().unwrap_or_default();
    let ours = format!("{NODE_PREFIX}{name}_");
    if shared
        .cached_graph()
        .is_some_and(|g| !g.subscribers(topic).iter().any(|n| n.starts_with(&ours)))
    {
        tokio::time::sleep(FOREIGN_FLUSH_GRACE).await;
        return;
    }
    let nonce = nonce();
    let (wake, answered) = oneshot::channel();
    let pending = &shared.wiring.pending;
    pending
        .lock()
        .unwrap_or_else(|e| e.into_inner())
        .insert(nonce, (to, wake));
    if shared
        .wiring
        .commands
        .send(Command::Probe(to, nonce))
        .await
        .is_ok()
    {
        let _ = tokio::time::timeout(timeout, answered).await;
    }
    pending
        .lock()
        .unwrap_or_else(|e| e.into_inner())
        .remove(&nonce);
}

/// How long a closing link gives its publishers to write frames to a destination that
/// answers no probes.
const FOREIGN_FLUSH_GRACE: Duration = Duration::from_millis(50);

/// Checks the master periodically; re-registers when it lost our registration, and forgets
/// the connection of destinations whose subscribers changed.
async fn supervise_loop(shared: Arc<Shared>) {
    let plan = &shared.plan;
    let mut tick = tokio::time::interval(plan.config.supervise_interval);
    tick.set_missed_tick_behavior(tokio::time::MissedTickBehavior::Delay);
    tick.tick().await;
    loop {
        tick.tick().await;
        let node_name = shared.identity().node_name;
        let new_state = match shared.graph(plan.config.master_call_timeout).await {
            Err(e) => MasterState::Unreachable(e),
            Ok(graph) if graph.subscribers(&plan.own_topic).contains(&node_name) => {
                for (to, dest) in &shared.wiring.dests {
                    if !dest.connected.load(Ordering::Acquire) {
                        continue;
                    }
                    let now = relevant(graph.subscribers(&plan.peer_topics[to]));
                    let mut then = dest.subscribers.lock().unwrap_or_else(|e| e.into_inner());
                    match &*then {
                        None => *then = Some(now),
                        Some(then) if *then != now => {
                            dest.connected.store(false, Ordering::Release)
                        }
                        Some(_) => {}
                    }
                }
                MasterState::Registered
            }
            Ok(_) => {
                // The master answers but does not know us: it was restarted. Register anew.
                match tokio::time::timeout(
                    plan.config.open_timeout,
                    register(plan, shared.wiring.clone(), shared.counters.clone()),
                )
                .await
                {
                    Ok(Ok(registration)) => {
                        let identity = Identity {
                            node_name: registration.node_name.clone(),
                            uri: registration.client.client_uri().to_string(),
                        };
                        if shared
                            .wiring
                            .commands
                            .send(Command::Swap(registration))
                            .await
                            .is_err()
                        {
                            return;
                        }
                        shared.wiring.forget_all();
                        *shared.identity.lock().unwrap_or_else(|e| e.into_inner()) = identity;
                        MasterState::Registered
                    }
                    Ok(Err(e)) => MasterState::Reregistering(e.to_string()),
                    Err(_) => MasterState::Reregistering(format!(
                        "no answer within {:?}",
                        plan.config.open_timeout
                    )),
                }
            }
        };
        *shared.master.lock().unwrap_or_else(|e| e.into_inner()) = new_state;
    }
}

/// Waits, all at once and at most the connect timeout, for the subscribers of the peers that
/// the master lists as running (subscribed to their topic), so that the first sends to them
/// need not wait. Peers that do not connect in time are left to the sends (which wait again
/// and fail with the reason).
async fn connect_running_peers(shared: Arc<Shared>) {
    let timeout = shared.plan.config.connect_timeout;
    let Ok(graph) = shared.graph(timeout).await else {
        return;
    };
    let mut waits = tokio::task::JoinSet::new();
    for (&to, topic) in &shared.plan.peer_topics {
        if !graph.subscribers(topic).is_empty() {
            let shared = shared.clone();
            waits.spawn(async move { (to, wait_connected(shared, to, timeout).await) });
        }
    }
    while let Some(done) = waits.join_next().await {
        if let Ok((to, Ok(subscribers))) = done {
            shared.wiring.settle(to, subscribers);
        }
    }
}

thread_local! {
    /// Set on the threads of a link's runtime: a send there must not block on the runtime.
    static ON_LINK_RUNTIME: Cell<bool> = const { Cell::new(false) };
}

/// A `ros1` link endpoint of one system. See the [crate docs](crate).
pub struct Ros1Link {
    shared: Arc<Shared>,
    stop: Option<oneshot::Sender<()>>,
    publisher: Option<tokio::task::JoinHandle<Registration>>,
    supervisor: Option<tokio::task::JoinHandle<()>>,
    handle: tokio::runtime::Handle,
    runtime: Option<tokio::runtime::Runtime>,
    /// The receive thread, and word that it ended.
    receiver: Mutex<Option<(std::thread::JoinHandle<()>, std::sync::mpsc::Receiver<()>)>>,
}

impl Ros1Link {
    /// Opens system `local`'s endpoint: registers a ROS node with the master of `settings`,
    /// subscribes to `local`'s topic (received frames go to `sink`) and advertises a publisher
    /// on the topic of every other system in `systems` (id → friendly name; the fleet's
    /// systems). Fails within `config.open_timeout` if the master does not answer.
    /// `settings.connect_timeout_ms`, when given, replaces `config.connect_timeout`.
    pub fn open(
        local: SystemId,
        systems: &BTreeMap<SystemId, String>,
        settings: &Ros1Settings,
        sink: Arc<dyn FrameSink>,
        mut config: Ros1Config,
    ) -> Result<Ros1Link, OpenError> {
        if let Some(ms) = settings.connect_timeout_ms {
            config.connect_timeout = Duration::from_millis(ms);
        }
        let namespace = settings.namespace.as_deref();
        let local_name = systems
            .get(&local)
            .ok_or(OpenError::UnknownLocalSystem { system: local })?
            .clone();
        let own_topic = topic_name(namespace, &local_name)?;
        let mut peer_topics = BTreeMap::new();
        for (&id, name) in systems {
            if id != local {
                peer_topics.insert(id, topic_name(namespace, name)?);
            }
        }
        let plan = Plan {
            master_uri: settings.master_uri.clone(),
            local,
            local_name,
            own_topic,
            peer_topics,
            config,
        };
        let runtime = tokio::runtime::Builder::new_multi_thread()
            .worker_threads(2)
            .thread_name("hetcomm-ros1")
            .on_thread_start(|| ON_LINK_RUNTIME.with(|f| f.set(true)))
            .enable_all()
            .build()?;
        let counters = Arc::new(Counters::default());
        let (commands, rx) = mpsc::channel(plan.config.send_queue.max(1));
        let (frames, mut frames_rx) = mpsc::channel::<Vec<u8>>(plan.config.ros_queue_size.max(1));
        let wiring = Arc::new(Wiring {
            dests: plan
                .peer_topics
                .keys()
                .map(|&id| (id, Dest::default()))
                .collect(),
            pending: Mutex::new(HashMap::new()),
            commands,
            frames: Mutex::new(Some(frames)),
            http: reqwest::Client::new(),
        });
        let timeout = plan.config.open_timeout;
        let registration = runtime.block_on(async {
            tokio::time::timeout(timeout, register(&plan, wiring.clone(), counters.clone()))
                .await
                .unwrap_or_else(|_| {
                    Err(OpenError::MasterUnreachable {
                        uri: plan.master_uri.clone(),
                        reason: format!("no answer within {timeout:?}"),
                    })
                })
        });
        let registration = match registration {
            Ok(r) => r,
            Err(e) => {
                runtime.shutdown_timeout(Duration::from_millis(500));
                return Err(e);
            }
        };
        // Frames reach the sink on a thread of their own (see "Threads" in the crate docs).
        let (receiver_done, receiver_ended) = std::sync::mpsc::channel();
        let receiver = std::thread::Builder::new()
            .name("hetcomm-ros1-rx".into())
            .spawn(move || {
                while let Some(frame) = frames_rx.blocking_recv() {
                    sink.on_frame(&frame, Peer::Unknown);
                }
                drop(sink);
                let _ = receiver_done.send(());
            });
        let receiver = match receiver {
            Ok(r) => r,
            Err(e) => {
                drop(registration);
                runtime.shutdown_timeout(Duration::from_millis(500));
                return Err(OpenError::Runtime(e));
            }
        };
        let (stop, stop_rx) = oneshot::channel();
        let shared = Arc::new(Shared {
            graph_cache: Mutex::new(None),
            without_bus_info: Mutex::new(Default::default()),
            identity: Mutex::new(Identity {
                node_name: registration.node_name.clone(),
                uri: registration.client.client_uri().to_string(),
            }),
            plan,
            counters: counters.clone(),
            wiring,
            master: Mutex::new(MasterState::Registered),
            closed: AtomicBool::new(false),
        });
        let publisher = runtime.spawn(publish_loop(registration, rx, local, counters, stop_rx));
        let supervisor = runtime.spawn(supervise_loop(shared.clone()));
        runtime.block_on(connect_running_peers(shared.clone()));
        Ok(Ros1Link {
            shared,
            stop: Some(stop),
            publisher: Some(publisher),
            supervisor: Some(supervisor),
            handle: runtime.handle().clone(),
            runtime: Some(runtime),
            receiver: Mutex::new(Some((receiver, receiver_ended))),
        })
    }

    /// The topic this link subscribes to (its system's topic).
    pub fn topic(&self) -> &str {
        &self.shared.plan.own_topic
    }

    /// The topic frames for `system` are published on, if it is a peer of this link.
    pub fn peer_topic(&self, system: SystemId) -> Option<&str> {
        self.shared
            .plan
            .peer_topics
            .get(&system)
            .map(String::as_str)
    }

    /// The master URI this link registers with.
    pub fn master_uri(&self) -> &str {
        &self.shared.plan.master_uri
    }

    /// The ROS node name of the current registration (changes when the link re-registers).
    pub fn node_name(&self) -> String {
        self.shared.identity().node_name
    }

    /// What the supervision task last saw of the master.
    pub fn master_state(&self) -> MasterState {
        self.shared
            .master
            .lock()
            .unwrap_or_else(|e| e.into_inner())
            .clone()
    }

    /// The system this link belongs to.
    pub fn local(&self) -> SystemId {
        self.shared.plan.local
    }

    /// Whether `system`'s subscriber has been seen connected to this link's publisher (sends
    /// to it do not wait).
    pub fn is_connected(&self, system: SystemId) -> bool {
        self.shared
            .wiring
            .dests
            .get(&system)
            .is_some_and(|d| d.connected.load(Ordering::Acquire))
    }

    /// Before closing: waits (at most the connect timeout) until every destination that was
    /// sent frames answers a probe queued behind them, i.e. has read them. roslibrust's
    /// publishers write from a queue of their own, and a node dropped before it wrote its
    /// queue loses it. Destinations that do not answer probes (foreign nodes) get a short
    /// grace period instead.
    fn flush(&self) {
        if ON_LINK_RUNTIME.with(Cell::get) {
            return;
        }
        let pending: Vec<SystemId> = self
            .shared
            .wiring
            .dests
            .iter()
            .filter(|(_, d)| d.unflushed.swap(0, Ordering::Relaxed) > 0)
            .map(|(&to, _)| to)
            .collect();
        if pending.is_empty() {
            return;
        }
        let timeout = self.shared.plan.config.connect_timeout;
        let (tx, rx) = std::sync::mpsc::channel();
        let shared = self.shared.clone();
        self.handle.spawn(async move {
            let mut waits = tokio::task::JoinSet::new();
            for to in pending {
                let shared = shared.clone();
                waits.spawn(wait_answer(shared, to, timeout));
            }
            while waits.join_next().await.is_some() {}
            let _ = tx.send(());
        });
        let _ = rx.recv_timeout(timeout + Duration::from_secs(1));
    }

    /// Waits (at most the connect timeout) until `to`'s subscriber is connected; the reason
    /// if it is not.
    fn ensure_connected(&self, to: SystemId) -> Result<(), LinkError> {
        let Some(dest) = self.shared.wiring.dests.get(&to) else {
            return Ok(());
        };
        if dest.connected.load(Ordering::Acquire) {
            return Ok(());
        }
        let timeout = self.shared.plan.config.connect_timeout;
        let topic = &self.shared.plan.peer_topics[&to];
        if ON_LINK_RUNTIME.with(Cell::get) {
            // Blocking here would stall the runtime that answers probes. Sinks are called on
            // the receive thread, so this takes a sink that calls back from elsewhere.
            return Err(LinkError::Unreachable {
                peer: to,
                reason: format!(
                    "the subscriber of {topic} is not connected yet (a send on the link's own runtime cannot wait for it)"
                ),
            });
        }
        let _gate = dest.gate.lock().unwrap_or_else(|e| e.into_inner());
        if dest.connected.load(Ordering::Acquire) {
            return Ok(());
        }
        let (tx, rx) = std::sync::mpsc::channel();
        let shared = self.shared.clone();
        self.handle.spawn(async move {
            let _ = tx.send(wait_connected(shared, to, timeout).await);
        });
        // The task ends by its own deadline; the margin only covers a runtime that is gone.
        match rx.recv_timeout(timeout + Duration::from_secs(2)) {
            Ok(Ok(subscribers)) => {
                self.shared.wiring.settle(to, subscribers);
                Ok(())
            }
            Ok(Err(reason)) => Err(LinkError::Unreachable { peer: to, reason }),
            Err(_) if self.shared.closed.load(Ordering::Relaxed) => Err(LinkError::Closed),
            Err(_) => Err(LinkError::Unreachable {
                peer: to,
                reason: format!(
                    "the subscriber of {topic} did not connect within {} ms",
                    timeout.as_millis()
                ),
            }),
        }
    }
}

impl Link for Ros1Link {
    fn caps(&self) -> LinkCaps {
        LinkCaps {
            max_frame: MAX_FRAME,
            mtu: MAX_FRAME,
            reliable: false,
            ordered: true,
            broadcast: false,
        }
    }

    fn send(&self, to: SystemId, frame: &[u8]) -> Result<(), LinkError> {
        if self.shared.closed.load(Ordering::Relaxed) {
            return Err(LinkError::Closed);
        }
        if frame.len() > MAX_FRAME {
            return Err(LinkError::TooLarge {
                len: frame.len(),
                max: MAX_FRAME,
            });
        }
        let plan = &self.shared.plan;
        if !plan.peer_topics.contains_key(&to) {
            let reason = if to == plan.local {
                "a ros1 link does not send to its own system".to_string()
            } else {
                "not a system of this fleet, so it has no ROS topic".to_string()
            };
            return Err(LinkError::Unreachable { peer: to, reason });
        }
        self.ensure_connected(to)?;
        let counters = &self.shared.counters;
        match self
            .shared
            .wiring
            .commands
            .try_send(Command::Frame(to, frame.to_vec()))
        {
            Ok(()) => {
                if let Some(dest) = self.shared.wiring.dests.get(&to) {
                    dest.unflushed.fetch_add(1, Ordering::Relaxed);
                }
                counters.sent.fetch_add(1, Ordering::Relaxed);
                counters
                    .queued_bytes
                    .fetch_add(frame.len() as u64, Ordering::Relaxed);
                Ok(())
            }
            Err(mpsc::error::TrySendError::Full(_)) => Err(LinkError::Congested {
                peer: to,
                reason: format!(
                    "{} frames queued for the ROS publisher",
                    plan.config.send_queue
                ),
            }),
            Err(mpsc::error::TrySendError::Closed(_)) => Err(LinkError::Closed),
        }
    }

    fn stats(&self) -> LinkStats {
        let c = &self.shared.counters;
        LinkStats {
            frames_sent: c.sent.load(Ordering::Relaxed),
            frames_received: c.received.load(Ordering::Relaxed),
            frames_dropped: c.dropped.load(Ordering::Relaxed),
            connects: c.connects.load(Ordering::Relaxed),
            buffered_bytes: c.queued_bytes.load(Ordering::Relaxed),
            kernel_drops: 0,
            security: Default::default(),
        }
    }
}

impl Drop for Ros1Link {
    fn drop(&mut self) {
        self.shared.closed.store(true, Ordering::Relaxed);
        self.flush();
        drop(
            self.shared
                .wiring
                .frames
                .lock()
                .unwrap_or_else(|e| e.into_inner())
                .take(),
        );
        let Some(runtime) = self.runtime.take() else {
            return;
        };
        if let Some(stop) = self.stop.take() {
            let _ = stop.send(());
        }
        if let Some(s) = self.supervisor.take() {
            s.abort();
        }
        let publisher = self.publisher.take();
        // Shut down on a plain thread: this may run inside another async runtime, where
        // blocking on ours is not allowed. roslibrust unregisters the dropped node from the
        // master with blocking calls (2 s timeout each).
        let shutdown = std::thread::Builder::new()
            .name("hetcomm-ros1-close".into())
            .spawn(move || {
                let registration = publisher.and_then(|p| {
                    runtime
                        .block_on(async { tokio::time::timeout(Duration::from_secs(2), p).await })
                        .ok()
                        .and_then(Result::ok)
                });
                {
                    let _guard = runtime.enter();
                    drop(registration);
                }
                runtime.shutdown_timeout(Duration::from_secs(1));
            });
        if let Ok(handle) = shutdown {
            let _ = handle.join();
        }
        // The receive thread ends once the receive tasks (gone with the runtime) dropped their
        // senders, unless the sink it is in waits for something the closing thread holds (the
        // system's router, say): then it is left to finish on its own.
        let receiver = self.receiver.get_mut().unwrap_or_else(|e| e.into_inner());
        if let Some((receiver, ended)) = receiver.take() {
            if receiver.thread().id() != std::thread::current().id()
                && ended.recv_timeout(Duration::from_secs(1)).is_ok()
            {
                let _ = receiver.join();
            }
        }
    }
}

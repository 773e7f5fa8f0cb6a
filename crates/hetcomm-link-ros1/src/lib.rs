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
//! * Opening fails within [`Ros1Config::open_timeout`] with [`Ros1OpenError::MasterUnreachable`]
//!   (naming the URI) when the master does not answer.
//! * While the link runs, a supervision task asks the master every
//!   [`Ros1Config::supervise_interval`] whether this link's subscription is still registered.
//!   If the master is gone, frames keep flowing over the TCPROS connections already made (ROS 1
//!   nodes talk peer to peer; the master only introduces them) and frames for destinations with
//!   no connection are lost (reported by the router as "no acknowledgement"). When a master
//!   answers again without our registration (it was restarted), the link re-registers: it
//!   creates a new ROS node with a fresh subscriber and publishers and drops the old one, so
//!   traffic resumes through the new master. [`LinkStats::connects`] counts registrations.
//! * The link also re-registers when sends to a destination keep waiting in vain (3 s) while
//!   its hetcomm subscriber is listed by the master and its node answers `getPid`: roslibrust
//!   takes a publisher's subscribers one at a time and waits for each one's TCPROS header
//!   (and a subscriber for a publisher's `requestTopic` answer) without a time limit, so one
//!   stalled connection can keep two live nodes apart for good; new registrations have new
//!   ports. Repeated re-registrations for a destination that keeps not answering back off
//!   (doubling, at most one a minute).
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

mod connect;
mod link;
mod registration;
mod tasks;
mod xmlrpc;

use connect::{wait_answer, wait_connected};
use registration::{nonce, register, retire};
use tasks::{
    connect_running_peers, publish_loop, receive_loop, supervise_loop, FOREIGN_FLUSH_GRACE,
};

use parking_lot::Mutex;
use std::cell::Cell;
use std::collections::{BTreeMap, HashMap};
use std::hash::{BuildHasher, Hasher};
use std::sync::atomic::{AtomicBool, AtomicU64, Ordering};
use std::sync::Arc;
use std::time::{Duration, Instant};

use hetcomm_core::SystemId;
use hetcomm_link::{FrameSink, Link, LinkCaps, LinkError, LinkEvent, LinkStats, Peer};
use roslibrust::ros1::{MasterClient, NodeHandle, Publisher, Subscriber};
use tokio::sync::{mpsc, oneshot};

pub mod bridge;
pub mod factory;
pub mod settings;

pub use settings::{default_master_uri, Ros1Settings};

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
pub enum Ros1OpenError {
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
pub fn topic_name(namespace: Option<&str>, name: &str) -> Result<String, Ros1OpenError> {
    if !valid_segment(name) {
        return Err(Ros1OpenError::InvalidName {
            name: name.to_string(),
        });
    }
    let mut topic = String::new();
    if let Some(ns) = namespace {
        for seg in ns.split('/').filter(|s| !s.is_empty()) {
            if !valid_segment(seg) {
                return Err(Ros1OpenError::InvalidName {
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
    /// Since when its hetcomm subscriber, listed by the master, has answered none of our
    /// probes, and when a wait for it last ended so (None: it answered, or nobody waited for
    /// it since the last registration). The supervision task re-registers when this lasts
    /// while sends still wait (see [`tasks::HEAL_AFTER`]).
    unanswered: Mutex<Option<(Instant, Instant)>>,
    /// Whether the link last reported it up (its subscriber connected) to the sink.
    up: AtomicBool,
}

impl Dest {
    /// Records that a wait for its subscriber ended without an answer to the probes.
    fn mark_unanswered(&self) {
        let now = Instant::now();
        let mut unanswered = self.unanswered.lock();
        let since = unanswered.map_or(now, |(since, _)| since);
        *unanswered = Some((since, now));
    }

    /// Forgets that its subscriber did not answer.
    fn clear_unanswered(&self) {
        *self.unanswered.lock() = None;
    }

    /// How long its subscriber has answered none of our probes, if it has not and a wait for
    /// it failed within `recent` (a destination nobody sends to any more is left alone).
    fn unanswered_for(&self, recent: Duration) -> Option<Duration> {
        let unanswered = self.unanswered.lock();
        let (since, last) = (*unanswered)?;
        (last.elapsed() <= recent).then(|| since.elapsed())
    }
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
    /// the thread ends once the receive tasks are gone. An empty one only wakes the thread for
    /// `presence`.
    frames: Mutex<Option<mpsc::Sender<Vec<u8>>>>,
    /// Presence changes not yet told to the sink (the receive thread tells them, after the
    /// frames queued before them).
    presence: Mutex<Vec<LinkEvent>>,
    /// For the XML-RPC calls roslibrust does not make.
    http: reqwest::Client,
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

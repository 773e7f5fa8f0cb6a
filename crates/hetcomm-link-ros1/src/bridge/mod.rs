//! The `ros1_bridge` transport kind: an external ROS 1 robot (a system that runs ROS 1, not
//! hetcomm) in the fleet, through typed ROS topics of its master.
//!
//! The ROS 1 twin of `ros2_bridge`, with the same fleet-file shape (docs/ros-bridges.md). A
//! bridge is a link between this system and the robot; its table maps, per module and message
//! type, to ROS topics and types ([`BridgeSettings`]):
//!
//! * **publish** (hetcomm → ROS): a message of type `TYPE_ID` sent to (robot, `MODULE`) is
//!   converted by field name (`hetcomm_rosmsg::codec`, ROS 1 serialization) and published on
//!   the topic, advertised with the ROS type's MD5 sum and definition. Nobody acknowledges it:
//!   the transport must say `delivery = "unacknowledged"`, and the outcome is Sent (without
//!   confirmation). A message that does not convert fails its send at once
//!   ([`LinkError::Refused`]), naming both types and the field. A send waits (at most
//!   `connect_timeout_ms`) until the topic's subscribers that the master lists are connected
//!   ([`subscribers`]); if none is, nothing is published and the send fails
//!   ([`LinkError::Unreachable`], "no node subscribes to …"). A closing bridge waits (as long
//!   again) until its subscribers have read what it published.
//! * **subscribe** (ROS → hetcomm): a ROS message on the topic arrives in this system's
//!   `MODULE` as a message of type `TYPE_ID` from the robot. A system whose `[systems]` entry
//!   lists its modules without `MODULE` does not subscribe to that topic.
//!
//! Types are read from their definitions (`hetcomm_rosmsg::registry`: the bridge's
//! `msg_paths`, `ROS_PACKAGE_PATH`, the definitions shipped with hetcomm), converted from the
//! definition, advertised with the MD5 sum and full definition computed from it.
//!
//! Bad input never reaches a module: a message that does not deserialize as the mapped type,
//! and a publisher on a mapped topic whose type is another (ROS 1 refuses its connection at
//! the handshake, for its MD5 sum, for every shipped type: see `types`; the bridge asks the
//! master who publishes each mapped topic and each publisher's `getPublications` for its
//! type), are counted (dropped frames in the link's stats) and described in
//! [`Ros1Bridge::problems`], each problem printed once to stderr. Plain ROS messages are unauthenticated: the transport must say
//! `security = "none"`.

mod settings;
mod subscribers;
mod types;

use parking_lot::Mutex;
use std::collections::BTreeSet;
use std::sync::Arc;
use std::time::Duration;

use subscribers::{Calls, Published};

use hetcomm_config::{Fleet, SettingsReader, TransportKind};
use hetcomm_core::{ModuleId, SystemId};
use hetcomm_link::registry::OpenFailure;
use hetcomm_link::{FrameSink, Link, LinkCaps, LinkError, LinkStats, Peer};
use hetcomm_rosmsg::bridge::{caps, hosts, module_id, robot_id, FrameMaker, Outbound, Tally};
use hetcomm_rosmsg::bridge::{BridgeFactory, BridgeKind};
use hetcomm_rosmsg::codec::Wire;
use hetcomm_rosmsg::schema::Flavour;
use roslibrust::ros1::{NodeHandle, PublisherAny};
use tokio::sync::mpsc;

pub use settings::{check_topic, BridgeSettings, Mapping, KEYS};
pub use types::{description, md5_checked, Description};

use crate::xmlrpc;

/// The kind's name in fleet files: `kind = "ros1_bridge"`.
pub fn kind() -> TransportKind {
    TransportKind::new(Ros1BridgeKind::NAME)
}

/// How often the bridge asks the master who publishes its subscribed topics.
const CHECK_INTERVAL: Duration = Duration::from_millis(500);
/// Longest wait for one XML-RPC call of that check.
const CALL_TIMEOUT: Duration = Duration::from_secs(1);
/// Queue size of each ROS publisher and subscriber (messages).
const ROS_QUEUE: usize = 64;
/// Messages `send` can queue for the publishing task before it reports congestion.
const SEND_QUEUE: usize = 1024;
/// Longest time `open` waits for the master.
const OPEN_TIMEOUT: Duration = Duration::from_secs(3);

/// An inbound mapping, as its receive task sees it.
struct Inbound {
    mapping: Mapping,
    module: ModuleId,
}

/// A link to an external ROS 1 robot through typed topics.
pub struct Ros1Bridge {
    /// Each publish mapping with the index of its publisher.
    outbound: Outbound<usize>,
    /// To the publishing task: (index of the publisher, TCPROS-framed message).
    publish: mpsc::Sender<(usize, Vec<u8>)>,
    /// What is known of each published topic's subscribers, by publisher index.
    published: Arc<Vec<Published>>,
    calls: Arc<Calls>,
    connect_timeout: Duration,
    tally: Arc<Tally>,
    /// The runtime (one thread: see [`subscribers`]), driven by `driver` until `stop` fires.
    runtime: Option<Arc<tokio::runtime::Runtime>>,
    handle: tokio::runtime::Handle,
    driver: Option<(
        tokio::sync::oneshot::Sender<()>,
        std::thread::JoinHandle<()>,
    )>,
    node: Option<NodeHandle>,
}

impl Ros1Bridge {
    /// Opens the bridge on system `local` of `fleet` with `settings`: registers a ROS node
    /// with the master, advertises every published topic and subscribes to every subscribed
    /// one (received messages go to `sink`).
    pub fn open(
        fleet: &Fleet,
        local: SystemId,
        settings: &BridgeSettings,
        sink: Arc<dyn FrameSink>,
    ) -> Result<Ros1Bridge, OpenFailure> {
        let robot = robot_id(fleet, local, &settings.robot, Flavour::Ros1)?;
        let mut inbound = Vec::new();
        // The subscribed topics this system reads: those whose module it hosts.
        let mut read = Vec::new();
        for m in &settings.subscribe {
            let module = module_id(fleet, &m.module, &m.topic)?;
            if !hosts(fleet, local, module) {
                continue;
            }
            read.push(m.clone());
            inbound.push(Inbound {
                mapping: m.clone(),
                module,
            });
        }
        let mut outbound = Outbound::new("ros1_bridge", robot, &settings.robot, Wire::Ros1);
        for (index, m) in settings.publish.iter().enumerate() {
            outbound.insert(module_id(fleet, &m.module, &m.topic)?, m.clone(), index);
        }
        // One thread: see `subscribers` for why.
        let runtime = tokio::runtime::Builder::new_current_thread()
            .enable_all()
            .build()?;
        let tally = Arc::new(Tally::new("ros1_bridge"));
        let node_name = format!(
            "/hetcomm_bridge_{}_{}_{}",
            settings.robot,
            std::process::id(),
            rand::random::<u16>()
        );
        let uri = settings.master_uri.clone();
        let opened = runtime.block_on(async {
            tokio::time::timeout(OPEN_TIMEOUT, async {
                let node = NodeHandle::new(&uri, &node_name)
                    .await
                    .map_err(|e| format!("the ROS master at {uri}: {e}"))?;
                let node_uri = node
                    .get_client_uri()
                    .await
                    .map_err(|e| format!("the bridge's node URI: {e}"))?;
                let mut publishers = Vec::new();
                for m in &settings.publish {
                    let d = description(m.schema);
                    types::check_advertised_md5(&d)?;
                    let p = node
                        .advertise_any(&m.topic, d.ros_type_name, d.definition, ROS_QUEUE, false)
                        .await
                        .map_err(|e| format!("advertising {}: {e}", m.topic))?;
                    publishers.push(p);
                }
                Ok::<_, String>((node, node_uri, publishers))
            })
            .await
            .unwrap_or_else(|_| {
                Err(format!(
                    "the ROS master at {uri} did not answer within {OPEN_TIMEOUT:?} (is \
                     `rosmaster --core` running? check the transport's `master_uri`)"
                ))
            })
        });
        let (node, node_uri, publishers) = match opened {
            Ok(o) => o,
            Err(e) => {
                runtime.shutdown_timeout(Duration::from_millis(500));
                return Err(e.into());
            }
        };
        let (tx_frames, mut rx_frames) = mpsc::channel::<Vec<u8>>(ROS_QUEUE);
        let frames = Arc::new(Mutex::new(FrameMaker::new(local, robot)));
        let subscribed = runtime.block_on(async {
            for inb in inbound {
                let (maker, frames, tally) = (frames.clone(), tx_frames.clone(), tally.clone());
                types::subscribe(&node, inb, ROS_QUEUE, maker, frames, tally).await?;
            }
            Ok::<_, String>(())
        });
        if let Err(e) = subscribed {
            {
                // roslibrust unregisters a dropped node from within the runtime.
                let _guard = runtime.enter();
                drop(node);
            }
            runtime.shutdown_timeout(Duration::from_millis(500));
            return Err(e.into());
        }
        drop(tx_frames);
        // Frames reach the sink on a thread of their own, as the `ros1` link's do.
        std::thread::Builder::new()
            .name(format!("hetcomm-ros1-bridge-{}", settings.robot))
            .spawn(move || {
                while let Some(frame) = rx_frames.blocking_recv() {
                    sink.on_frame(&frame, Peer::System(robot));
                }
            })?;
        let (publish, publish_rx) = mpsc::channel(SEND_QUEUE);
        let published: Arc<Vec<Published>> = Arc::new(
            settings
                .publish
                .iter()
                .map(|m| Published::new(&m.topic))
                .collect(),
        );
        let calls = Arc::new(Calls {
            http: reqwest::Client::new(),
            master: settings.master_uri.clone(),
            me: node_name,
            uri: node_uri,
        });
        runtime.spawn(publish_loop(publishers, publish_rx));
        runtime.spawn(check_topics(
            calls.clone(),
            read,
            published.clone(),
            tally.clone(),
        ));
        let runtime = Arc::new(runtime);
        let (stop, stopped) = tokio::sync::oneshot::channel::<()>();
        let driven = runtime.clone();
        let driver = std::thread::Builder::new()
            .name(format!("hetcomm-ros1-bridge-rt-{}", settings.robot))
            .spawn(move || {
                let _ = driven.block_on(stopped);
            })?;
        Ok(Ros1Bridge {
            outbound,
            publish,
            published,
            calls,
            connect_timeout: Duration::from_millis(settings.connect_timeout_ms),
            tally,
            handle: runtime.handle().clone(),
            runtime: Some(runtime),
            driver: Some((stop, driver)),
            node: Some(node),
        })
    }

    /// The problems seen with input from ROS (messages that do not deserialize, publishers
    /// of another type on a mapped topic), each once.
    pub fn problems(&self) -> Vec<String> {
        self.tally.problems()
    }
}

async fn publish_loop(publishers: Vec<PublisherAny>, mut rx: mpsc::Receiver<(usize, Vec<u8>)>) {
    while let Some((index, framed)) = rx.recv().await {
        if let Some(p) = publishers.get(index) {
            // The outcome is already Sent (without confirmation); ROS 1 says nothing more.
            let _ = p.publish(framed).await;
        }
    }
}

/// Asks the master every [`CHECK_INTERVAL`] who is on the bridge's topics: reports
/// publishers on a subscribed topic whose type is not the mapped one (ROS 1 refuses their
/// connection, MD5 mismatch, so their messages would otherwise vanish without a word; each
/// publishing node is asked once per topic), and has the next send on a published topic wait
/// again when its subscribers changed.
async fn check_topics(
    calls: Arc<Calls>,
    subscribed: Vec<Mapping>,
    published: Arc<Vec<Published>>,
    tally: Arc<Tally>,
) {
    let (http, master, me) = (&calls.http, &calls.master, &calls.me);
    let mut checked = BTreeSet::new();
    loop {
        tokio::time::sleep(CHECK_INTERVAL).await;
        let args = vec![me.clone().into()];
        let Ok(state) = xmlrpc::call(http, master, "getSystemState", args, CALL_TIMEOUT).await
        else {
            continue;
        };
        let graph = xmlrpc::Graph::from_value(&state);
        for p in published.iter() {
            p.recheck(&graph, me);
        }
        for m in &subscribed {
            for node in graph.publishers(&m.topic) {
                if checked.contains(&(m.topic.clone(), node.clone())) {
                    continue;
                }
                let args = vec![me.clone().into(), node.clone().into()];
                let Ok(serde_xmlrpc::Value::String(uri)) =
                    xmlrpc::call(http, master, "lookupNode", args, CALL_TIMEOUT).await
                else {
                    continue;
                };
                let args = vec![me.clone().into()];
                let Ok(pubs) =
                    xmlrpc::call(http, &uri, "getPublications", args, CALL_TIMEOUT).await
                else {
                    continue;
                };
                checked.insert((m.topic.clone(), node.clone()));
                match xmlrpc::publication_type(&pubs, &m.topic) {
                    Some(ty) if ty != m.ros_type() && types::md5_checked(m.schema) => tally
                        .dropped_once(format!(
                            "a publisher on {} ({node}) has type {ty}, but the topic is mapped \
                             as {}: ROS 1 refuses its connection (MD5 sum mismatch), its \
                             messages are not received",
                            m.topic,
                            m.ros_type()
                        )),
                    // Subscribed with any MD5 sum: its messages arrive and are checked one
                    // by one against the definition.
                    Some(ty) if ty != m.ros_type() => tally.dropped_once(format!(
                        "a publisher on {} ({node}) has type {ty}, but the topic is mapped \
                         as {} (a definition read at run time, subscribed to with any MD5 \
                         sum): its messages are dropped where they do not read as {}, and \
                         may be taken for it where they do",
                        m.topic,
                        m.ros_type(),
                        m.ros_type()
                    )),
                    _ => {}
                }
            }
        }
    }
}

impl Link for Ros1Bridge {
    /// True: the frames the router sends are read, and the frames it receives are made,
    /// in this process (`hetcomm_rosmsg::bridge::FrameMaker`); only their headers need a CRC.
    fn checksums_payload(&self) -> bool {
        true
    }

    fn caps(&self) -> LinkCaps {
        caps()
    }

    fn send(&self, to: SystemId, frame: &[u8]) -> Result<(), LinkError> {
        let Some(out) = self.outbound.convert(to, frame)? else {
            return Ok(());
        };
        let (m, index, body) = (out.mapping, *out.publisher, out.body);
        self.wait_subscribers(to, index)?;
        // TCPROS frames each message with its length.
        let mut framed = Vec::with_capacity(body.len() + 4);
        framed.extend_from_slice(&(body.len() as u32).to_le_bytes());
        framed.extend_from_slice(&body);
        match self.publish.try_send((index, framed)) {
            Ok(()) => {
                self.published[index].count();
                self.tally.sent();
                Ok(())
            }
            Err(mpsc::error::TrySendError::Full(_)) => Err(LinkError::Congested {
                peer: to,
                reason: format!("the publishing queue of {} is full", m.topic),
            }),
            Err(mpsc::error::TrySendError::Closed(_)) => Err(LinkError::Unreachable {
                peer: to,
                reason: "the bridge is closing".into(),
            }),
        }
    }

    fn stats(&self) -> LinkStats {
        self.tally.stats()
    }
}

impl Ros1Bridge {
    /// Waits (at most the connect timeout) until the subscribers of publisher `index`'s topic
    /// are connected, unless they were at the last send and have not changed since.
    fn wait_subscribers(&self, to: SystemId, index: usize) -> Result<(), LinkError> {
        let p = &self.published[index];
        if p.ready() {
            return Ok(());
        }
        let _gate = p.gate();
        if p.ready() {
            return Ok(());
        }
        let (tx, rx) = std::sync::mpsc::channel();
        let (calls, published, timeout) = (
            self.calls.clone(),
            self.published.clone(),
            self.connect_timeout,
        );
        self.handle.spawn(async move {
            let _ = tx.send(calls.wait(&published[index], timeout).await);
        });
        // The task ends by its own deadline; the margin only covers a runtime that is gone.
        match rx.recv_timeout(timeout + Duration::from_secs(2)) {
            Ok(Ok(())) => Ok(()),
            Ok(Err(reason)) => Err(LinkError::Unreachable { peer: to, reason }),
            Err(_) => Err(LinkError::Closed),
        }
    }

    /// Waits (at most the connect timeout) until what was queued is published and read by
    /// the subscribers found connected.
    fn flush(&self) {
        let (tx, rx) = std::sync::mpsc::channel();
        let (calls, published, timeout) = (
            self.calls.clone(),
            self.published.clone(),
            self.connect_timeout,
        );
        let publish = self.publish.clone();
        self.handle.spawn(async move {
            // The publishing task has taken everything queued before this marker's room.
            let _ = tokio::time::timeout(timeout, publish.reserve_many(SEND_QUEUE)).await;
            for p in published.iter() {
                calls.flush(p, timeout).await;
            }
            let _ = tx.send(());
        });
        let _ = rx.recv_timeout(timeout * 2 + Duration::from_secs(1));
    }
}

impl Drop for Ros1Bridge {
    fn drop(&mut self) {
        self.flush();
        let (Some(runtime), node) = (self.runtime.take(), self.node.take()) else {
            return;
        };
        if let Some((stop, driver)) = self.driver.take() {
            let _ = stop.send(());
            let _ = driver.join();
        }
        // On a plain thread: this may run inside another async runtime, where blocking on
        // ours is not allowed; roslibrust unregisters a dropped node with blocking calls.
        let shutdown = std::thread::Builder::new()
            .name("hetcomm-ros1-bridge-close".into())
            .spawn(move || {
                {
                    let _guard = runtime.enter();
                    drop(node);
                }
                if let Ok(runtime) = Arc::try_unwrap(runtime) {
                    runtime.shutdown_timeout(Duration::from_secs(1));
                }
            });
        if let Ok(handle) = shutdown {
            let _ = handle.join();
        }
    }
}

/// The `ros1_bridge` kind, registered as a [`BridgeFactory`] ([`Ros1BridgeFactory`]).
pub struct Ros1BridgeKind;

/// Reads `ros1_bridge` tables and opens them as [`Ros1Bridge`]s.
pub type Ros1BridgeFactory = BridgeFactory<Ros1BridgeKind>;

impl BridgeKind for Ros1BridgeKind {
    type Settings = BridgeSettings;
    const NAME: &'static str = "ros1_bridge";
    const KEYS: &'static [&'static str] = &KEYS;

    fn parse(s: &mut SettingsReader<'_, '_>) -> Option<BridgeSettings> {
        settings::parse(s)
    }

    fn robot(settings: &BridgeSettings) -> &str {
        &settings.robot
    }

    fn mappings(settings: &BridgeSettings) -> (&[Mapping], &[Mapping]) {
        (&settings.publish, &settings.subscribe)
    }

    fn open(
        fleet: &Fleet,
        local: SystemId,
        settings: &BridgeSettings,
        sink: Arc<dyn FrameSink>,
    ) -> Result<(Arc<dyn Link>, String), OpenFailure> {
        let bridge = Ros1Bridge::open(fleet, local, settings, sink)?;
        let address = format!(
            "ros1_bridge://{}/{}",
            settings.master_uri.trim_start_matches("http://"),
            settings.robot
        );
        Ok((Arc::new(bridge), address))
    }
}

//! The subscribers of the bridge's published topics: a send waits (at most the bridge's
//! `connect_timeout_ms`) until the subscribers the master lists have their connection from the
//! bridge made, and a closing bridge waits until they have read what it published.
//!
//! roslibrust's publisher answers a subscriber's TCPROS header and only then starts that
//! connection's writer, which takes the messages published from then on: a message published
//! before the subscriber connected, or between its handshake and the writer's start, reaches
//! nobody. The bridge therefore asks each subscriber (rospy, roscpp: `getBusInfo`) whether its
//! connection from the bridge's node has finished its handshake, and its runtime has one
//! thread: roslibrust answers the header and starts the writer in one step of one task, so
//! once the subscriber has read the header, no message of the bridge (published from the same
//! thread) can fall between the two. A closing bridge asks each subscriber's `getBusStats`
//! how many messages its connection read, until it has read every one published since it was
//! found connected (roslibrust writes from queues of its own, which a process that exits at
//! once would lose).

use parking_lot::Mutex;
use std::collections::BTreeSet;
use std::sync::atomic::{AtomicBool, AtomicU64, Ordering};
use std::time::{Duration, Instant};

use crate::xmlrpc::{self, Graph};

/// How often a waiting send asks again.
const POLL: Duration = Duration::from_millis(20);
/// How long a closing bridge gives a subscriber that cannot say what it read (a node without
/// `getBusStats`, such as roslibrust's) to read what was published.
const UNCHECKED_GRACE: Duration = Duration::from_millis(50);

/// A subscriber found connected to one of the bridge's publishers.
#[derive(Clone, Debug)]
struct Connected {
    /// Its node name.
    node: String,
    /// Its XML-RPC URI.
    uri: String,
    /// Its connection's id in its `getBusInfo`; None when it cannot be asked (a node without
    /// `getBusInfo`: it is taken as connected).
    connection: Option<i64>,
    /// Messages published on the topic before it was found connected.
    since: u64,
}

/// One published topic and what the bridge knows of its subscribers.
pub(super) struct Published {
    topic: String,
    /// Every subscriber the master listed at the last wait was connected, and the list has
    /// not changed since: sends do not wait.
    ready: AtomicBool,
    connected: Mutex<Vec<Connected>>,
    /// Messages queued for the topic.
    published: AtomicU64,
    /// Held by the one send that waits.
    gate: Mutex<()>,
}

impl Published {
    /// A topic nobody was found subscribed to yet.
    pub(super) fn new(topic: &str) -> Published {
        Published {
            topic: topic.to_string(),
            ready: AtomicBool::new(false),
            connected: Mutex::new(Vec::new()),
            published: AtomicU64::new(0),
            gate: Mutex::new(()),
        }
    }

    /// Whether sends go without waiting.
    pub(super) fn ready(&self) -> bool {
        self.ready.load(Ordering::Acquire)
    }

    /// Held while one send waits, so that the others wait for its result.
    pub(super) fn gate(&self) -> parking_lot::MutexGuard<'_, ()> {
        self.gate.lock()
    }

    /// One message queued for the topic.
    pub(super) fn count(&self) {
        self.published.fetch_add(1, Ordering::Relaxed);
    }

    fn connected(&self) -> Vec<Connected> {
        self.connected.lock().clone()
    }

    /// Forgets that the subscribers are connected when the master's list of them is not the
    /// one found connected (a subscriber came or went): the next send waits for them again.
    pub(super) fn recheck(&self, graph: &Graph, me: &str) {
        if !self.ready() {
            return;
        }
        let now: BTreeSet<String> = others(graph, &self.topic, me).into_iter().collect();
        let then: BTreeSet<String> = self.connected().into_iter().map(|c| c.node).collect();
        if now != then {
            self.ready.store(false, Ordering::Release);
        }
    }
}

/// The subscribers of `topic` the master lists, the bridge's own node left out.
fn others(graph: &Graph, topic: &str, me: &str) -> Vec<String> {
    graph
        .subscribers(topic)
        .into_iter()
        .filter(|n| n != me)
        .collect()
}

/// The bridge's node as other nodes know it, and how it calls them.
pub(super) struct Calls {
    pub(super) http: reqwest::Client,
    pub(super) master: String,
    /// The bridge's node name.
    pub(super) me: String,
    /// The bridge's node's XML-RPC URI (subscribers name their publishers by it).
    pub(super) uri: String,
}

impl Calls {
    /// `node`'s connection from us on `topic`, if its handshake is done (None: not yet, or
    /// the node did not answer).
    async fn connection(
        &self,
        node: &str,
        topic: &str,
        timeout: Duration,
        since: u64,
    ) -> Option<Connected> {
        let args = vec![self.me.clone().into(), node.to_string().into()];
        let Ok(serde_xmlrpc::Value::String(uri)) =
            xmlrpc::call(&self.http, &self.master, "lookupNode", args, timeout).await
        else {
            return None;
        };
        let args = vec![self.me.clone().into()];
        let connection = match xmlrpc::call(&self.http, &uri, "getBusInfo", args, timeout).await {
            Ok(info) => Some(xmlrpc::inbound_connection(&info, topic, &self.uri)?),
            // A node that cannot say (roslibrust's answers 501): taken as connected.
            Err(e) if e.http_status == Some(501) => None,
            Err(_) => return None,
        };
        Some(Connected {
            node: node.to_string(),
            uri,
            connection,
            since,
        })
    }

    /// Waits, at most `timeout`, until every subscriber of `p`'s topic that the master lists
    /// has its connection from us made; then sends to it go without waiting. Fine if at
    /// least one is connected by then (the others get what is published once they are); the
    /// reason if none is, and nothing may be published.
    pub(super) async fn wait(&self, p: &Published, timeout: Duration) -> Result<(), String> {
        let deadline = Instant::now() + timeout;
        let topic = &p.topic;
        let mut listed: Option<Vec<String>> = None;
        let mut problem = None;
        let mut found: Vec<Connected> = Vec::new();
        loop {
            let left = deadline
                .saturating_duration_since(Instant::now())
                .max(Duration::from_millis(1));
            let args = vec![self.me.clone().into()];
            match xmlrpc::call(&self.http, &self.master, "getSystemState", args, left).await {
                Ok(state) => {
                    let subscribers = others(&Graph::from_value(&state), topic, &self.me);
                    let since = p.published.load(Ordering::Relaxed);
                    found.clear();
                    for node in &subscribers {
                        if let Some(c) = self.connection(node, topic, left, since).await {
                            found.push(c);
                        }
                    }
                    let all = !subscribers.is_empty() && found.len() == subscribers.len();
                    listed = Some(subscribers);
                    if all {
                        break;
                    }
                }
                Err(e) => problem = Some(e.to_string()),
            }
            let left = deadline.saturating_duration_since(Instant::now());
            if left.is_zero() {
                break;
            }
            tokio::time::sleep(POLL.min(left)).await;
        }
        if found.is_empty() {
            let ms = timeout.as_millis();
            return Err(match (listed, problem) {
                (Some(l), _) if l.is_empty() => {
                    format!("no node subscribes to {topic} (waited {ms} ms; nothing was published)")
                }
                (Some(l), _) => format!(
                    "the subscribers of {topic} ({}) did not connect within {ms} ms (nothing \
                     was published)",
                    l.join(", ")
                ),
                (None, p) => format!(
                    "the ROS master did not say who subscribes to {topic} within {ms} ms{} \
                     (nothing was published)",
                    p.map(|p| format!(": {p}")).unwrap_or_default()
                ),
            });
        }
        *p.connected.lock() = found;
        p.ready.store(true, Ordering::Release);
        Ok(())
    }

    /// Waits, at most `timeout`, until every subscriber found connected to `p`'s publisher has
    /// read every message published on it since.
    pub(super) async fn flush(&self, p: &Published, timeout: Duration) {
        let deadline = Instant::now() + timeout;
        let total = p.published.load(Ordering::Relaxed);
        for c in p.connected() {
            if total <= c.since {
                continue;
            }
            let expected = (total - c.since) as i64;
            let Some(id) = c.connection else {
                tokio::time::sleep(UNCHECKED_GRACE).await;
                continue;
            };
            loop {
                let left = deadline.saturating_duration_since(Instant::now());
                if left.is_zero() {
                    return;
                }
                let args = vec![self.me.clone().into()];
                match xmlrpc::call(&self.http, &c.uri, "getBusStats", args, left).await {
                    Ok(stats) => {
                        let read = xmlrpc::messages_read(&stats, &p.topic, id);
                        // Gone from its stats: the connection closed, nothing more to wait for.
                        if read.is_none_or(|n| n >= expected) {
                            break;
                        }
                    }
                    Err(_) => {
                        tokio::time::sleep(UNCHECKED_GRACE.min(left)).await;
                        break;
                    }
                }
                tokio::time::sleep(Duration::from_millis(5).min(left)).await;
            }
        }
    }
}

//! Waiting for a destination's subscriber before the first frame goes to it: probes to
//! hetcomm peers, `getBusInfo` for foreign nodes.

use super::*;

impl Shared {
    pub(super) fn identity(&self) -> Identity {
        self.identity.lock().clone()
    }

    /// Asks the master who subscribes to what.
    pub(super) async fn graph(&self, timeout: Duration) -> Result<xmlrpc::Graph, String> {
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
            *self.graph_cache.lock() = Some((Instant::now(), Arc::new(graph.clone())));
            graph
        })
    }

    /// The master's last answer, if it is recent (one supervision interval).
    pub(super) fn cached_graph(&self) -> Option<Arc<xmlrpc::Graph>> {
        let cache = self.graph_cache.lock();
        let (at, graph) = cache.as_ref()?;
        (at.elapsed() <= self.plan.config.supervise_interval).then(|| graph.clone())
    }

    /// Whether `node`'s `getBusInfo` lists an inbound connection on `topic` from our node;
    /// None if the node does not implement `getBusInfo` (a roslibrust node, such as a hetcomm
    /// link: it answers probes instead), which is remembered.
    pub(super) async fn bus_info_connected(
        &self,
        node: &str,
        topic: &str,
        timeout: Duration,
    ) -> Option<bool> {
        if self.without_bus_info.lock().contains(node) {
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
                let mut without = self.without_bus_info.lock();
                without.insert(node.to_string());
                None
            }
            Err(_) => Some(false),
        }
    }
}

/// How often a waiting send asks the master again who subscribes to the destination's topic.
pub(super) const GRAPH_REFRESH: Duration = Duration::from_millis(100);

/// Waits until `to`'s subscriber is connected to our publisher on its topic (see the crate
/// docs), at most `timeout`. Returns the topic's subscribers then (as last seen), or why it
/// gave up.
///
/// The master is not on the critical path of a hetcomm destination: the link probes at once
/// (and every probe interval) unless the master is known to list only foreign subscribers,
/// while it asks the master in the background who subscribes (a loaded master may take
/// longer than the whole timeout to answer).
pub(super) async fn wait_connected(
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
    shared.wiring.pending.lock().insert(nonce, (to, wake));
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
                (Some(s), _) if ours => {
                    if let Some(dest) = shared.wiring.dests.get(&to) {
                        dest.mark_unanswered();
                    }
                    format!(
                        "subscribed by {}; no answer to the connection probe",
                        s.join(", ")
                    )
                }
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
    shared.wiring.pending.lock().remove(&nonce);
    outcome.map(|()| subscribers.unwrap_or_default())
}

/// Probes `to` and waits (at most `timeout`) for the answer, which comes after everything
/// queued before the probe was read. A destination with no hetcomm subscriber answers no
/// probe: it gets [`FOREIGN_FLUSH_GRACE`] instead.
pub(super) async fn wait_answer(shared: Arc<Shared>, to: SystemId, timeout: Duration) {
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
    pending.lock().insert(nonce, (to, wake));
    if shared
        .wiring
        .commands
        .send(Command::Probe(to, nonce))
        .await
        .is_ok()
    {
        let _ = tokio::time::timeout(timeout, answered).await;
    }
    pending.lock().remove(&nonce);
}

//! The link's background tasks on its runtime: receiving frames and probes, publishing,
//! and supervising the registration (master restarts, `rosnode kill`, new peers).

use super::*;

/// A probe or a probe's answer, if `msg` is one.
pub(super) fn control(msg: &UInt8MultiArray) -> Option<(&str, u32, SystemId)> {
    if !msg.data.is_empty() {
        return None;
    }
    let d = msg.layout.dim.first()?;
    let from = SystemId(u16::try_from(d.stride).ok()?);
    Some((d.label.as_str(), d.size, from))
}

pub(super) async fn receive_loop(
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
                    let mut pending = wiring.pending.lock();
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
                        *dest.subscribers.lock() = None;
                        dest.connected.store(true, Ordering::Release);
                        dest.clear_unanswered();
                        wiring.set_presence(from, true);
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

/// An empty message whose layout carries a probe or an answer.
pub(super) fn control_message(label: &str, nonce: u32, from: SystemId) -> UInt8MultiArray {
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

/// Owns the current registration and publishes queued frames.
pub(super) async fn publish_loop(
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

/// How long a closing link gives its publishers to write frames to a destination that
/// answers no probes.
pub(super) const FOREIGN_FLUSH_GRACE: Duration = Duration::from_millis(50);

/// How long a destination's hetcomm subscriber, listed by the master and alive (its node
/// answers `getPid`), may leave our probes unanswered before the link re-registers.
///
/// roslibrust's publishers take subscribers one at a time, reading each one's TCPROS header
/// without a time limit, and its subscribers ask a publisher for its TCP endpoint without one
/// either: one connection that never sends its header (or a stale `publisherUpdate` that
/// reaches a node that reused a dead node's port) leaves a pair of live nodes unconnected for
/// good, and sends to that destination would fail forever. A new registration has new
/// listening ports and a subscriber that gets the current publishers from the master's answer,
/// so the connection is made afresh. Repeated re-registrations back off (doubling up to
/// [`HEAL_BACKOFF_MAX`]) while the destination keeps not answering.
pub(super) const HEAL_AFTER: Duration = Duration::from_secs(3);

/// Longest pause between re-registrations for a destination that keeps not answering.
pub(super) const HEAL_BACKOFF_MAX: Duration = Duration::from_secs(60);

/// Checks the master periodically; re-registers when it lost our registration, or when a live
/// destination has answered no probe for [`HEAL_AFTER`], and forgets the connection of
/// destinations whose subscribers changed.
pub(super) async fn supervise_loop(shared: Arc<Shared>) {
    let plan = &shared.plan;
    let mut tick = tokio::time::interval(plan.config.supervise_interval);
    tick.set_missed_tick_behavior(tokio::time::MissedTickBehavior::Delay);
    tick.tick().await;
    let mut heal_backoff = HEAL_AFTER;
    let mut heal_not_before = Instant::now();
    loop {
        tick.tick().await;
        let node_name = shared.identity().node_name;
        let new_state = match shared.graph(plan.config.master_call_timeout).await {
            Err(e) => MasterState::Unreachable(e),
            Ok(graph) if graph.subscribers(&plan.own_topic).contains(&node_name) => {
                for (to, dest) in &shared.wiring.dests {
                    let now = relevant(graph.subscribers(&plan.peer_topics[to]));
                    if now.is_empty() {
                        // Its node unregistered (or its master lost it): down until it is
                        // connected again.
                        dest.connected.store(false, Ordering::Release);
                        shared.wiring.set_presence(*to, false);
                        continue;
                    }
                    if !dest.connected.load(Ordering::Acquire) {
                        continue;
                    }
                    let mut then = dest.subscribers.lock();
                    match &*then {
                        None => *then = Some(now),
                        Some(then) if *then != now => {
                            dest.connected.store(false, Ordering::Release)
                        }
                        Some(_) => {}
                    }
                }
                let stuck: Vec<SystemId> = shared
                    .wiring
                    .dests
                    .iter()
                    .filter(|(_, d)| {
                        d.unanswered_for(HEAL_AFTER)
                            .is_some_and(|t| t >= HEAL_AFTER)
                    })
                    .map(|(&to, _)| to)
                    .collect();
                if stuck.is_empty() {
                    heal_backoff = HEAL_AFTER;
                    MasterState::Registered
                } else if Instant::now() >= heal_not_before
                    && any_alive(&shared, &graph, &stuck).await
                {
                    heal_not_before = Instant::now() + heal_backoff;
                    heal_backoff = (heal_backoff * 2).min(HEAL_BACKOFF_MAX);
                    match reregister(&shared).await {
                        Some(state) => state,
                        None => return,
                    }
                } else {
                    MasterState::Registered
                }
            }
            // The master answers but does not know us: it was restarted. Register anew.
            Ok(_) => match reregister(&shared).await {
                Some(state) => state,
                None => return,
            },
        };
        *shared.master.lock() = new_state;
    }
}

/// Whether a hetcomm subscriber of one of `systems`' topics is a running node (its XML-RPC
/// server answers `getPid`): a stale registration of a node that died needs no new
/// registration of ours.
async fn any_alive(shared: &Shared, graph: &xmlrpc::Graph, systems: &[SystemId]) -> bool {
    let plan = &shared.plan;
    let timeout = plan.config.master_call_timeout;
    let me = shared.identity().node_name;
    for to in systems {
        let topic = &plan.peer_topics[to];
        let name = topic.rsplit('/').next().unwrap_or_default();
        let prefix = format!("{NODE_PREFIX}{name}_");
        for node in graph.subscribers(topic) {
            if !node.starts_with(&prefix) {
                continue;
            }
            let http = &shared.wiring.http;
            let args = vec![me.clone().into(), node.clone().into()];
            let Ok(serde_xmlrpc::Value::String(uri)) =
                xmlrpc::call(http, &plan.master_uri, "lookupNode", args, timeout).await
            else {
                continue;
            };
            let args = vec![me.clone().into()];
            if xmlrpc::call(http, &uri, "getPid", args, timeout)
                .await
                .is_ok()
            {
                return true;
            }
        }
    }
    false
}

/// Registers a new node and has the publishing task swap it in (the old one is retired);
/// the resulting state, or None if the link is closing.
async fn reregister(shared: &Shared) -> Option<MasterState> {
    let plan = &shared.plan;
    let state = match tokio::time::timeout(
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
                return None;
            }
            shared.wiring.forget_all();
            *shared.identity.lock() = identity;
            MasterState::Registered
        }
        Ok(Err(e)) => MasterState::Reregistering(e.to_string()),
        Err(_) => {
            MasterState::Reregistering(format!("no answer within {:?}", plan.config.open_timeout))
        }
    };
    Some(state)
}

/// Waits, all at once and at most the connect timeout, for the subscribers of the peers that
/// the master lists as running (subscribed to their topic), so that the first sends to them
/// need not wait. Peers that do not connect in time are left to the sends (which wait again
/// and fail with the reason).
pub(super) async fn connect_running_peers(shared: Arc<Shared>) {
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

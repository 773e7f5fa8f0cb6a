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

/// Checks the master periodically; re-registers when it lost our registration, and forgets
/// the connection of destinations whose subscribers changed.
pub(super) async fn supervise_loop(shared: Arc<Shared>) {
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

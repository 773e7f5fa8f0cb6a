//! Registering a link's node with the master: its publishers and subscriber, and
//! retiring an old registration.

use super::*;

impl Wiring {
    /// Records that `to`'s subscriber is connected (`subscribers`: the topic's subscribers).
    pub(super) fn settle(&self, to: SystemId, subscribers: Vec<String>) {
        if let Some(dest) = self.dests.get(&to) {
            *dest.subscribers.lock() = Some(relevant(subscribers));
            dest.connected.store(true, Ordering::Release);
            dest.clear_unanswered();
            self.set_presence(to, true);
        }
    }

    /// Tells the sink (through the receive thread) that `to` is up (its subscriber connected
    /// to us) or down (the master lists no subscriber of its topic any more: its node
    /// unregistered), if that is news.
    pub(super) fn set_presence(&self, to: SystemId, up: bool) {
        let Some(dest) = self.dests.get(&to) else {
            return;
        };
        if dest.up.swap(up, Ordering::AcqRel) == up {
            return;
        }
        let event = match up {
            true => LinkEvent::PeerUp(to),
            false => LinkEvent::PeerDown(to),
        };
        self.presence.lock().push(event);
        // Wakes the receive thread; if its queue is full, it tells the event after the frames.
        if let Some(frames) = &*self.frames.lock() {
            let _ = frames.try_send(Vec::new());
        }
    }

    /// The presence changes not told yet.
    pub(super) fn take_presence(&self) -> Vec<LinkEvent> {
        std::mem::take(&mut *self.presence.lock())
    }

    /// Forgets every connection (a new registration has new publishers), and that any
    /// destination did not answer (the new registration has not asked yet).
    pub(super) fn forget_all(&self) {
        for d in self.dests.values() {
            d.connected.store(false, Ordering::Release);
            d.clear_unanswered();
        }
    }
}

pub(super) fn node_counter() -> u64 {
    static NEXT: AtomicU64 = AtomicU64::new(0);
    NEXT.fetch_add(1, Ordering::Relaxed)
}

/// A nonce for a probe: random enough that two processes of the same system (which share a
/// topic, so both see every answer) never take each other's answers.
pub(super) fn nonce() -> u32 {
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
pub(super) async fn register(
    plan: &Plan,
    wiring: Arc<Wiring>,
    counters: Arc<Counters>,
) -> Result<Registration, Ros1OpenError> {
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
            | roslibrust::ros1::NodeError::IoError(_) => Ros1OpenError::MasterUnreachable {
                uri: uri.clone(),
                reason,
            },
            _ => Ros1OpenError::Registration {
                uri: uri.clone(),
                reason,
            },
        }
    })?;
    let registration = |what: &str, e: &dyn std::fmt::Display| Ros1OpenError::Registration {
        uri: uri.clone(),
        reason: format!("{what}: {e}"),
    };
    let client_uri = node
        .get_client_uri()
        .await
        .map_err(|e| registration("node URI", &e))?;
    let client = MasterClient::new(uri.as_str(), client_uri, node_name.as_str())
        .await
        .map_err(|e| Ros1OpenError::MasterUnreachable {
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

/// Drops a registration off the async threads: roslibrust unregisters a dropped node from the
/// master with blocking HTTP calls.
pub(super) fn retire(old: Registration) {
    drop(tokio::task::spawn_blocking(move || drop(old)));
}

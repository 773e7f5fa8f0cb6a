//! Which peers are alive: iceoryx2's node list, read every `liveness_ms`. A node of a fleet
//! system whose process died is cleaned up (its ports and segments removed) and reported
//! down; a node that appears is reported up.

use parking_lot::Mutex;
use std::collections::{HashMap, HashSet};
use std::sync::atomic::Ordering;
use std::sync::Arc;
use std::time::{Duration, Instant};

use hetcomm_core::SystemId;
use hetcomm_link::{FrameSink, LinkEvent};
use iceoryx2::node::NodeView;
use iceoryx2::prelude::*;

use crate::link::Counters;
use crate::IpcService;

struct State {
    last: Option<Instant>,
    alive: HashSet<SystemId>,
    /// Peers that died or left and have not come back.
    dead: HashSet<SystemId>,
}

/// The peers of one link as iceoryx2's node list last showed them.
pub(crate) struct Liveness {
    local: SystemId,
    /// Fleet systems by their node's name.
    names: HashMap<String, SystemId>,
    interval: Duration,
    state: Mutex<State>,
    sweeping: Mutex<()>,
    counters: Arc<Counters>,
}

impl Liveness {
    pub(crate) fn new(
        local: SystemId,
        names: HashMap<String, SystemId>,
        interval_ms: u32,
        counters: Arc<Counters>,
    ) -> Liveness {
        Liveness {
            local,
            names,
            interval: Duration::from_millis(interval_ms as u64),
            state: Mutex::new(State {
                last: None,
                alive: HashSet::new(),
                dead: HashSet::new(),
            }),
            sweeping: Mutex::new(()),
            counters,
        }
    }

    /// Whether the last look is `liveness_ms` old (and nobody else is looking).
    pub(crate) fn due(&self) -> bool {
        match self.state.try_lock() {
            Some(s) => s.last.map_or(true, |t| t.elapsed() >= self.interval),
            None => false,
        }
    }

    /// Whether `peer` was found dead or gone and has not come back.
    pub(crate) fn is_dead(&self, peer: SystemId) -> bool {
        self.state.lock().dead.contains(&peer)
    }

    /// Lists the nodes: cleans up the fleet's dead ones, and tells `sink` (if any) who went
    /// down and who came up since the last look.
    pub(crate) fn sweep(&self, config: &Config, sink: Option<&dyn FrameSink>) {
        // One look at a time (the reader's upkeep and a congested sender may both ask): two
        // looks racing would both find a dead node and fight over removing it.
        let _one = self.sweeping.lock();
        let mut alive = HashSet::new();
        let mut dead_nodes = Vec::new();
        let _ = Node::<IpcService>::list(config, |state| {
            match state {
                NodeState::Alive(view) => {
                    if let Some(id) = view.details().as_ref().and_then(|d| self.system(d.name())) {
                        alive.insert(id);
                    }
                }
                NodeState::Dead(view) => {
                    if let Some(id) = view.details().as_ref().and_then(|d| self.system(d.name())) {
                        dead_nodes.push((id, view));
                    }
                }
                NodeState::Inaccessible(_) | NodeState::Undefined(_) => {}
            }
            CallbackProgression::Continue
        });
        let mut died = Vec::new();
        for (id, view) in dead_nodes {
            // Dead either way. A removal that fails (another look, or iceoryx2 itself while a
            // port of ours updated its connections, got there first; or another user's files)
            // is counted apart.
            self.counters.peers_died.fetch_add(1, Ordering::Relaxed);
            died.push(id);
            if view.try_remove_stale_resources().is_err() {
                self.counters
                    .cleanups_failed
                    .fetch_add(1, Ordering::Relaxed);
            }
        }
        let mut s = self.state.lock();
        s.last = Some(Instant::now());
        let mut events = Vec::new();
        for id in died.into_iter().filter(|id| *id != self.local) {
            // An old corpse of a peer already back up (its removal still pending) says
            // nothing new; nor does one already reported.
            let back = alive.contains(&id) && s.alive.contains(&id);
            if !back && s.dead.insert(id) {
                events.push(LinkEvent::PeerDown(id));
            }
        }
        // Gone from the list: closed, or dead and already cleaned up by another process (any
        // iceoryx2 process removes dead nodes it comes across). Down either way.
        let vanished: Vec<SystemId> = s.alive.difference(&alive).copied().collect();
        for id in vanished {
            if id != self.local && !events.contains(&LinkEvent::PeerDown(id)) {
                s.dead.insert(id);
                events.push(LinkEvent::PeerDown(id));
            }
        }
        for id in alive.difference(&s.alive.clone()) {
            if *id != self.local {
                s.dead.remove(id);
                self.counters.connects.fetch_add(1, Ordering::Relaxed);
                events.push(LinkEvent::PeerUp(*id));
            }
        }
        // A peer that died and was restarted between two looks: down, then up again.
        for id in &alive {
            if events.contains(&LinkEvent::PeerDown(*id))
                && !events.contains(&LinkEvent::PeerUp(*id))
            {
                s.dead.remove(id);
                events.push(LinkEvent::PeerUp(*id));
            }
        }
        s.alive = alive;
        drop(s);
        if let Some(sink) = sink {
            for e in events {
                sink.on_event(e);
            }
        }
    }

    fn system(&self, name: &NodeName) -> Option<SystemId> {
        self.names.get(name.as_str()).copied()
    }
}

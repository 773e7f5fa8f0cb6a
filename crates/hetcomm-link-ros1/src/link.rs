//! [`Ros1Link`]: opening, sending, and closing.

use super::*;

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
    ) -> Result<Ros1Link, Ros1OpenError> {
        if let Some(ms) = settings.connect_timeout_ms {
            config.connect_timeout = Duration::from_millis(ms);
        }
        let namespace = settings.namespace.as_deref();
        let local_name = systems
            .get(&local)
            .ok_or(Ros1OpenError::UnknownLocalSystem { system: local })?
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
            presence: Mutex::default(),
            http: reqwest::Client::new(),
        });
        let timeout = plan.config.open_timeout;
        let registration = runtime.block_on(async {
            tokio::time::timeout(timeout, register(&plan, wiring.clone(), counters.clone()))
                .await
                .unwrap_or_else(|_| {
                    Err(Ros1OpenError::MasterUnreachable {
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
        // Frames and presence reach the sink on a thread of their own (see "Threads" in the
        // crate docs).
        let (receiver_done, receiver_ended) = std::sync::mpsc::channel();
        let told = wiring.clone();
        let receiver = std::thread::Builder::new()
            .name("hetcomm-ros1-rx".into())
            .spawn(move || {
                while let Some(frame) = frames_rx.blocking_recv() {
                    if !frame.is_empty() {
                        sink.on_frame(&frame, Peer::Unknown);
                    }
                    for event in told.take_presence() {
                        sink.on_event(event);
                    }
                }
                drop(sink);
                let _ = receiver_done.send(());
            });
        let receiver = match receiver {
            Ok(r) => r,
            Err(e) => {
                drop(registration);
                runtime.shutdown_timeout(Duration::from_millis(500));
                return Err(Ros1OpenError::Runtime(e));
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
        self.shared.master.lock().clone()
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
    pub(super) fn flush(&self) {
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
    pub(super) fn ensure_connected(&self, to: SystemId) -> Result<(), LinkError> {
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
        let _gate = dest.gate.lock();
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
        // Counted before the frame is queued: the publishing task may take it and subtract its
        // bytes before `try_send` returns, and the counter must not pass below zero meanwhile
        // (it wrapped to nearly 2^64, and a layer adding to it panicked).
        counters
            .queued_bytes
            .fetch_add(frame.len() as u64, Ordering::Relaxed);
        let queued = self
            .shared
            .wiring
            .commands
            .try_send(Command::Frame(to, frame.to_vec()));
        if queued.is_err() {
            counters
                .queued_bytes
                .fetch_sub(frame.len() as u64, Ordering::Relaxed);
        }
        match queued {
            Ok(()) => {
                if let Some(dest) = self.shared.wiring.dests.get(&to) {
                    dest.unflushed.fetch_add(1, Ordering::Relaxed);
                }
                counters.sent.fetch_add(1, Ordering::Relaxed);
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
        drop(self.shared.wiring.frames.lock().take());
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
        let receiver = self.receiver.get_mut();
        if let Some((receiver, ended)) = receiver.take() {
            if receiver.thread().id() != std::thread::current().id()
                && ended.recv_timeout(Duration::from_secs(1)).is_ok()
            {
                let _ = receiver.join();
            }
        }
    }
}

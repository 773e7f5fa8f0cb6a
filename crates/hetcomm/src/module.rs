//! The autonomy developer's API: one [`Module`] of one system sends, broadcasts, polls and
//! subscribes. It is the thesis's Table 5 (`Send`, `CheckForMessage`, `GetNextMessageType`,
//! `GetMessage`) plus callbacks, priorities, timeouts and outcomes.

use std::cell::RefCell;
use std::marker::PhantomData;
use std::sync::Arc;
use std::time::Duration;

use hetcomm_core::{payload, Address, Message, MessageType, PayloadSource, Priority, Time};
use hetcomm_router::{Admitted, DirectLane, Outcome, SendRequest};

use crate::comm::SystemHandle;
use crate::error::{RecvError, SendError};
use crate::inbox::{Entry, InboxStats};
use crate::observe::RouteKind;
use crate::received::{RawMessage, Received};
use crate::runtime::{raw_message, Directory, Leaving, ModuleCore, Seen, SystemCore, Traffic};
use crate::ticket::{BroadcastTicket, OutcomeSlot, Ticket, TicketSlot};

mod senders;

use senders::{DirectRoute, Route};
pub use senders::{RawSender, Sender};

thread_local! {
    /// Type checks that passed on this thread: (registry id, type id, name address, name
    /// length). The name's address and length identify the exact `&'static str` checked.
    static CHECKED_TYPES: RefCell<rustc_hash::FxHashSet<(u64, u32, usize, usize)>> =
        RefCell::default();
}

/// Per-send options.
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq)]
pub struct SendOptions {
    /// Receive priority at the destination (default [`Priority::NORMAL`]).
    pub priority: Priority,
}

impl SendOptions {
    /// Options with the given priority.
    pub fn priority(priority: u8) -> Self {
        SendOptions {
            priority: Priority(priority),
        }
    }
}

/// A module (Sense, Plan, Act, …) of an opened system. Cheap to clone and `Send + Sync`: use
/// it from whichever thread runs the module.
#[derive(Clone)]
pub struct Module {
    pub(crate) sys: Arc<SystemHandle>,
    pub(crate) core: Arc<ModuleCore>,
}

impl Module {
    /// This module's name.
    pub fn name(&self) -> &str {
        self.core.name
    }

    /// This module's address.
    pub fn address(&self) -> Address {
        Address {
            system: self.sys.core.id,
            module: self.core.id,
        }
    }

    /// Registers `M` in the process's type registry, or checks it is there under its name.
    /// A check that passed is remembered by the thread (types are never unregistered), so
    /// the common case takes no lock shared with other threads.
    fn check_type<M: Message>(&self) -> Result<(), hetcomm_core::TypeRegistryError> {
        let key = (
            self.sys.core.registry_id,
            M::TYPE.0,
            M::NAME.as_ptr() as usize,
            M::NAME.len(),
        );
        if CHECKED_TYPES.with(|c| c.borrow().contains(&key)) {
            return Ok(());
        }
        let registry = &self.sys.core.registry;
        let known = registry.read().get(M::TYPE).map(|t| t.name == M::NAME);
        if known != Some(true) {
            registry.write().register::<M>()?;
        }
        CHECKED_TYPES.with(|c| c.borrow_mut().insert(key));
        Ok(())
    }

    fn resolve(&self, system: &str, module: &str) -> Result<Address, SendError> {
        let dir = &self.sys.core.directory;
        let system = *dir
            .system_ids
            .get(system)
            .ok_or_else(|| SendError::UnknownSystem(system.to_string()))?;
        let module = *dir
            .module_ids
            .get(module)
            .ok_or_else(|| SendError::UnknownModule(module.to_string()))?;
        Ok(Address { system, module })
    }

    /// Sends `msg` to `module` of `system` (friendly names). Returns at once with a
    /// [`Ticket`] for the outcome; errors here mean nothing was sent (unknown name, `X` pair,
    /// too large, type id conflict, or [`SendError::Backpressure`]: the transport's
    /// `max_in_flight` sends to that system still await their outcome).
    pub fn send<M: Message>(
        &self,
        system: &str,
        module: &str,
        msg: &M,
    ) -> Result<Ticket, SendError> {
        self.send_with(system, module, msg, SendOptions::default())
    }

    /// [`Module::send`] with options (priority).
    pub fn send_with<M: Message>(
        &self,
        system: &str,
        module: &str,
        msg: &M,
        opts: SendOptions,
    ) -> Result<Ticket, SendError> {
        self.check_type::<M>()?;
        let to = self.resolve(system, module)?;
        let payload = payload::encode_buf(msg)?;
        self.send_encoded(to, M::TYPE, PayloadSource::Owned(payload), opts, false)
    }

    /// Sends an already-encoded payload (tools, other-language bindings).
    pub fn send_raw(
        &self,
        system: &str,
        module: &str,
        message_type: MessageType,
        payload: &[u8],
        opts: SendOptions,
    ) -> Result<Ticket, SendError> {
        let to = self.resolve(system, module)?;
        self.send_encoded(
            to,
            message_type,
            PayloadSource::Borrowed(payload),
            opts,
            false,
        )
    }

    fn send_encoded(
        &self,
        to: Address,
        message_type: MessageType,
        payload: PayloadSource<'_>,
        opts: SendOptions,
        broadcast: bool,
    ) -> Result<Ticket, SendError> {
        let core = &self.sys.core;
        if core.is_closed() {
            return Err(SendError::Closed);
        }
        let now = core.clock.now();
        let mut router = core.router();
        let link = router.route_link(to.system);
        let direct = link.and_then(|link| core.direct_peer(link, to.system));
        let what = Outgoing {
            to,
            message_type,
            opts,
            broadcast,
        };
        if let Some(peer) = direct {
            let lane = router
                .direct_lane(to.system)
                .map_err(|e| send_error(&core.directory, e))?;
            drop(router);
            let to = DirectTarget {
                peer: &peer,
                module: peer.modules.get(&to.module).map(|m| &**m),
                lane: &lane,
                name: core.directory.system_name(to.system),
                lane_transport: link.and_then(|l| core.link_name(l)),
            };
            return self.hand_over(to, what, payload, now);
        }
        let req = what.request(self.core.id, payload.as_slice(), core.clock.wall(now));
        // A slot for the outcome is shared with the runtime only when the outcome comes
        // later (an acknowledged send, or a refused frame that is retried).
        let mut slot = None;
        let make_slot = |slot: &mut Option<Arc<OutcomeSlot>>| {
            let s = core.slots.take();
            *slot = Some(s.clone());
            s
        };
        let admitted = router.send_unqueued(now, req, || make_slot(&mut slot));
        let destination = core.directory.system_name(to.system);
        let tx = match admitted {
            Err(e) => {
                drop(router);
                return Err(send_error(&core.directory, e));
            }
            Ok(Admitted::Queued(_)) => {
                core.pump_at(router, now);
                let slot = slot.expect("a queued send has an outcome slot");
                return Ok(Ticket {
                    slot: TicketSlot::Pending(slot),
                    destination,
                });
            }
            Ok(Admitted::Transmit(tx)) => tx,
        };
        // An unacknowledged send: every earlier input pumped its own work, so the router has
        // nothing else queued; the frame goes out without a trip through `pump`, and its
        // outcome is known when the link answers.
        drop(router);
        let id = tx.id();
        let tx_link = tx.link;
        let out = Leaving {
            link: tx.link,
            to: tx.to,
            frame: &tx.frame,
            body: tx.body,
            traffic: Traffic::Data,
            wants_receipt: true,
            seen: Seen::Attempt {
                route: RouteKind::Unqueued,
                attempt: 1,
            },
        };
        let (result, receipt) = match core.leave(out, now) {
            Ok(receipt) => (Ok(()), receipt),
            Err(e) => (Err(e), None),
        };
        let mut router = core.router();
        match router.unqueued_result(now, tx, result, || make_slot(&mut slot)) {
            Some(outcome) => {
                drop(router);
                let transport = core.link_name(tx_link);
                // A link with an intermediary that confirms frames (an MQTT broker at QoS 1)
                // gave a receipt: the outcome says what the intermediary said.
                let slot = match (receipt, &outcome) {
                    (Some(receipt), Outcome::Sent { attempts }) => {
                        let slot = core.slots.take();
                        core.end_relayed(id, receipt, *attempts, transport, slot.clone());
                        TicketSlot::Pending(slot)
                    }
                    _ => core.end_send(id, outcome, transport, None, now),
                };
                Ok(Ticket { slot, destination })
            }
            None => {
                // Refused and retried later: the timer must learn the retry's deadline.
                core.pump_at(router, now);
                let slot = slot.expect("a retried send has an outcome slot");
                Ok(Ticket {
                    slot: TicketSlot::Pending(slot),
                    destination,
                })
            }
        }
    }

    /// Sends straight into `peer`'s inbox (an in-process route): the destination's lane
    /// numbers and counts the message without the router's lock; no frame is built.
    fn hand_over(
        &self,
        to: DirectTarget<'_>,
        what: Outgoing,
        payload: PayloadSource<'_>,
        now: hetcomm_core::Time,
    ) -> Result<Ticket, SendError> {
        let core = &self.sys.core;
        let req = what.request(self.core.id, payload.as_slice(), core.clock.wall(now));
        let header = to
            .lane
            .send(&req)
            .map_err(|e| send_error(&core.directory, e))?;
        let slot = core.hand_over(
            to.peer,
            to.module,
            header,
            payload,
            now,
            |status| to.lane.result(&header, status),
            to.lane_transport,
        );
        Ok(Ticket {
            slot,
            destination: to.name,
        })
    }

    /// A handle for sending many `M`s to `module` of `system`: the names are looked up, the
    /// type registered and the route found once, here, instead of at every send. Sending
    /// through it behaves exactly like [`Module::send`] (same checks, numbering, outcomes).
    pub fn sender<M: Message>(&self, system: &str, module: &str) -> Result<Sender<M>, SendError> {
        self.check_type::<M>()?;
        Ok(Sender {
            route: self.route(system, module)?,
            _type: PhantomData,
        })
    }

    /// [`Module::sender`] for already-encoded payloads of type `message_type`.
    pub fn raw_sender(
        &self,
        system: &str,
        module: &str,
        message_type: MessageType,
    ) -> Result<RawSender, SendError> {
        Ok(RawSender {
            route: self.route(system, module)?,
            message_type,
        })
    }

    fn route(&self, system: &str, module: &str) -> Result<Route, SendError> {
        let to = self.resolve(system, module)?;
        let core = &self.sys.core;
        let mut router = core.router();
        let link = router
            .route_link(to.system)
            .ok_or_else(|| SendError::NoRoute {
                from: core.name.to_string(),
                to: system.to_string(),
            })?;
        let direct = match core.direct_peer(link, to.system) {
            Some(peer) => Some(DirectRoute {
                module: peer.modules.get(&to.module).cloned(),
                peer,
                lane: router
                    .direct_lane(to.system)
                    .map_err(|e| send_error(&core.directory, e))?,
                transport: core.link_name(link),
            }),
            None => None,
        };
        drop(router);
        Ok(Route {
            from: self.clone(),
            to,
            destination: core.directory.system_name(to.system),
            direct,
        })
    }

    /// Sends `msg` to `module` on every other system this one may talk to (the thesis's
    /// "All"). Systems whose pair is `X` are skipped. One outcome per destination; a
    /// destination whose window is full gets one that failed with
    /// [`FailReason::Backpressure`](crate::FailReason::Backpressure), and the others are sent.
    /// On a transport that reaches every system with one send (an unsecured `zenoh`
    /// transport: docs/zenoh.md, "Broadcasts"), the destinations it carries get one frame for
    /// all of them, with the same outcomes; every other destination gets a copy of its own.
    pub fn broadcast<M: Message>(
        &self,
        module: &str,
        msg: &M,
    ) -> Result<BroadcastTicket, SendError> {
        self.broadcast_with(module, msg, SendOptions::default())
    }

    /// [`Module::broadcast`] with options.
    pub fn broadcast_with<M: Message>(
        &self,
        module: &str,
        msg: &M,
        opts: SendOptions,
    ) -> Result<BroadcastTicket, SendError> {
        self.check_type::<M>()?;
        let payload = payload::encode(msg)?;
        self.broadcast_raw(module, M::TYPE, &payload, opts)
    }

    /// Broadcasts an already-encoded payload.
    pub fn broadcast_raw(
        &self,
        module: &str,
        message_type: MessageType,
        payload: &[u8],
        opts: SendOptions,
    ) -> Result<BroadcastTicket, SendError> {
        let module_id = *self
            .sys
            .core
            .directory
            .module_ids
            .get(module)
            .ok_or_else(|| SendError::UnknownModule(module.to_string()))?;
        let destinations = self.sys.core.router().destinations();
        let mut native = self.broadcast_native(module_id, message_type, payload, opts);
        let mut tickets = Vec::with_capacity(destinations.len());
        for system in destinations {
            if let Some(ticket) = native.remove(&system) {
                tickets.push(ticket);
                continue;
            }
            let to = Address {
                system,
                module: module_id,
            };
            let sent = self.send_encoded(
                to,
                message_type,
                PayloadSource::Borrowed(payload),
                opts,
                true,
            );
            // One destination's full window must not cut the broadcast short: the others
            // are sent, and that one's ticket tells it was not.
            let ticket = match sent {
                Err(SendError::Backpressure { .. }) => Ticket {
                    slot: TicketSlot::Ready(
                        hetcomm_router::Outcome::Failed {
                            reason: hetcomm_router::FailReason::Backpressure,
                            attempts: 0,
                        },
                        None,
                    ),
                    destination: self.sys.core.directory.system_name(system),
                },
                other => other?,
            };
            tickets.push(ticket);
        }
        Ok(BroadcastTicket { tickets })
    }

    /// The native part of a broadcast: on each link that reaches every system with one send
    /// (`LinkCaps::broadcast`), one frame for the destinations whose route takes that link
    /// (at least two of them). Returns their tickets; every other destination (and every
    /// destination of a group the router refused whole, e.g. one destination's window is
    /// full) is left to a send of its own.
    fn broadcast_native(
        &self,
        module: hetcomm_core::ModuleId,
        message_type: MessageType,
        payload: &[u8],
        opts: SendOptions,
    ) -> std::collections::BTreeMap<hetcomm_core::SystemId, Ticket> {
        let mut tickets = std::collections::BTreeMap::new();
        let core = &self.sys.core;
        let capable: Vec<usize> = (core.links().iter().enumerate())
            .filter(|(_, l)| l.caps().broadcast)
            .map(|(i, _)| i)
            .collect();
        if capable.is_empty() || core.is_closed() {
            return tickets;
        }
        let now = core.clock.now();
        let mut router = core.router();
        let req = SendRequest {
            from: self.core.id,
            to: Address {
                system: hetcomm_core::wire::TO_ALL_SYSTEM,
                module,
            },
            message_type,
            priority: opts.priority,
            payload,
            broadcast: true,
            timestamp: core.clock.wall(now),
        };
        for link in capable {
            let group = router.broadcast_group(link);
            if group.len() < 2 {
                continue;
            }
            let mut slots = Vec::with_capacity(group.len());
            let sent = router.send_broadcast(now, req, &group, |to| {
                let slot = core.slots.take();
                slots.push((to, slot.clone()));
                slot
            });
            if sent.is_ok() {
                for (to, slot) in slots {
                    let ticket = Ticket {
                        slot: TicketSlot::Pending(slot),
                        destination: core.directory.system_name(to),
                    };
                    tickets.insert(to, ticket);
                }
            }
        }
        if !tickets.is_empty() {
            core.pump_at(router, now);
        }
        tickets
    }

    /// Whether a message is waiting (the thesis's `CheckForMessage`).
    pub fn has_message(&self) -> bool {
        !self.core.inbox.is_empty()
    }

    /// Lets `recv` calls on this module spin up to `spin` for a message before they sleep
    /// (default: no spinning, beyond a look of about a microsecond). A message arriving while
    /// the receiver spins is taken within a fraction of a microsecond instead of after a
    /// thread wake-up (several microseconds, tens when the wake-up crosses CPUs on a small VM),
    /// at the cost of a busy core while spinning. A receiver that reads its links itself (UDP)
    /// keeps polling them without a timeout meanwhile, yielding the CPU between looks so that
    /// a peer sharing the CPU still runs. For latency-critical modules on machines with cores
    /// to spare.
    pub fn set_wait_spin(&self, spin: Duration) {
        self.core.inbox.set_spin(spin);
    }

    /// Runs this module's callbacks ([`Module::on`], [`Module::on_any`], [`Module::on_raw`])
    /// at the delivery, on the thread that delivers the message, instead of on the module's
    /// callback thread: a reply sent from the callback then leaves without any thread
    /// hand-off — the structure of DDS listeners and of `ddsperf`'s ping–pong. The delivering
    /// thread is the link's: a UDP or TCP link's reader (the module or background thread
    /// reading the sockets, or a connection's reader thread), Cyclone DDS's receive thread on
    /// a `ros2` transport with `deliver_on_receive_thread = true` (docs/ros2.md), the
    /// sender's own thread for an in-process sender.
    ///
    /// What an inline callback must respect: it delays every frame behind it on that link,
    /// so it must be short and must not wait (for a message, a lock another callback holds,
    /// a full inbox); callbacks of one module may run at the same time on different
    /// delivering threads (no arrival order across links). Sends from it are fine; a message
    /// a send delivers on the same thread (an in-process destination) to a module with inline
    /// callbacks goes to that module's callback thread instead of nesting a second callback.
    /// A panicking callback is caught and counted in [`crate::SystemStats::callback_failures`],
    /// as on the callback thread. Set it before messages for the callbacks arrive: messages
    /// already queued for the callback thread are still run there. Under simulation
    /// callbacks are always inline.
    pub fn set_inline_callbacks(&self, inline: bool) {
        self.core
            .inline_requested
            .store(inline, std::sync::atomic::Ordering::Release);
    }

    /// Messages waiting.
    pub fn pending(&self) -> usize {
        self.core.inbox.len()
    }

    /// The type of the message `recv` would return next (`GetNextMessageType`).
    pub fn next_type(&self) -> Option<MessageType> {
        self.core.inbox.next_type()
    }

    fn decode<M: Message>(&self, e: Entry) -> Result<Received<M>, RecvError> {
        let raw = raw_message(&self.sys.core.directory, e);
        let message = payload::decode::<M>(&raw.payload)?;
        Ok(Received {
            message,
            envelope: raw.envelope,
        })
    }

    fn wrong_type<M: Message>(&self, found: MessageType) -> RecvError {
        let found_name = self
            .sys
            .core
            .registry
            .read()
            .get(found)
            .map(|t| t.name.clone())
            .unwrap_or_else(|| "unregistered".into());
        RecvError::WrongType {
            expected: M::TYPE,
            expected_name: M::NAME,
            found,
            found_name,
        }
    }

    /// Takes the next message if there is one and it is an `M` (`GetMessage`). A message of
    /// another type is an error and stays in the inbox.
    pub fn try_recv<M: Message>(&self) -> Result<Option<Received<M>>, RecvError> {
        self.check_type::<M>()?;
        match self.core.inbox.try_take(|h| h.message_type == M::TYPE) {
            Ok(Some(e)) => self.decode(e).map(Some),
            Ok(None) => Ok(None),
            Err(h) => Err(self.wrong_type::<M>(h.message_type)),
        }
    }

    /// Waits for the next message, which must be an `M`.
    pub fn recv<M: Message>(&self) -> Result<Received<M>, RecvError> {
        self.recv_inner(None)
    }

    /// Waits up to `timeout` for the next message, which must be an `M`.
    pub fn recv_timeout<M: Message>(&self, timeout: Duration) -> Result<Received<M>, RecvError> {
        self.recv_inner(Some(timeout))
    }

    fn recv_inner<M: Message>(&self, timeout: Option<Duration>) -> Result<Received<M>, RecvError> {
        self.check_type::<M>()?;
        match self
            .sys
            .core
            .take_waiting(&self.core, |h| h.message_type == M::TYPE, timeout)
        {
            Ok(Some(e)) => self.decode(e),
            Ok(None) if self.sys.core.is_closed() => Err(RecvError::Closed),
            Ok(None) => Err(RecvError::Timeout(timeout.unwrap_or_default())),
            Err(h) => Err(self.wrong_type::<M>(h.message_type)),
        }
    }

    /// Takes the next message of any type, undecoded, without waiting.
    pub fn try_recv_raw(&self) -> Option<RawMessage> {
        match self.core.inbox.try_take(|_| true) {
            Ok(Some(e)) => Some(raw_message(&self.sys.core.directory, e)),
            _ => None,
        }
    }

    /// Waits up to `timeout` (None: forever) for the next message of any type, undecoded.
    pub fn recv_raw_timeout(&self, timeout: Option<Duration>) -> Result<RawMessage, RecvError> {
        match self.sys.core.take_waiting(&self.core, |_| true, timeout) {
            Ok(Some(e)) => Ok(raw_message(&self.sys.core.directory, e)),
            _ if self.sys.core.is_closed() => Err(RecvError::Closed),
            _ => Err(RecvError::Timeout(timeout.unwrap_or_default())),
        }
    }

    /// Waits up to `timeout` (None: forever) for a message of any type, then takes it and
    /// whatever else is queued, up to `max` messages in all, undecoded, appending them to
    /// `out` in the order [`Module::recv_raw_timeout`] would give them. Returns how many
    /// were taken (at least 1: no message before the timeout is an error). A consumer of a
    /// fast stream takes batches at a fraction of the per-message cost (one lock of the
    /// inbox for the batch); `max` bounds how much one call takes.
    pub fn recv_raw_many(
        &self,
        out: &mut Vec<RawMessage>,
        max: usize,
        timeout: Option<Duration>,
    ) -> Result<usize, RecvError> {
        if max == 0 {
            return Ok(0);
        }
        let first = self.recv_raw_timeout(timeout)?;
        out.push(first);
        let dir = &self.sys.core.directory;
        let more = self
            .core
            .inbox
            .take_up_to(max - 1, |e| out.push(raw_message(dir, e)));
        Ok(1 + more)
    }

    /// Calls `f` for every `M` that arrives from now on, instead of queueing it for polling.
    /// Callbacks of one module run one at a time, in arrival order (priority first), on that
    /// module's callback thread; a slow callback delays only this module's callbacks. A message
    /// that fails to decode, or a callback that panics, is counted in
    /// [`crate::SystemStats::callback_failures`].
    pub fn on<M: Message>(
        &self,
        f: impl Fn(Received<M>) + Send + Sync + 'static,
    ) -> Result<(), RecvError> {
        self.check_type::<M>()?;
        let failures = self.sys.core.clone();
        let module = self.core.id;
        let cb = Arc::new(
            move |raw: RawMessage| match payload::decode::<M>(&raw.payload) {
                Ok(message) => f(Received {
                    message,
                    envelope: raw.envelope,
                }),
                Err(_) => {
                    if let Some(m) = failures.modules.get(&module) {
                        m.callback_failures
                            .fetch_add(1, std::sync::atomic::Ordering::Relaxed);
                    }
                }
            },
        );
        self.core
            .set_callback(Some(M::TYPE), cb, self.sys.core.directory.clone());
        Ok(())
    }

    /// Calls `f` for every message of a type without its own callback, undecoded.
    pub fn on_any(&self, f: impl Fn(RawMessage) + Send + Sync + 'static) {
        self.core
            .set_callback(None, Arc::new(f), self.sys.core.directory.clone());
    }

    /// Calls `f` for every message of type `message_type` that arrives from now on, undecoded,
    /// instead of queueing it for polling: [`Module::on`] for types that are not Rust types
    /// (other-language bindings, tools). Same threading as [`Module::on`]; replaces any
    /// callback already set for that type. Messages of other types are not affected.
    pub fn on_raw(
        &self,
        message_type: MessageType,
        f: impl Fn(RawMessage) + Send + Sync + 'static,
    ) {
        self.core.set_callback(
            Some(message_type),
            Arc::new(f),
            self.sys.core.directory.clone(),
        );
    }

    /// This module's inbox counters.
    pub fn inbox_stats(&self) -> InboxStats {
        self.core.inbox.stats()
    }
}

/// The facade's error for a send the router refused.
fn send_error(dir: &Directory, e: hetcomm_router::SendError) -> SendError {
    match e {
        hetcomm_router::SendError::NoRoute { from, to } => SendError::NoRoute {
            from: dir.system_name(from).to_string(),
            to: dir.system_name(to).to_string(),
        },
        hetcomm_router::SendError::TooLarge { len, max, to } => SendError::TooLarge {
            to: dir.system_name(to).to_string(),
            len,
            max,
        },
        hetcomm_router::SendError::Backpressure { to, limit } => SendError::Backpressure {
            to: dir.system_name(to).to_string(),
            limit,
        },
        other => SendError::UnknownSystem(other.to_string()),
    }
}

/// What a send asks for, besides its payload.
#[derive(Clone, Copy)]
struct Outgoing {
    to: Address,
    message_type: MessageType,
    opts: SendOptions,
    broadcast: bool,
}

impl Outgoing {
    /// The router's request, stamped `timestamp` (the wall clock at the send's `now`).
    fn request<'a>(
        &self,
        from: hetcomm_core::ModuleId,
        payload: &'a [u8],
        timestamp: Time,
    ) -> SendRequest<'a> {
        SendRequest {
            from,
            to: self.to,
            message_type: self.message_type,
            priority: self.opts.priority,
            payload,
            broadcast: self.broadcast,
            timestamp,
        }
    }
}

/// Where an in-process send goes ([`Module::hand_over`]).
struct DirectTarget<'a> {
    peer: &'a SystemCore,
    /// The destination module (None: the peer has no such module).
    module: Option<&'a ModuleCore>,
    /// Numbers and counts the send.
    lane: &'a DirectLane,
    /// The destination system's name, for the ticket.
    name: &'static str,
    /// The in-process transport's name, for the ticket.
    lane_transport: Option<&'static str>,
}

//! Senders resolved once ([`Module::sender`], [`Module::raw_sender`]): the route they keep,
//! and how a send on it takes the in-process hand-over or the general path.

use std::marker::PhantomData;
use std::sync::Arc;

use hetcomm_core::wire::AckStatus;
use hetcomm_core::{payload, Address, Header, Message, MessageType, PayloadBuf, PayloadSource};
use hetcomm_router::DirectLane;

use super::{send_error, DirectTarget, Module, Outgoing, SendOptions};
use crate::error::SendError;
use crate::runtime::{ModuleCore, SystemCore};
use crate::ticket::{Ticket, TicketSlot};

/// A resolved destination: the sending module, the address, and the destination system
/// itself when it lives in this process behind an in-process route.
#[derive(Clone)]
pub(super) struct Route {
    pub(super) from: Module,
    pub(super) to: Address,
    pub(super) destination: &'static str,
    /// The destination when it lives in this process.
    pub(super) direct: Option<DirectRoute>,
}

/// A destination system in this process, resolved once for a [`Route`].
#[derive(Clone)]
pub(super) struct DirectRoute {
    pub(super) peer: Arc<SystemCore>,
    /// The destination module (None: that system has no such module).
    pub(super) module: Option<Arc<ModuleCore>>,
    pub(super) lane: Arc<DirectLane>,
    /// The in-process transport's name, for the ticket.
    pub(super) transport: Option<&'static str>,
}

impl Route {
    pub(super) fn send(
        &self,
        message_type: MessageType,
        payload: PayloadSource<'_>,
        opts: SendOptions,
    ) -> Result<Ticket, SendError> {
        let core = &self.from.sys.core;
        match &self.direct {
            Some(d) if !d.peer.is_closed() && !core.is_closed() => {
                let now = core.clock.now();
                let what = Outgoing {
                    to: self.to,
                    message_type,
                    opts,
                    broadcast: false,
                };
                let to = DirectTarget {
                    peer: &d.peer,
                    module: d.module.as_deref(),
                    lane: &d.lane,
                    name: self.destination,
                    lane_transport: d.transport,
                };
                self.from.hand_over(to, what, payload, now)
            }
            // Not in-process, or that system was closed (it may have been opened again):
            // the general path finds the route afresh.
            _ => self
                .from
                .send_encoded(self.to, message_type, payload, opts, false),
        }
    }
}

impl Route {
    /// Sends each of `payloads`, in order, exactly as [`Route::send`] would one by one, and
    /// gives each its own result (its ticket, with its own outcome). To a module of this
    /// process the batch costs one clock reading and one pass through the destination
    /// inbox's lock (while nothing observes or taps it: [`SystemCore::deliver_direct_many`]).
    pub(super) fn send_many(
        &self,
        message_type: MessageType,
        payloads: &[&[u8]],
        opts: SendOptions,
    ) -> Vec<Result<Ticket, SendError>> {
        let core = &self.from.sys.core;
        let d = match &self.direct {
            Some(d) if !d.peer.is_closed() && !core.is_closed() && !core.sends_observed() => d,
            // Observed sends are reported one by one; other routes take the general path.
            _ => {
                return payloads
                    .iter()
                    .map(|p| self.send(message_type, PayloadSource::Borrowed(p), opts))
                    .collect()
            }
        };
        let now = core.clock.now();
        let stamp = core.clock.wall(now);
        let what = Outgoing {
            to: self.to,
            message_type,
            opts,
            broadcast: false,
        };
        // Numbered in order; one the lane refuses (too large) keeps its error and is not sent.
        let numbered: Vec<Result<Header, SendError>> = payloads
            .iter()
            .map(|p| {
                d.lane
                    .send(&what.request(self.from.core.id, p, stamp))
                    .map_err(|e| send_error(&core.directory, e))
            })
            .collect();
        let messages: Vec<(Header, PayloadBuf)> = numbered
            .iter()
            .zip(payloads)
            .filter_map(|(h, p)| Some((*h.as_ref().ok()?, PayloadBuf::copy_from_slice(p))))
            .collect();
        let mut statuses: Vec<AckStatus> = Vec::with_capacity(messages.len());
        d.peer
            .deliver_direct_many(d.module.as_deref(), messages.into_iter(), now, |status| {
                statuses.push(status)
            });
        let mut statuses = statuses.into_iter();
        numbered
            .into_iter()
            .map(|h| {
                let header = h?;
                let status = statuses
                    .next()
                    .expect("deliver_direct_many answers once per message");
                Ok(Ticket {
                    slot: TicketSlot::Ready(d.lane.result(&header, status), d.transport),
                    destination: self.destination,
                })
            })
            .collect()
    }
}

/// Sends `M`s from one module to one destination module without looking anything up per
/// send; made by [`Module::sender`]. Cheap to clone, `Send + Sync`.
pub struct Sender<M> {
    pub(super) route: Route,
    pub(super) _type: PhantomData<fn(&M)>,
}

impl<M> Clone for Sender<M> {
    fn clone(&self) -> Self {
        Sender {
            route: self.route.clone(),
            _type: PhantomData,
        }
    }
}

impl<M: Message> Sender<M> {
    /// Sends `msg` ([`Module::send`]).
    pub fn send(&self, msg: &M) -> Result<Ticket, SendError> {
        self.send_with(msg, SendOptions::default())
    }

    /// Sends `msg` with options ([`Module::send_with`]).
    pub fn send_with(&self, msg: &M, opts: SendOptions) -> Result<Ticket, SendError> {
        let payload = payload::encode_buf(msg)?;
        self.route
            .send(M::TYPE, PayloadSource::Owned(payload), opts)
    }

    /// The destination system's name.
    pub fn destination(&self) -> &str {
        self.route.destination
    }
}

/// Sends already-encoded payloads of one type from one module to one destination module;
/// made by [`Module::raw_sender`].
#[derive(Clone)]
pub struct RawSender {
    pub(super) route: Route,
    pub(super) message_type: MessageType,
}

impl RawSender {
    /// Sends `payload` ([`Module::send_raw`]).
    pub fn send(&self, payload: &[u8], opts: SendOptions) -> Result<Ticket, SendError> {
        self.route
            .send(self.message_type, PayloadSource::Borrowed(payload), opts)
    }

    /// Sends every payload of `payloads`, in order, each exactly as [`RawSender::send`]
    /// would (same checks, numbering and outcomes), and returns each one's result in the
    /// same order. To a system of this process the whole batch goes into the destination's
    /// inbox at once (one clock reading, one pass through the inbox's lock), which is what
    /// makes a stream of small messages fast; elsewhere the sends are made one by one.
    /// Under the `block` overflow policy the messages that find the inbox full wait for
    /// room one by one, as single sends do.
    pub fn send_many(
        &self,
        payloads: &[&[u8]],
        opts: SendOptions,
    ) -> Vec<Result<Ticket, SendError>> {
        self.route.send_many(self.message_type, payloads, opts)
    }

    /// The destination system's name.
    pub fn destination(&self) -> &str {
        self.route.destination
    }
}

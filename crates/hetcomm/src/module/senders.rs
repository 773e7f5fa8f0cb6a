//! Senders resolved once ([`Module::sender`], [`Module::raw_sender`]): the route they keep,
//! and how a send on it takes the in-process hand-over or the general path.

use std::marker::PhantomData;
use std::sync::Arc;

use hetcomm_core::{payload, Address, Message, MessageType, PayloadSource};
use hetcomm_router::DirectLane;

use super::{DirectTarget, Module, Outgoing, SendOptions};
use crate::error::SendError;
use crate::runtime::{ModuleCore, SystemCore};
use crate::ticket::Ticket;

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

    /// The destination system's name.
    pub fn destination(&self) -> &str {
        self.route.destination
    }
}

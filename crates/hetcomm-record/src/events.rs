//! From what an [`Observer`](hetcomm::Observer) sees to the [`Event`]s of a recording: one
//! code path for the recorder and for anything else that shows a fleet's traffic with the
//! fleet's names (the live Foxglove view serves the same JSON objects).
//!
//! An observer's callbacks run on the threads doing the work, so they only copy the record
//! ([`Observed::send`], [`Observed::receipt`], [`Observed::outcome`]); naming and encoding
//! ([`EventBuilder::event`]) happen later on a thread of the observer's own.

use std::collections::HashMap;
use std::sync::Arc;

use hetcomm::config::Fleet;
use hetcomm::observe::{
    OutcomeRecord, PathChangeRecord, ReceiptRecord, RouteKind, SendRecord, Via,
};
use hetcomm::wire::AckStatus;
use hetcomm::{Header, Outcome, SendId, Time};

use crate::format::{
    self, Addr, Envelope, Event, OutcomeEvent, PathSwitchEvent, ReceiptEvent, SendEvent,
};
use crate::Encoding;

/// An observed send attempt, receipt or outcome, copied out of the observer's callback.
#[derive(Clone, Debug)]
pub enum Observed {
    /// One attempt of a send ([`hetcomm::Observer::on_send`] / `on_retransmit`).
    Send {
        /// The header as it left.
        header: Header,
        /// The encoded payload.
        payload: Vec<u8>,
        /// When, on the system's clock.
        time: Time,
        /// Which way it left.
        route: RouteKind,
        /// The link it was handed to.
        link: Option<usize>,
        /// 1 for the send, 2 and more for retransmissions.
        attempt: u32,
    },
    /// A message handed to an inbox ([`hetcomm::Observer::on_receipt`]).
    Receipt {
        /// The message's header.
        header: Header,
        /// The encoded payload.
        payload: Vec<u8>,
        /// When, on the system's clock.
        time: Time,
        /// Which link it came on.
        via: Via,
        /// What the inbox answered.
        status: AckStatus,
    },
    /// A send that ended ([`hetcomm::Observer::on_outcome`]).
    Outcome {
        /// The sending system (the observed one).
        system: Arc<str>,
        /// Which send.
        id: SendId,
        /// How it ended.
        outcome: Outcome,
        /// When, on the system's clock.
        time: Time,
    },
    /// A path switch of `system` ([`hetcomm::Observer::on_path_change`]).
    PathSwitch {
        /// The switching system (the observed one).
        system: Arc<str>,
        /// The destination system's name.
        to: String,
        /// The transport left.
        from: String,
        /// The transport taken.
        now: String,
        /// The system's switches so far.
        number: u64,
        /// When, on the system's clock.
        time: Time,
    },
}

impl Observed {
    /// A copy of a send attempt.
    pub fn send(r: &SendRecord<'_>) -> Observed {
        Observed::Send {
            header: r.header,
            payload: r.payload.to_vec(),
            time: r.time,
            route: r.route,
            link: r.link,
            attempt: r.attempt,
        }
    }

    /// A copy of a receipt.
    pub fn receipt(r: &ReceiptRecord<'_>) -> Observed {
        Observed::Receipt {
            header: r.header,
            payload: r.payload.to_vec(),
            time: r.time,
            via: r.via,
            status: r.status,
        }
    }

    /// A copy of an outcome of a send of `system`.
    pub fn outcome(system: &Arc<str>, r: &OutcomeRecord<'_>) -> Observed {
        Observed::Outcome {
            system: system.clone(),
            id: r.id,
            outcome: r.outcome.clone(),
            time: r.time,
        }
    }

    /// A copy of a path switch of `system`.
    pub fn path_switch(system: &Arc<str>, r: &PathChangeRecord<'_>) -> Observed {
        Observed::PathSwitch {
            system: system.clone(),
            to: r.to_name.to_string(),
            from: r.from.to_string(),
            now: r.now.to_string(),
            number: r.number,
            time: r.time,
        }
    }

    /// The encoded payload of a send or receipt (empty for an outcome or a path switch).
    pub fn payload(&self) -> &[u8] {
        match self {
            Observed::Send { payload, .. } | Observed::Receipt { payload, .. } => payload,
            Observed::Outcome { .. } | Observed::PathSwitch { .. } => &[],
        }
    }
}

/// The fleet's names of systems, modules and transports, by id and tag.
#[derive(Clone, Debug)]
pub struct FleetNames {
    systems: HashMap<u16, String>,
    modules: HashMap<u16, String>,
    transports: HashMap<u8, String>,
}

impl FleetNames {
    /// The names of `fleet`.
    pub fn new(fleet: &Fleet) -> FleetNames {
        FleetNames {
            systems: fleet
                .systems
                .iter()
                .map(|s| (s.id.0, s.name.clone()))
                .collect(),
            modules: fleet
                .modules
                .iter()
                .map(|m| (m.id.0, m.name.clone()))
                .collect(),
            transports: fleet
                .transports
                .iter()
                .map(|t| (t.tag, t.name.clone()))
                .collect(),
        }
    }

    /// A system's name (`#id` when the fleet does not name it).
    pub fn system(&self, id: u16) -> String {
        self.systems
            .get(&id)
            .cloned()
            .unwrap_or_else(|| format!("#{id}"))
    }

    /// A module's name (`#id` when the fleet does not name it).
    pub fn module(&self, id: u16) -> String {
        self.modules
            .get(&id)
            .cloned()
            .unwrap_or_else(|| format!("#{id}"))
    }

    /// The name of the transport with this tag, if the fleet has one.
    pub fn transport(&self, tag: u8) -> Option<&str> {
        self.transports.get(&tag).map(String::as_str)
    }
}

/// Names systems, modules and transports by the fleet and builds [`Event`]s.
#[derive(Clone, Debug)]
pub struct EventBuilder {
    names: FleetNames,
    encoding: Encoding,
}

impl EventBuilder {
    /// Names from `fleet`; with [`Encoding::Json`] payloads are decoded into the events, with
    /// [`Encoding::MsgPack`] they are left to the caller.
    pub fn new(fleet: &Fleet, encoding: Encoding) -> EventBuilder {
        EventBuilder {
            names: FleetNames::new(fleet),
            encoding,
        }
    }

    /// The fleet's names.
    pub fn names(&self) -> &FleetNames {
        &self.names
    }

    /// The envelope of a message, named.
    pub fn envelope(&self, h: &Header, payload: &[u8]) -> Envelope {
        let (value, b64) = match self.encoding {
            Encoding::Json => format::payload_json(payload),
            Encoding::MsgPack => (None, None),
        };
        Envelope {
            source: Addr {
                system: self.names.system(h.source.system.0),
                module: self.names.module(h.source.module.0),
            },
            destination: Addr {
                system: self.names.system(h.destination.system.0),
                module: self.names.module(h.destination.module.0),
            },
            seq: h.seq,
            message_type: h.message_type.0,
            priority: h.priority.0,
            transport: (h.transport as char).to_string(),
            transport_name: self.names.transport(h.transport).map(str::to_string),
            ack_requested: h.flags & hetcomm::wire::FLAG_ACK_REQUESTED != 0,
            broadcast: h.flags & hetcomm::wire::FLAG_BROADCAST != 0,
            timestamp_us: h.timestamp.as_micros(),
            size: payload.len(),
            payload: value,
            payload_b64: b64,
        }
    }

    /// The event of an observed record.
    pub fn event(&self, item: &Observed) -> Event {
        match item {
            Observed::Send {
                header,
                payload,
                time,
                route,
                link,
                attempt,
            } => Event::Send(SendEvent {
                time_us: time.as_micros(),
                message: self.envelope(header, payload),
                attempt: *attempt,
                route: route_name(*route).to_string(),
                link: *link,
            }),
            Observed::Receipt {
                header,
                payload,
                time,
                via,
                status,
            } => Event::Receipt(ReceiptEvent {
                time_us: time.as_micros(),
                message: self.envelope(header, payload),
                status: status_name(*status).to_string(),
                link: match via {
                    Via::Link(i) => Some(*i),
                    _ => None,
                },
            }),
            Observed::Outcome {
                system,
                id,
                outcome,
                time,
            } => {
                let (outcome, attempts, latency_us, reason) = format::outcome_parts(outcome);
                Event::Outcome(OutcomeEvent {
                    time_us: time.as_micros(),
                    source_system: system.to_string(),
                    destination_system: self.names.system(id.to.0),
                    seq: id.seq,
                    outcome: outcome.to_string(),
                    attempts,
                    latency_us,
                    reason,
                })
            }
            Observed::PathSwitch {
                system,
                to,
                from,
                now,
                number,
                time,
            } => Event::PathSwitch(PathSwitchEvent {
                time_us: time.as_micros(),
                source_system: system.to_string(),
                destination_system: to.clone(),
                from: from.clone(),
                to: now.clone(),
                number: *number,
            }),
        }
    }
}

/// A receipt's status as recordings spell it.
pub fn status_name(s: AckStatus) -> &'static str {
    match s {
        AckStatus::Delivered => "delivered",
        AckStatus::InboxFull => "inbox_full",
        AckStatus::UnknownModule => "unknown_module",
    }
}

fn route_name(r: RouteKind) -> &'static str {
    match r {
        RouteKind::Routed => "routed",
        RouteKind::Unqueued => "unqueued",
        RouteKind::Direct => "direct",
        _ => "other",
    }
}

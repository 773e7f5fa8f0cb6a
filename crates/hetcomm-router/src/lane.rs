//! Sends into the same process without the router's lock.

use std::sync::atomic::{AtomicU64, Ordering};
use std::time::Duration;

use hetcomm_core::wire::{self, AckStatus, FLAG_ACK_REQUESTED, FLAG_BROADCAST, HEADER_LEN};
use hetcomm_core::{Address, FrameKind, Header, SystemId};

use crate::router::{Outcome, Route, RouterStats, SendError, SendRequest};

/// Numbering and counting for sends to one destination that the driver hands straight to an
/// inbox of the same process (an in-process link: reliable, ordered and synchronous), so they
/// need neither a frame nor the destination's router.
///
/// Made by [`Router::direct_lane`](crate::Router::direct_lane), once per destination, and
/// shared with the router: both number messages towards that destination from the same
/// counter, and the router's [`stats`](crate::Router::stats) include the lane's sends. A lane
/// is used without the router's lock, from any number of threads at once: a send costs one
/// atomic increment (two for an acknowledged one), where a trip through the router costs a
/// lock, two table lookups and an unlock.
///
/// A lane's sends end at once, so they never occupy the destination's window
/// ([`Route::max_in_flight`]) and are never refused for back-pressure.
#[derive(Debug)]
pub struct DirectLane {
    local: SystemId,
    incarnation: u32,
    to: SystemId,
    route: Route,
    /// The last sequence number given towards `to`, by the lane or by the router.
    pub(crate) last_seq: AtomicU64,
    /// Acknowledged lane sends that ended delivered.
    delivered: AtomicU64,
    /// Acknowledged lane sends that ended failed.
    failed: AtomicU64,
}

impl DirectLane {
    pub(crate) fn new(
        local: SystemId,
        incarnation: u32,
        to: SystemId,
        route: Route,
        last_seq: u64,
    ) -> Self {
        DirectLane {
            local,
            incarnation,
            to,
            route,
            last_seq: AtomicU64::new(last_seq),
            delivered: AtomicU64::new(0),
            failed: AtomicU64::new(0),
        }
    }

    /// Accepts a send to this lane's destination: checks its size, numbers it and returns the
    /// header to deliver. An unacknowledged send ends `Sent` here, whatever the inbox will
    /// say, exactly as over a link; an acknowledged one ends with [`DirectLane::result`].
    pub fn send(&self, req: &SendRequest<'_>) -> Result<Header, SendError> {
        debug_assert_eq!(req.to.system, self.to, "a lane sends to one destination");
        let len = HEADER_LEN + req.payload.len();
        let max = self.route.max_frame.min(HEADER_LEN + wire::MAX_PAYLOAD);
        if len > max {
            return Err(SendError::TooLarge {
                len,
                max,
                to: self.to,
            });
        }
        // Relaxed: the number only has to be unique and increasing per destination; the
        // message itself is published by the inbox's own synchronisation.
        let seq = self.last_seq.fetch_add(1, Ordering::Relaxed) + 1;
        let mut flags = 0;
        if self.route.acknowledged {
            flags |= FLAG_ACK_REQUESTED;
        }
        if req.broadcast {
            flags |= FLAG_BROADCAST;
        }
        Ok(Header {
            kind: FrameKind::Data,
            flags,
            priority: req.priority,
            transport: self.route.tag,
            source: Address {
                system: self.local,
                module: req.from,
            },
            destination: req.to,
            incarnation: self.incarnation,
            seq,
            message_type: req.message_type,
            timestamp: req.timestamp,
        })
    }

    /// The outcome of a [`DirectLane::send`], given what the destination's inbox said
    /// (`status`). An unacknowledged send is `Sent` (and was counted when it was numbered); an
    /// acknowledged one is counted here.
    pub fn result(&self, header: &Header, status: AckStatus) -> Outcome {
        if !header.ack_requested() {
            return Outcome::Sent { attempts: 1 };
        }
        let outcome = Outcome::acknowledged(status, 1, Duration::ZERO);
        let counter = match outcome {
            Outcome::Delivered { .. } => &self.delivered,
            // An acknowledgement's outcome is delivered or failed: never `Sent`, and never
            // unconfirmed, since the inbox answered on this thread.
            Outcome::Sent { .. }
            | Outcome::Relayed { .. }
            | Outcome::Unconfirmed { .. }
            | Outcome::Failed { .. } => &self.failed,
        };
        // Release, with the acquiring loads in `add_to`: whoever sees the outcome counted
        // also sees the send's number, so `in_flight` never goes below zero.
        counter.fetch_add(1, Ordering::Release);
        outcome
    }

    /// Adds the lane's sends to `stats`; `numbered_by_router` is how many of the numbers
    /// given towards the destination the router gave itself (the rest are the lane's).
    pub(crate) fn add_to(&self, stats: &mut RouterStats, numbered_by_router: u64) {
        // The outcomes first, then the numbers (see `result`).
        let delivered = self.delivered.load(Ordering::Acquire);
        let failed = self.failed.load(Ordering::Acquire);
        let sends = self
            .last_seq
            .load(Ordering::Relaxed)
            .saturating_sub(numbered_by_router);
        stats.sends += sends;
        stats.transmissions += sends;
        if self.route.acknowledged {
            stats.delivered += delivered;
            stats.failed += failed;
        } else {
            stats.sent += sends;
        }
    }
}

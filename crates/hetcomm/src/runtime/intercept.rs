//! The interception point. Every message this system's modules send or receive passes through
//! here, whichever path it takes: the router's loop, the unqueued fast path, a direct
//! hand-over in process, a batch into one inbox, a topic. This file is the only place where
//! the harness's taps and scheduled faults, and the observers (monitor, recordings, Foxglove),
//! see it.
//!
//! One entry per direction:
//! - **leaving**: [`SystemCore::leave`] puts a frame on a link (observers, then faults, then
//!   the link), and [`SystemCore::hand_over`] puts a message straight into an in-process
//!   peer's inbox (observers, then the peer's way in);
//! - **arriving**: [`SystemCore::arrive`] (taps, then observers, then the inbox), entered after
//!   the taps by what the harness lets through or puts there ([`SystemCore::arrive_untapped`]);
//! - **ending**: [`SystemCore::end_send`] (observers, then the ticket), for every send's
//!   outcome.
//!
//! The paths that skip a step for speed ask here first whether they may:
//! [`SystemCore::may_skip_links`], [`SystemCore::sends_observed`],
//! [`SystemCore::arrivals_plain`]. Each check is one relaxed load while nothing watches, so the
//! unwatched paths cost what they did before observers, taps and faults existed.

use super::*;
use crate::harness::TopicValue;
use crate::observe::PathChangeRecord;
use hetcomm_core::wire::TO_ALL_SYSTEM;
use hetcomm_core::PayloadSource;
use hetcomm_link::relay::RelayReceipt;

/// A frame about to leave on a link ([`SystemCore::leave`]).
pub(crate) struct Leaving<'a> {
    /// The link's index in this system's links.
    pub link: usize,
    pub to: SystemId,
    /// The encoded frame, followed on the wire by `body` (empty unless the payload was left in
    /// the caller's memory).
    pub frame: &'a [u8],
    pub body: &'a [u8],
    pub traffic: Traffic,
    /// An unacknowledged send's frame: ask the link for its intermediary's receipt.
    pub wants_receipt: bool,
    /// How the observers see it.
    pub seen: Seen<'a>,
}

/// How the observers see a frame that leaves.
#[derive(Clone, Copy)]
pub(crate) enum Seen<'a> {
    /// Not reported: an acknowledgement, a frame that was reported when first offered, or a
    /// frame that left while nobody observed.
    Unreported,
    /// One attempt of one send.
    Attempt { route: RouteKind, attempt: u32 },
    /// A native broadcast's one frame: one attempt of each of these destinations' shares.
    Broadcast(&'a [SystemId]),
}

/// What the observers need of the frames of one round of the router's loop, read while the
/// router is locked (nothing at all while nobody observes).
#[derive(Default)]
pub(super) struct RoundNotes {
    observed: bool,
    /// Per transmit: which attempt of its send it is (0: not reported).
    attempts: SmallVec<[u32; 4]>,
    /// The destinations of each native broadcast's frame, in transmit order.
    broadcasts: SmallVec<[Vec<SystemId>; 1]>,
    /// The next broadcast's place in `broadcasts`.
    next_broadcast: usize,
}

impl RoundNotes {
    /// Starts a round: whether anyone observes is decided once for all its frames.
    pub(super) fn begin(&mut self, core: &SystemCore) {
        self.observed = core.observers.active();
        self.attempts.clear();
        self.broadcasts.clear();
        self.next_broadcast = 0;
    }

    /// Notes transmit `t` (the next of the round) while the router that made it is locked.
    #[inline]
    pub(super) fn note(&mut self, router: &Router<Arc<OutcomeSlot>>, t: &Transmit) {
        if !self.observed {
            return;
        }
        // A frame that waited for a secure session was seen when first offered.
        let seen = t.send.is_some_and(|id| router.repeats_refused_offer(id));
        let attempt = t.send.and_then(|id| router.attempts(id)).unwrap_or(0);
        self.attempts.push(if seen { 0 } else { attempt });
        if t.to == TO_ALL_SYSTEM {
            let b = t.send.map_or(0, |id| id.wire_seq());
            self.broadcasts.push(router.broadcast_destinations(b));
        }
    }

    /// How the observers see the round's transmit number `i`, `t`. Called in transmit order.
    pub(super) fn seen(&mut self, i: usize, t: &Transmit) -> Seen<'_> {
        if !self.observed {
            return Seen::Unreported;
        }
        if t.to == TO_ALL_SYSTEM {
            if let Some(dests) = self.broadcasts.get(self.next_broadcast) {
                self.next_broadcast += 1;
                return Seen::Broadcast(dests);
            }
        }
        match self.attempts.get(i) {
            Some(&attempt) if attempt > 0 => Seen::Attempt {
                route: RouteKind::Routed,
                attempt,
            },
            _ => Seen::Unreported,
        }
    }
}

impl SystemCore {
    // ----- leaving -----

    /// The way out for every frame: the observers see it, the scheduled faults act on it (a
    /// frame they take is dropped or held back, and the link never sees it), and then it goes
    /// on its link. `Ok(Some(receipt))`: the link took an unacknowledged send's frame and its
    /// intermediary will say what became of it. Frames held back for batching, or that a
    /// fault acts on, get no receipt.
    #[inline]
    pub(crate) fn leave(
        &self,
        out: Leaving<'_>,
        now: Time,
    ) -> Result<Option<RelayReceipt>, TransmitError> {
        if !matches!(out.seen, Seen::Unreported) && self.observers.active() {
            self.observe_leaving(&out, now);
        }
        if self.harness.faulted() {
            return self.leave_faulted(out, now);
        }
        if out.wants_receipt && !self.holds_frames(out.link) {
            return self.put_relayed_on_link(out.link, out.to, out.frame, out.body);
        }
        self.put_on_link(out.link, out.to, out.frame, out.body, now, out.traffic)
            .map(|()| None)
    }

    /// [`SystemCore::leave`]'s report, out of the way of the unobserved path.
    #[cold]
    #[inline(never)]
    fn observe_leaving(&self, out: &Leaving<'_>, now: Time) {
        match out.seen {
            Seen::Unreported => {}
            Seen::Attempt { route, attempt } => self
                .observers
                .send_frame(out.frame, out.body, now, route, out.link, attempt),
            Seen::Broadcast(dests) => self
                .observers
                .send_broadcast_frame(out.frame, dests, now, out.link),
        }
    }

    /// [`SystemCore::leave`] while faults are scheduled here.
    #[cold]
    #[inline(never)]
    fn leave_faulted(
        &self,
        out: Leaving<'_>,
        now: Time,
    ) -> Result<Option<RelayReceipt>, TransmitError> {
        if self
            .harness
            .fault_frame(self.id, out.link, out.to, out.frame, out.body, now)
        {
            return Ok(None);
        }
        self.put_on_link(out.link, out.to, out.frame, out.body, now, out.traffic)
            .map(|()| None)
    }

    /// Whether a send may skip links and go straight into an in-process peer's inbox: not
    /// while faults are scheduled here, since they act on frames (every send takes its link).
    #[inline(always)]
    pub(crate) fn may_skip_links(&self) -> bool {
        !self.harness.faulted()
    }

    /// Whether sends are reported one by one (a batch of sends then takes the one-send path).
    #[inline(always)]
    pub(crate) fn sends_observed(&self) -> bool {
        self.observers.active()
    }

    /// The way out of a send handed straight to `peer`'s module `module` (None: the peer has
    /// no such module), with its header already numbered by its lane: the observers see the
    /// send and its outcome, and the message enters the peer's way in. `outcome` makes the
    /// send's outcome from the peer's answer; `transport` names the in-process transport.
    #[allow(clippy::too_many_arguments)] // one hand-over's whole description
    #[inline]
    pub(crate) fn hand_over(
        &self,
        peer: &SystemCore,
        module: Option<&ModuleCore>,
        header: Header,
        payload: PayloadSource<'_>,
        now: Time,
        outcome: impl FnOnce(AckStatus) -> Outcome,
        transport: Option<&'static str>,
    ) -> TicketSlot {
        // Decided once per send: a send is observed whole (send and outcome) or not at all.
        let observed = self.observers.active();
        if observed {
            self.observers.send_direct(&header, payload.as_slice(), now);
        }
        let status = peer.deliver_direct(module, header, payload.into_buf(), now);
        let outcome = outcome(status);
        if observed {
            let id = SendId {
                to: header.destination.system,
                seq: header.seq,
            };
            self.observe_outcome(id, &outcome, now);
        }
        TicketSlot::Ready(outcome, transport)
    }

    /// The way out of a value published on a topic of this process: the harness's topic taps
    /// see it first (and may drop, hold back or duplicate it); `deliver` gives a value to the
    /// topic's subscribers.
    #[inline]
    pub(crate) fn publish(
        &self,
        topic: &Arc<str>,
        value: TopicValue,
        now: Time,
        deliver: impl Fn(TopicValue),
    ) {
        if !self.harness.topic_tapped() {
            return deliver(value);
        }
        if let Some((value, copies)) = self.harness.on_publish(topic, value, now) {
            for _ in 0..copies {
                deliver(value.clone());
            }
            deliver(value);
        }
    }

    // ----- arriving -----

    /// The way in for every message to this system's modules, from a link or handed over
    /// in process: the harness's message taps see it first (and may drop, delay, duplicate,
    /// corrupt or record it), then the observers, then `module`'s inbox (None: there is no
    /// such module).
    #[inline]
    pub(crate) fn arrive(
        &self,
        module: Option<&ModuleCore>,
        header: Header,
        payload: PayloadBuf,
        now: Time,
        source: Source,
    ) -> AckStatus {
        if self.harness.tapped_for(&header) {
            return self
                .harness
                .on_delivery(self, module, header, payload, now, source);
        }
        self.arrive_untapped(module, header, payload, now, source)
    }

    /// [`SystemCore::arrive`] after the taps: for a message that passed them, or that the
    /// harness held back, duplicated or injected. The observers see it, then the inbox takes
    /// it.
    #[inline]
    pub(crate) fn arrive_untapped(
        &self,
        module: Option<&ModuleCore>,
        header: Header,
        payload: PayloadBuf,
        now: Time,
        source: Source,
    ) -> AckStatus {
        if self.observers.active() {
            return self.deliver_observed(module, header, payload, now, source);
        }
        self.deliver_to(module, header, payload, now, source)
    }

    /// Whether messages arriving for `module` go straight to its inbox, so a batch of them
    /// may enter through the inbox's lock once: nothing observes or taps them (and `module`
    /// has no callbacks, which take messages one by one).
    #[inline]
    pub(crate) fn arrivals_plain(&self, module: &ModuleCore) -> bool {
        !self.observers.active() && !self.harness.tapping() && !module.has_callbacks()
    }

    /// [`SystemCore::deliver_to`] and a report of the receipt to the observers (every
    /// receipt, from a link or handed over directly, is reported here). The payload is
    /// copied for the observers: the inbox takes the message.
    #[cold]
    #[inline(never)]
    fn deliver_observed(
        &self,
        module: Option<&ModuleCore>,
        header: Header,
        payload: PayloadBuf,
        now: Time,
        source: Source,
    ) -> AckStatus {
        let copy = payload.clone();
        let status = self.deliver_to(module, header, payload, now, source);
        self.observers.receipt(&ReceiptRecord {
            header,
            payload: &copy,
            time: now,
            via: match source {
                Source::Link(link) => Via::Link(link),
                Source::SameProcess | Source::Harness => Via::Direct,
            },
            status,
        });
        status
    }

    // ----- ending -----

    /// Where every send's outcome goes, whichever way the send went: the observers see it,
    /// then the ticket gets it (`slot`, or a ticket made ready with it, returned).
    #[inline(always)]
    pub(crate) fn end_send(
        &self,
        id: SendId,
        outcome: Outcome,
        transport: Option<&'static str>,
        slot: Option<Arc<OutcomeSlot>>,
        now: Time,
    ) -> TicketSlot {
        match slot {
            Some(slot) => {
                if self.observers.active() {
                    self.observe_outcome(id, &outcome, now);
                }
                // Nobody holds a ticket for it (dropped, as a stream's sender does): nobody
                // can read it, and writing it would pull its line to this core for nothing.
                if Arc::strong_count(&slot) > 1 {
                    slot.complete(outcome, transport);
                }
                TicketSlot::Pending(slot)
            }
            None => {
                // Made first, so the outcome is not moved again after the observers saw it.
                let ready = TicketSlot::Ready(outcome, transport);
                if self.observers.active() {
                    if let TicketSlot::Ready(outcome, _) = &ready {
                        self.observe_outcome(id, outcome, now);
                    }
                }
                ready
            }
        }
    }

    /// [`SystemCore::end_send`]'s report, out of the way of the unobserved path.
    #[cold]
    #[inline(never)]
    fn observe_outcome(&self, id: SendId, outcome: &Outcome, now: Time) {
        self.observers.outcome(&OutcomeRecord {
            id,
            outcome,
            time: now,
        });
    }

    /// Reports a path switch to the observers (the system's own log keeps it either way).
    pub(crate) fn observe_path_change(&self, record: &PathChangeRecord<'_>) {
        if self.observers.active() {
            self.observers.path_change(record);
        }
    }
}

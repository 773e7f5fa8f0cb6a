//! Carrying out what the router decided: transmissions, deliveries into inboxes (through the
//! harness's taps and the observers), and ended sends.

use super::*;
use hetcomm_core::wire::TO_ALL_SYSTEM;
use hetcomm_link::relay::RelayReceipt;

/// Where a message being delivered comes from: it decides whether a full `block` inbox may
/// make the deliverer wait.
#[derive(Clone, Copy)]
pub(crate) enum Source {
    /// Handed over by a sender of this process, on its own thread: it may wait for room.
    SameProcess,
    /// From a link (this index), through the router: refused at once when there is no room.
    Link(usize),
    /// Put there by the harness (held back, duplicated or injected): refused at once when
    /// there is no room, as from a link.
    Harness,
}

/// Receipts of the unacknowledged frames one [`SystemCore::pump_at`] put on links that pass
/// them through an intermediary which confirms them, kept until their sends' outcomes come
/// (the router ends such a send *sent* when its link takes the frame; the receipt then says
/// more). A broadcast's one receipt serves each of its shares.
#[derive(Default)]
struct Receipts(SmallVec<[(SendId, RelayReceipt); 1]>);

impl Receipts {
    fn put(&mut self, id: SendId, receipt: Option<RelayReceipt>) {
        if let Some(receipt) = receipt {
            self.0.push((id, receipt));
        }
    }

    /// The receipt for send `id`'s frame: its own, or its broadcast's.
    fn take(&mut self, id: SendId) -> Option<RelayReceipt> {
        if self.0.is_empty() {
            return None;
        }
        if id.is_broadcast() {
            let frame = SendId {
                to: TO_ALL_SYSTEM,
                seq: id.seq,
            };
            return self
                .0
                .iter()
                .find(|(i, _)| *i == frame)
                .map(|(_, r)| r.clone());
        }
        let at = self.0.iter().position(|(i, _)| *i == id)?;
        Some(self.0.swap_remove(at).1)
    }
}

impl SystemCore {
    /// Performs everything the router asks for, until it has nothing more: frames onto links,
    /// deliveries into inboxes, outcomes into tickets, and the timer re-armed. The router lock
    /// is never held while a link or an inbox is called (an in-process link re-enters
    /// another system's router on this same thread).
    pub(crate) fn pump<'a>(&'a self, router: MutexGuard<'a, Router<Arc<OutcomeSlot>>>) {
        let now = self.clock.now();
        self.pump_at(router, now);
    }

    /// [`SystemCore::pump`] with the clock already read (by a caller that read it
    /// microseconds ago: reading it is a noticeable part of a small message's cost).
    pub(crate) fn pump_at<'a>(
        &'a self,
        mut router: MutexGuard<'a, Router<Arc<OutcomeSlot>>>,
        first_now: Time,
    ) {
        // One message usually makes one transmit, delivery or outcome per round: keep them on
        // the stack.
        let mut transmits: SmallVec<[Transmit; 4]> = SmallVec::new();
        // A batch datagram's frames are handled in one go (see `SystemSink::on_frames`).
        let mut deliveries: SmallVec<[Delivery; 16]> = SmallVec::new();
        let mut events: SmallVec<[Event<Arc<OutcomeSlot>>; 4]> = SmallVec::new();
        let mut delivery_results: SmallVec<[(DeliveryToken, AckStatus); 2]> = SmallVec::new();
        let mut transmit_results: SmallVec<[(Transmit, Result<(), TransmitError>); 4]> =
            SmallVec::new();
        // Per transmit, while observed: which attempt of its send it is (0 for an ack).
        let mut attempts: SmallVec<[u32; 4]> = SmallVec::new();
        // While observed: the destinations of each native broadcast's frame among them.
        let mut broadcast_dests: SmallVec<[Vec<SystemId>; 1]> = SmallVec::new();
        let mut switches: SmallVec<[hetcomm_router::PathChange; 1]> = SmallVec::new();
        // Per transmit: whether its send ends when the frame leaves (a receipt is asked for).
        let mut unacknowledged: SmallVec<[bool; 4]> = SmallVec::new();
        // Receipts of frames an intermediary confirms, by send, until the send's outcome is
        // known (see `SystemCore::end_relayed`).
        let mut receipts = Receipts::default();
        // Presettled frames the links took, for the router at its next lock.
        let mut taken: SmallVec<[(Transmit, Time); 4]> = SmallVec::new();
        // Slots of the sends that ended this round, for the pool.
        let mut ended: SmallVec<[Arc<OutcomeSlot>; 4]> = SmallVec::new();
        let mut now = first_now;
        let mut first = true;
        loop {
            // One clock read per round: the calls below are microseconds apart.
            if !first {
                now = self.clock.now();
            }
            first = false;
            let observed = self.observers.active();
            while let Some(t) = router.poll_transmit(now) {
                if observed {
                    // A frame that waited for a secure session was seen when first offered.
                    let seen = t.send.is_some_and(|id| router.repeats_refused_offer(id));
                    let attempt = t.send.and_then(|id| router.attempts(id)).unwrap_or(0);
                    attempts.push(if seen { 0 } else { attempt });
                    if t.to == TO_ALL_SYSTEM {
                        let b = t.send.map_or(0, |id| id.wire_seq());
                        broadcast_dests.push(router.broadcast_destinations(b));
                    }
                }
                unacknowledged.push(t.send.is_some_and(|id| router.unacknowledged(id)));
                transmits.push(t);
            }
            while let Some(d) = router.poll_delivery() {
                deliveries.push(d);
            }
            while let Some(e) = router.poll_event() {
                events.push(e);
            }
            while let Some(c) = router.poll_path_change() {
                switches.push(c);
            }
            let next = router.poll_timeout();
            drop(router);
            self.timer.arm(next);
            if !switches.is_empty() {
                self.path_switched(&switches, now);
                switches.clear();
            }
            if transmits.is_empty() && deliveries.is_empty() && events.is_empty() {
                return;
            }
            for Event::Outcome {
                id,
                token,
                outcome,
                path,
            } in events.drain(..)
            {
                let transport = path.and_then(|p| self.link_name(p.link));
                match (&outcome, receipts.take(id)) {
                    (Outcome::Sent { attempts }, Some(receipt)) => {
                        self.end_relayed(id, receipt, *attempts, transport, token);
                    }
                    _ => {
                        if let TicketSlot::Pending(slot) =
                            self.end_send(id, outcome, transport, Some(token), now)
                        {
                            ended.push(slot);
                        }
                    }
                }
            }
            self.slots.give_back(ended.drain(..));
            for d in deliveries.drain(..) {
                let token = d.token;
                let status = self.deliver(d, now);
                if let Some(token) = token {
                    delivery_results.push((token, status));
                }
            }
            for (i, tx) in transmits.drain(..).enumerate() {
                // Only sends need their result: an acknowledgement lost here is counted by
                // the link, and its sender retransmits and is acknowledged again.
                let traffic = match tx.send {
                    Some(_) => Traffic::Data,
                    None => Traffic::Ack,
                };
                if tx.to == TO_ALL_SYSTEM && !broadcast_dests.is_empty() {
                    let dests = broadcast_dests.remove(0);
                    self.observers
                        .send_broadcast_frame(&tx.frame, &dests, now, tx.link);
                } else if let Some(&attempt) = attempts.get(i).filter(|&&a| a > 0) {
                    self.observers.send_frame(
                        &tx.frame,
                        &[],
                        now,
                        RouteKind::Routed,
                        tx.link,
                        attempt,
                    );
                }
                let result = match (tx.send, unacknowledged.get(i)) {
                    (Some(id), Some(true)) => self
                        .transmit_relayed_on(tx.link, tx.to, &tx.frame, &[], now)
                        .map(|receipt| receipts.put(id, receipt)),
                    _ => self.transmit_on(tx.link, tx.to, &tx.frame, &[], now, traffic),
                };
                if tx.presettled && result.is_ok() {
                    taken.push((tx, now));
                } else if tx.send.is_some() || tx.probe.is_some() {
                    transmit_results.push((tx, result));
                }
            }
            if !taken.is_empty() {
                self.taken_back.push(taken.drain(..));
            }
            attempts.clear();
            broadcast_dests.clear();
            unacknowledged.clear();
            if delivery_results.is_empty() && transmit_results.is_empty() {
                // Nothing to feed back (timers were armed above).
                return;
            }
            router = self.router();
            for (token, status) in delivery_results.drain(..) {
                router.delivery_result(now, token, status);
            }
            for (tx, result) in transmit_results.drain(..) {
                router.transmit_result(now, tx, result);
            }
        }
    }

    /// Puts a delivery that came through the router (from a link) into its module's inbox
    /// (or callback queue).
    pub(super) fn deliver(&self, d: Delivery, now: Time) -> AckStatus {
        let module = self.modules.get(&d.header.destination.module);
        let source = Source::Link(d.link);
        if self.harness.tapped_for(&d.header) {
            return self.harness.on_delivery(
                self,
                module.map(|m| &**m),
                d.header,
                d.payload,
                now,
                source,
            );
        }
        if self.observers.active() {
            return self.deliver_observed(module.map(|m| &**m), d.header, d.payload, now, source);
        }
        self.deliver_to(module.map(|m| &**m), d.header, d.payload, now, source)
    }

    /// Puts a message that passed this system's taps (or that the harness injected or held
    /// back) into its module's inbox. `link`: the link it came on (None: from this process,
    /// or from the harness, which never waits for room).
    pub(crate) fn deliver_untapped(
        &self,
        header: Header,
        payload: PayloadBuf,
        now: Time,
        link: Option<usize>,
    ) -> AckStatus {
        let module = self.modules.get(&header.destination.module).map(|m| &**m);
        let source = match link {
            Some(l) => Source::Link(l),
            None => Source::Harness,
        };
        self.deliver_passed(module, header, payload, now, source)
    }

    /// [`SystemCore::deliver_untapped`] with the module already looked up and the message's
    /// own source (a message that passed its taps unchanged in time).
    pub(crate) fn deliver_passed(
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

    /// Puts a frame the harness held back (a scheduled latency) on link `index`.
    pub(crate) fn send_held_frame(
        &self,
        index: usize,
        to: SystemId,
        frame: &[u8],
    ) -> Result<(), LinkError> {
        if self.is_closed() {
            return Err(LinkError::Closed);
        }
        match self.links().get(index) {
            Some(link) => link.send(to, frame),
            None => Err(LinkError::Closed),
        }
    }

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
    pub(super) fn observe_outcome(&self, id: SendId, outcome: &Outcome, now: Time) {
        self.observers.outcome(&OutcomeRecord {
            id,
            outcome,
            time: now,
        });
    }

    /// [`SystemCore::deliver_to`] and a report of the receipt to the observers (every
    /// receipt, from a link or handed over directly, is reported here). The payload is
    /// copied for the observers: the inbox takes the message.
    #[cold]
    #[inline(never)]
    pub(super) fn deliver_observed(
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

    /// Puts a message into `module`'s inbox, or hands it to the module's callbacks (None:
    /// there is no such module). Only a sender of this process waits for room under the
    /// `block` policy; a link is never stopped. (Callers report it: [`Self::deliver_observed`].)
    pub(super) fn deliver_to(
        &self,
        module: Option<&ModuleCore>,
        header: Header,
        payload: PayloadBuf,
        now: Time,
        source: Source,
    ) -> AckStatus {
        let Some(module) = module else {
            self.unknown_module.fetch_add(1, Ordering::Relaxed);
            return AckStatus::UnknownModule;
        };
        let entry = Entry {
            header,
            payload,
            received_at: self.clock.wall(now),
        };
        let wants_callback = module.wants_callback(header.message_type);
        let entry = match wants_callback {
            true => match module.run_inline(&self.directory, entry) {
                None => return AckStatus::Delivered,
                Some(entry) => entry,
            },
            false => entry,
        };
        let inbox = if wants_callback {
            &module.callback_inbox
        } else {
            &module.inbox
        };
        let pushed = match source {
            Source::SameProcess => inbox.push(entry),
            Source::Link(_) | Source::Harness => inbox.push_from_link(entry),
        };
        match pushed {
            Ok(()) => {
                if !wants_callback && module.leading.load(Ordering::SeqCst) && !leading_here() {
                    if let Some(r) = self.reactor.get() {
                        r.kick();
                    }
                }
                AckStatus::Delivered
            }
            Err(PushError::Full) | Err(PushError::Closed) => AckStatus::InboxFull,
        }
    }
}

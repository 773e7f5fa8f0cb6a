//! Carrying out what the router decided: transmissions, deliveries into inboxes and ended
//! sends, each through the interception point (`intercept.rs`).

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
        // What the observers need of each transmit (nothing while nobody observes).
        let mut notes = RoundNotes::default();
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
            notes.begin(self);
            while let Some(t) = router.poll_transmit(now) {
                notes.note(&router, &t);
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
                let wants_receipt = tx.send.is_some() && unacknowledged.get(i) == Some(&true);
                let out = Leaving {
                    link: tx.link,
                    to: tx.to,
                    frame: &tx.frame,
                    body: &[],
                    traffic,
                    wants_receipt,
                    seen: notes.seen(i, &tx),
                };
                let result = self.leave(out, now).map(|receipt| {
                    if let Some(id) = tx.send {
                        receipts.put(id, receipt);
                    }
                });
                if tx.presettled && result.is_ok() {
                    taken.push((tx, now));
                } else if tx.send.is_some() || tx.probe.is_some() {
                    transmit_results.push((tx, result));
                }
            }
            if !taken.is_empty() {
                self.taken_back.push(taken.drain(..));
            }
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
        let module = self.modules.get(&d.header.destination.module).map(|m| &**m);
        self.arrive(module, d.header, d.payload, now, Source::Link(d.link))
    }

    /// Puts a message that passed this system's taps (or that the harness injected or held
    /// back) into its module's inbox, through [`SystemCore::arrive_untapped`]. `link`: the
    /// link it came on (None: from this process, or from the harness, which never waits for
    /// room).
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
        self.arrive_untapped(module, header, payload, now, source)
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

    /// Puts a message into `module`'s inbox, or hands it to the module's callbacks (None:
    /// there is no such module). Only a sender of this process waits for room under the
    /// `block` policy; a link is never stopped. (It is reached through [`SystemCore::arrive`].)
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

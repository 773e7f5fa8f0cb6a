//! The timer table, outcomes out and shutdown.

use super::*;

impl<T> Router<T> {
    /// When [`Router::handle_timeout`] should next be called.
    pub fn poll_timeout(&self) -> Option<Time> {
        self.timers.first().map(|(t, _)| *t)
    }

    /// Retransmits or gives up on sends whose acknowledgement is overdue, and moves in-order
    /// delivery past gaps that waited longer than the hold timeout: every deadline due at
    /// `now`, in the order they fall due.
    pub fn handle_timeout(&mut self, now: Time) {
        while let Some(&(deadline, timer)) = self.timers.first() {
            if deadline > now {
                break;
            }
            self.timers.pop_first();
            match timer {
                Timer::Retransmit(id) => self.retransmit_due(now, id, deadline),
                Timer::Hold(origin, incarnation) => {
                    self.hold_due(now, (origin, incarnation), deadline)
                }
                Timer::Probe(to) => self.probe_due(now, to, deadline),
            }
        }
    }

    /// A send's deadline fell due: transmit it again, or give up without attempts left.
    fn retransmit_due(&mut self, now: Time, id: SendId, deadline: Time) {
        let Some(p) = self.pending.get_mut(&id) else {
            return;
        };
        if p.deadline != Some(deadline) {
            return; // superseded
        }
        if p.presettled_from.is_some() {
            // Its frame is still with the driver, which has not said whether the link took
            // it: look again shortly rather than judge an attempt that may not have left.
            let again = now + self.config.timing.link_retry;
            p.deadline = Some(again);
            self.timers.insert((again, Timer::Retransmit(id)));
            return;
        }
        p.deadline = None;
        let timed_out = std::mem::take(&mut p.awaiting_ack);
        if timed_out && self.judging {
            // Unconfirmed on the path its last frame took: that path's health hears of it
            // (and may fail over, which gives this send a budget on the next path), and the
            // next frame goes on another healthy path if there is one.
            p.timed_out = true;
            let link = p.route.link;
            let sign = paths::Sign::Unconfirmed { offered: p.offered };
            self.path_sign(now, id.to, link, sign);
        }
        let Some(p) = self.pending.get(&id) else {
            return;
        };
        if p.attempts < p.route.attempts || self.untried_path(id) {
            self.transmits.push_back(TransmitItem::Send(id));
        } else if let Some(p) = self.pending.get(&id) {
            let outcome = p.give_up(FailReason::NoAcknowledgement);
            self.finish(id, outcome);
        }
    }

    /// An in-order hold fell due: give the gap up and deliver what waited behind it.
    fn hold_due(&mut self, now: Time, key: (SystemId, u32), deadline: Time) {
        let Some(state) = self.order.get_mut(&key) else {
            return;
        };
        if state.deadline != Some(deadline) {
            return; // superseded
        }
        state.deadline = None;
        if let Some(&first) = state.held.keys().next() {
            self.stats.gaps_skipped += 1;
            state.next = first;
        }
        self.release_in_order(now, key);
    }

    /// The next outcome.
    pub fn poll_event(&mut self) -> Option<Event<T>> {
        self.events.pop_front()
    }

    /// Fails every unresolved send with [`FailReason::Shutdown`] (their outcomes appear in
    /// [`Router::poll_event`]).
    pub fn shutdown(&mut self) {
        let ids: Vec<SendId> = self.pending.keys().copied().collect();
        for id in ids {
            let outcome = self.pending[&id].give_up(FailReason::Shutdown);
            self.finish(id, outcome);
        }
        self.timers.clear();
    }
}

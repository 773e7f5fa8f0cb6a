//! The timer table, outcomes out and shutdown.

use super::*;

impl<T> Router<T> {
    /// When [`Router::handle_timeout`] should next be called.
    pub fn poll_timeout(&self) -> Option<Time> {
        let retransmit = self.timers.first().map(|(t, _)| *t);
        let hold = self.order.values().filter_map(|o| o.deadline).min();
        match (retransmit, hold) {
            (Some(a), Some(b)) => Some(a.min(b)),
            (a, b) => a.or(b),
        }
    }

    /// Retransmits or fails sends whose acknowledgement is overdue, and moves in-order
    /// delivery past gaps that waited longer than the hold timeout.
    pub fn handle_timeout(&mut self, now: Time) {
        let overdue: Vec<(SystemId, u32)> = self
            .order
            .iter()
            .filter(|(_, o)| o.deadline.is_some_and(|d| d <= now))
            .map(|(k, _)| *k)
            .collect();
        for key in overdue {
            if let Some(state) = self.order.get_mut(&key) {
                if let Some(&first) = state.held.keys().next() {
                    self.stats.gaps_skipped += 1;
                    state.next = first;
                }
            }
            self.release_in_order(now, key);
        }
        while let Some(&(deadline, id)) = self.timers.first() {
            if deadline > now {
                break;
            }
            self.timers.pop_first();
            let Some(p) = self.pending.get_mut(&id) else {
                continue;
            };
            if p.deadline != Some(deadline) {
                continue; // superseded
            }
            p.deadline = None;
            if p.attempts < p.route.attempts {
                self.transmits.push_back(TransmitItem::Send(id));
            } else {
                let outcome = p.give_up(FailReason::NoAcknowledgement);
                self.finish(id, outcome);
            }
        }
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

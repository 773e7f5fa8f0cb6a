//! Transmitting: link results, retransmission after a timeout and giving up.

use super::*;

impl<T> Router<T> {
    /// The next frame to put on a link. `now` is when the driver hands it to the link: an
    /// acknowledgement may come back before [`Router::transmit_result`] is called (an
    /// in-process link delivers synchronously), and is accepted.
    pub fn poll_transmit(&mut self, now: Time) -> Option<Transmit> {
        while let Some(item) = self.transmits.pop_front() {
            match item {
                TransmitItem::Ack { link, to, frame } => {
                    return Some(Transmit {
                        link,
                        to,
                        frame,
                        send: None,
                    })
                }
                TransmitItem::Send(id) => {
                    // A send may have ended (acknowledged) while queued for retransmission.
                    let Some(p) = self.pending.get_mut(&id) else {
                        continue;
                    };
                    let Some(frame) = p.frame.take() else {
                        continue;
                    };
                    p.attempts += 1;
                    p.first_sent.get_or_insert(now);
                    self.stats.transmissions += 1;
                    if p.attempts > 1 {
                        self.stats.retransmissions += 1;
                    }
                    return Some(Transmit {
                        link: p.route.link,
                        to: id.to,
                        frame,
                        send: Some(id),
                    });
                }
            }
        }
        None
    }

    /// Reports what the link did with a frame from [`Router::poll_transmit`], handing the
    /// frame back (the router keeps it for retransmission).
    pub fn transmit_result(&mut self, now: Time, tx: Transmit, result: Result<(), TransmitError>) {
        let Some(id) = tx.send else { return };
        let Some(attempts) = self.pending.get(&id).map(|p| p.attempts) else {
            return; // already ended (an ack overtook the result)
        };
        let rto = self.rto_for(id.to, attempts);
        let Some(p) = self.pending.get_mut(&id) else {
            return;
        };
        p.frame = Some(tx.frame);
        if result.is_ok() {
            p.transmitted = true;
        }
        match result {
            Ok(()) => {
                if p.route.acknowledged {
                    let deadline = now + rto;
                    p.deadline = Some(deadline);
                    self.timers.insert((deadline, id));
                } else {
                    let attempts = p.attempts;
                    self.finish(id, Outcome::Sent { attempts });
                }
            }
            Err(TransmitError::TooLarge(reason)) => {
                let outcome = p.give_up(FailReason::Link(reason));
                self.finish(id, outcome);
            }
            Err(err) => {
                if p.attempts < p.route.attempts {
                    let factor = 1u32 << p.attempts.saturating_sub(1).min(16);
                    let deadline = now + self.config.timing.link_retry * factor;
                    p.deadline = Some(deadline);
                    self.timers.insert((deadline, id));
                } else {
                    let reason = match err {
                        TransmitError::Unreachable(r) => FailReason::Unreachable(r),
                        TransmitError::TooLarge(r) | TransmitError::Other(r) => FailReason::Link(r),
                    };
                    let outcome = p.give_up(reason);
                    self.finish(id, outcome);
                }
            }
        }
    }

    /// The timeout for the given attempt: the destination's RTO, backed off per earlier attempt.
    pub(super) fn rto_for(&self, to: SystemId, attempt: u32) -> Duration {
        let t = self.config.timing;
        let base = self.rtt.get(&to).map(|r| r.rto()).unwrap_or(t.initial_rto);
        let factor = t
            .backoff
            .max(1.0)
            .powi(attempt.saturating_sub(1).min(30) as i32);
        base.mul_f64(factor).min(t.max_rto).max(t.min_rto)
    }

    pub(super) fn finish(&mut self, id: SendId, outcome: Outcome) {
        if let Some(p) = self.pending.remove(&id) {
            if let Some(t) = self.towards.get_mut(&id.to) {
                t.pending -= 1;
            }
            // Its retransmission timer would only wake the driver for nothing.
            if let Some(deadline) = p.deadline {
                self.timers.remove(&(deadline, id));
            }
            if let Some(frame) = p.frame {
                self.recycle(frame);
            }
            match outcome {
                Outcome::Delivered { .. } => self.stats.delivered += 1,
                Outcome::Sent { .. } => self.stats.sent += 1,
                Outcome::Unconfirmed { .. } => self.stats.unconfirmed += 1,
                Outcome::Failed { .. } => self.stats.failed += 1,
            }
            self.events.push_back(Event::Outcome {
                id,
                token: p.token,
                outcome,
            });
        }
    }
}

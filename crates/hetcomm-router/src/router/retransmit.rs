//! Transmitting: link results, retransmission after a timeout and giving up.

use super::*;

impl<T> Router<T> {
    /// The next frame to put on a link. `now` is when the driver hands it to the link: an
    /// acknowledgement may come back before [`Router::transmit_result`] is called (an
    /// in-process link delivers synchronously), and is accepted.
    pub fn poll_transmit(&mut self, now: Time) -> Option<Transmit> {
        while let Some(item) = self.transmits.pop_front() {
            match item {
                TransmitItem::Ack {
                    link,
                    header,
                    status,
                    first,
                } => {
                    let mut payload = [0u8; 9];
                    let len = AckPayload { status, first }.write(header.seq, &mut payload);
                    self.stats.ack_frames_sent += 1;
                    return Some(Transmit {
                        link,
                        to: header.destination.system,
                        frame: wire::encode(&header, &payload[..len]),
                        send: None,
                        probe: None,
                        presettled: false,
                    });
                }
                TransmitItem::Broadcast(b) => match self.poll_broadcast(now, b) {
                    Some(tx) => return Some(tx),
                    None => continue,
                },
                TransmitItem::Probe { id, path } => match self.probe_frame(id, path) {
                    Some(tx) => return Some(tx),
                    None => continue,
                },
                TransmitItem::Send(id) => {
                    // A send may have ended (acknowledged) while queued for retransmission.
                    let Some(p) = self.pending.get_mut(&id) else {
                        continue;
                    };
                    let (taken, unbuilt) = (p.frame.take(), p.unbuilt);
                    let taken = match taken {
                        // A broadcast share's first retransmission: a copy for it alone.
                        None if unbuilt => self.broadcast_copy(now, id),
                        taken => taken,
                    };
                    let Some(mut frame) = taken else {
                        continue;
                    };
                    let Some(p) = self.pending.get(&id) else {
                        continue;
                    };
                    let written_for = p.route.link;
                    // After a failover, or a timeout that sends it on an alternate path, the
                    // frame leaves on another path than it was written for: rewrite it for
                    // the path it takes now.
                    let (timed_out, to_untried) = (p.timed_out, p.to_untried);
                    let next = self.next_path(id.to, written_for, timed_out, to_untried, p.tried);
                    let moved = next.filter(|c| c.link != written_for);
                    if let Some(current) = moved {
                        frame = self.frame_for_path(&current, frame);
                    }
                    let Some(p) = self.pending.get_mut(&id) else {
                        continue;
                    };
                    if let Some(current) = moved {
                        p.route.link = current.link;
                        p.route.tag = current.tag;
                    }
                    p.attempts += 1;
                    p.timed_out = false;
                    p.to_untried = false;
                    p.tried |= link_bit(p.route.link);
                    p.first_sent.get_or_insert(now);
                    p.offered = now;
                    self.stats.transmissions += 1;
                    if p.attempts > 1 {
                        self.stats.retransmissions += 1;
                    }
                    // What the link's `Ok` would do, done now (see `Transmit::presettled`):
                    // nothing else to judge while every path is healthy, and a send that waits
                    // for a secure session takes the longer way.
                    let presettled =
                        p.route.acknowledged && p.session_waits == 0 && self.unhealthy_paths == 0;
                    let (link, attempts) = (p.route.link, p.attempts);
                    if presettled {
                        let deadline = now + self.rto_for(id.to, link, attempts);
                        if let Some(p) = self.pending.get_mut(&id) {
                            p.presettled_from = Some(p.transmitted);
                            p.transmitted = true;
                            p.awaiting_ack = true;
                            p.deadline = Some(deadline);
                            self.timers.insert((deadline, Timer::Retransmit(id)));
                        }
                    }
                    return Some(Transmit {
                        link,
                        to: id.to,
                        frame,
                        send: Some(id),
                        probe: None,
                        presettled,
                    });
                }
            }
        }
        None
    }

    /// Reports what the link did with a frame from [`Router::poll_transmit`], handing the
    /// frame back (the router keeps it for retransmission).
    pub fn transmit_result(&mut self, now: Time, tx: Transmit, result: Result<(), TransmitError>) {
        if tx.to == TO_ALL_SYSTEM {
            return self.broadcast_result(now, tx, result);
        }
        self.path_result(now, tx.to, tx.link, &result);
        if let Some(id) = tx.probe {
            // A copy of the message left on the probed path: giving up on it is unconfirmed
            // from now on (the copy may arrive), never failed.
            if let (Some(p), true) = (self.pending.get_mut(&id), result.is_ok()) {
                p.transmitted = true;
            }
            return self.recycle(tx.frame);
        }
        let Some(id) = tx.send else { return };
        let Some(p) = self.pending.get_mut(&id) else {
            return self.recycle(tx.frame); // already ended (an ack overtook the result)
        };
        p.frame = Some(tx.frame);
        if let Some(transmitted) = p.presettled_from.take() {
            if result.is_ok() {
                return; // settled when it was handed out
            }
            // Refused after all: undo what `poll_transmit` assumed, then settle as usual.
            p.transmitted = transmitted;
            if let Some(deadline) = p.deadline.take() {
                self.timers.remove(&(deadline, Timer::Retransmit(id)));
            }
        }
        self.settle(now, id, tx.link, result);
    }

    /// What the link did with an attempt of send `id` on `link`: arms its retransmission,
    /// retries after a refusal, or ends it.
    pub(super) fn settle(
        &mut self,
        now: Time,
        id: SendId,
        link: usize,
        result: Result<(), TransmitError>,
    ) {
        let Some(attempts) = self.pending.get(&id).map(|p| p.attempts) else {
            return;
        };
        let rto = self.rto_for(id.to, link, attempts);
        // A refusal may just have taken the path down and moved the route: then the retry goes
        // on the new path at once rather than after the link's back-off. (Looked up only on a
        // refusal: a frame the link took needs nothing of the route.)
        let moved = result.is_err() && self.route_link(id.to).is_some_and(|l| l != link);
        let Some(p) = self.pending.get_mut(&id) else {
            return;
        };
        if result.is_ok() {
            p.transmitted = true;
        }
        p.awaiting_ack = result.is_ok() && p.route.acknowledged;
        if let Err(err @ TransmitError::NoSession(_)) = result {
            return self.wait_for_session(now, id, link, err);
        }
        p.session_waits = 0;
        match result {
            Ok(()) => {
                if p.route.acknowledged {
                    let deadline = now + rto;
                    p.deadline = Some(deadline);
                    self.timers.insert((deadline, Timer::Retransmit(id)));
                } else {
                    let attempts = p.attempts;
                    self.finish(id, Outcome::Sent { attempts });
                }
            }
            Err(err @ (TransmitError::TooLarge(_) | TransmitError::Refused(_))) => {
                let outcome = p.give_up(err.into());
                self.finish(id, outcome);
            }
            Err(err) => {
                // Its frame did not get through: on a route the router judges, the retry
                // goes on another healthy path when there is one, as after a timeout.
                p.timed_out = true;
                let left = p.attempts < p.route.attempts;
                if !left && !self.untried_path(id) {
                    if let Some(p) = self.pending.get(&id) {
                        let outcome = p.give_up(err.into());
                        self.finish(id, outcome);
                    }
                    return;
                }
                let Some(p) = self.pending.get_mut(&id) else {
                    return;
                };
                let factor = 1u32 << p.attempts.saturating_sub(1).min(16);
                let deadline = if moved {
                    now
                } else {
                    now + self.config.timing.link_retry * factor
                };
                p.deadline = Some(deadline);
                self.timers.insert((deadline, Timer::Retransmit(id)));
            }
        }
    }

    /// The link refused an offer of send `id` for want of a secure session: nothing left, the
    /// frame waits for the handshake. It goes when the session is up ([`Router::session_up`]),
    /// else after a round trip's wait, while the budget lasts; then the send gives up with
    /// every offer counted as an attempt.
    fn wait_for_session(&mut self, now: Time, id: SendId, link: usize, err: TransmitError) {
        let Some(p) = self.pending.get_mut(&id) else {
            return;
        };
        p.attempts -= 1;
        p.session_waits += 1;
        let offers = p.attempts + p.session_waits;
        // The last offer of the budget still gets its round trip's wait for the session, as
        // a frame that left gets its wait for an acknowledgement: a handshake that needs a
        // reconnection (the peer's old connection to a restarted sender is gone) takes longer
        // than the first offers' waits. Past it the send gives up, every offer counted.
        if offers > p.route.attempts {
            p.attempts = p.route.attempts;
            let outcome = p.give_up(err.into());
            return self.finish(id, outcome);
        }
        // The session may have come up between the link's refusal and this report of it (the
        // handshake's answer is read on another thread): then the frame goes now.
        let offered = p.offered;
        let up_since = self
            .session_up_at
            .get(&id.to)
            .is_some_and(|&t| t >= offered);
        let deadline = if up_since {
            now
        } else {
            now + self.rto_for(id.to, link, offers)
        };
        if let Some(p) = self.pending.get_mut(&id) {
            p.deadline = Some(deadline);
            self.timers.insert((deadline, Timer::Retransmit(id)));
        }
    }

    /// A link now has a secure session with `peer`: sends whose frames waited for it go now
    /// instead of at their deadlines.
    pub(super) fn session_up(&mut self, now: Time, peer: SystemId) {
        self.session_up_at.insert(peer, now);
        let waiting: Vec<SendId> = self
            .pending
            .iter()
            .filter(|(id, p)| id.to == peer && p.session_waits > 0 && p.deadline.is_some())
            .map(|(id, _)| *id)
            .collect();
        for id in waiting {
            if let Some(deadline) = self.pending.get_mut(&id).and_then(|p| p.deadline.take()) {
                self.timers.remove(&(deadline, Timer::Retransmit(id)));
                self.transmits.push_back(TransmitItem::Send(id));
            }
        }
    }

    /// A probe of `path` towards `id.to`: a copy of send `id`'s frame written for that path,
    /// handed out like an acknowledgement (its link's answer is not needed: the path is
    /// judged by the acknowledgement that comes back on it). None when the send ended or its
    /// frame is out with the driver.
    fn probe_frame(&mut self, id: SendId, path: Path) -> Option<Transmit> {
        let p = self.pending.get(&id)?;
        let frame = p.frame.clone()?;
        let route = Route {
            link: path.link,
            tag: path.tag,
            ..p.route
        };
        let frame = self.frame_for_path(&route, frame);
        self.stats.probes += 1;
        Some(Transmit {
            link: path.link,
            to: id.to,
            frame,
            send: None,
            probe: Some(id),
            presettled: false,
        })
    }

    pub(super) fn finish(&mut self, id: SendId, outcome: Outcome) {
        if let Some(p) = self.pending.remove(&id) {
            if let Some(t) = self.towards.get_mut(&id.to) {
                t.pending -= 1;
                t.pending_bytes -= p.bytes;
            }
            // Its retransmission timer would only wake the driver for nothing.
            if let Some(deadline) = p.deadline {
                self.timers.remove(&(deadline, Timer::Retransmit(id)));
            }
            if let Some(frame) = p.frame {
                self.recycle(frame);
            }
            if let Some(b) = p.broadcast {
                self.broadcast_share_ended(b);
            }
            match outcome {
                Outcome::Delivered { .. } => self.stats.delivered += 1,
                Outcome::Sent { .. } | Outcome::Relayed { .. } => self.stats.sent += 1,
                Outcome::Unconfirmed { .. } => self.stats.unconfirmed += 1,
                Outcome::Failed { .. } => self.stats.failed += 1,
            }
            let path = (p.attempts > 0 || p.transmitted).then(|| p.route.path());
            self.events.push_back(Event::Outcome {
                id,
                token: p.token,
                outcome,
                path,
            });
        }
    }
}

//! Paths to each destination: their health, link events, and failover between them.
//!
//! A route has its own path first and may have fallbacks ([`RouterConfig::fallbacks`]).
//! Sends take the first path that is up (and not congested); a path goes down when its link
//! says the peer is gone ([`LinkEvent::PeerDown`]) or refuses a frame as unreachable, and
//! comes back when its link says the peer is up, takes a frame, or delivers a frame from it.
//! Each change of the path sends take is counted and reported ([`Router::poll_path_change`]).
//! A frame is written for the path it leaves on (tag and checksum flags), so a retransmission
//! after a failover carries the new path's tag.

use super::*;

impl<T> Router<T> {
    /// Tells the router what a link knows about a peer. A peer going down on the active path
    /// moves the destination's sends to the next path that is up (if any) and retransmits
    /// its unacknowledged sends there at once; a path coming back up is taken again when it
    /// comes first.
    pub fn handle_link_event(&mut self, now: Time, event: LinkEvent) {
        match event {
            LinkEvent::PeerUp { link, peer } => {
                self.set_path_health(now, peer, link, true, false);
                self.session_up(now, peer);
            }
            LinkEvent::PeerDown { link, peer } => {
                self.set_path_health(now, peer, link, false, false)
            }
            LinkEvent::Congested { link, peer } => {
                self.set_path_health(now, peer, link, true, true)
            }
        }
    }

    /// The next change of the path a destination's sends take.
    pub fn poll_path_change(&mut self) -> Option<PathChange> {
        self.path_changes.pop_front()
    }

    /// A frame from `peer` arrived on `link`: that path works (cheap unless some path is
    /// marked unhealthy).
    pub(super) fn path_heard(&mut self, now: Time, peer: SystemId, link: usize) {
        if self.unhealthy_paths > 0 {
            self.set_path_health(now, peer, link, true, false);
        }
    }

    /// What a link's answer to a frame says about its path.
    pub(super) fn path_result(
        &mut self,
        now: Time,
        peer: SystemId,
        link: usize,
        result: &Result<(), TransmitError>,
    ) {
        match result {
            Ok(()) => {
                if self.unhealthy_paths > 0 {
                    self.set_path_health(now, peer, link, true, false);
                }
            }
            Err(TransmitError::Unreachable(_)) => {
                self.set_path_health(now, peer, link, false, false)
            }
            Err(TransmitError::Congested(_)) => self.set_path_health(now, peer, link, true, true),
            // A missing session says nothing about the path: the handshake runs on it.
            Err(
                TransmitError::TooLarge(_) | TransmitError::Other(_) | TransmitError::NoSession(_),
            ) => {}
        }
    }

    /// Records a path's health and moves the destination's sends to its best path.
    fn set_path_health(&mut self, now: Time, to: SystemId, link: usize, up: bool, congested: bool) {
        let Some(r) = self.routes.get_mut(&to) else {
            return;
        };
        let Some(p) = r.path_mut(link) else {
            return;
        };
        let was_healthy = p.up && !p.congested;
        p.up = up;
        p.congested = congested;
        let healthy = up && !congested;
        match (was_healthy, healthy) {
            (true, false) => self.unhealthy_paths += 1,
            (false, true) => self.unhealthy_paths -= 1,
            _ => {}
        }
        let best = r.best();
        if best == r.active {
            return;
        }
        let from = r.paths[r.active].path;
        let failed_over = !r.paths[r.active].up;
        r.active = best;
        let change = PathChange {
            to,
            from,
            now: r.paths[best].path,
        };
        self.stats.path_changes += 1;
        self.path_changes.push_back(change);
        if failed_over {
            self.retransmit_now(now, to);
        }
    }

    /// Sends to `to` that wait for an acknowledgement or a retry go again now (on the path
    /// just taken), while attempts remain.
    fn retransmit_now(&mut self, now: Time, to: SystemId) {
        let waiting: Vec<(SendId, Time)> = self
            .pending
            .iter()
            .filter(|(id, p)| {
                id.to == to && (p.frame.is_some() || p.unbuilt) && p.attempts < p.route.attempts
            })
            .filter_map(|(id, p)| p.deadline.map(|d| (*id, d)))
            .collect();
        for (id, deadline) in waiting {
            self.timers.remove(&(deadline, Timer::Retransmit(id)));
            if let Some(p) = self.pending.get_mut(&id) {
                p.deadline = Some(now);
            }
            self.timers.insert((now, Timer::Retransmit(id)));
        }
    }

    /// Rewrites a kept frame for the path it leaves on now, when that is not the path it was
    /// written for (after a failover): the header's tag and checksum flag are the path's.
    pub(super) fn frame_for_path(&self, route: &Route, frame: Vec<u8>) -> Vec<u8> {
        let Ok(decoded) = wire::decode(&frame) else {
            return frame; // our own frame: cannot happen; sent as it is
        };
        let mut header = decoded.header;
        header.transport = route.tag;
        header.flags &= !FLAG_HEADER_CRC;
        if self.link_checksums_payload(route.link) {
            header.flags |= FLAG_HEADER_CRC;
        }
        wire::encode(&header, decoded.payload)
    }

    /// `route` as written for the path on `link` towards `to` (its tag), for a frame that was
    /// encoded for that path.
    pub(super) fn route_written_for(&self, to: SystemId, link: usize, route: Route) -> Route {
        let tag = self
            .routes
            .get(&to)
            .and_then(|r| r.paths.iter().find(|p| p.path.link == link))
            .map_or(route.tag, |p| p.path.tag);
        Route { link, tag, ..route }
    }

    /// The retransmission timeout for `attempt` on `link` towards `to`: that path's RTO,
    /// backed off per earlier attempt.
    pub(super) fn rto_for(&self, to: SystemId, link: usize, attempt: u32) -> Duration {
        let t = self.config.timing;
        let base = self
            .routes
            .get(&to)
            .and_then(|r| r.paths.iter().find(|p| p.path.link == link))
            .and_then(|p| p.rtt.as_ref())
            .map_or(t.initial_rto, |r| r.rto());
        let factor = t
            .backoff
            .max(1.0)
            .powi(attempt.saturating_sub(1).min(30) as i32);
        base.mul_f64(factor).min(t.max_rto).max(t.min_rto)
    }

    /// Feeds a round-trip sample to the path on `link` towards `to`.
    pub(super) fn rtt_sample(&mut self, to: SystemId, link: usize, sample: Duration) {
        let t = self.config.timing;
        if let Some(p) = self.routes.get_mut(&to).and_then(|r| r.path_mut(link)) {
            p.rtt
                .get_or_insert_with(|| RttEstimator::new(t.initial_rto, t.min_rto, t.max_rto))
                .sample(sample);
        }
    }
}

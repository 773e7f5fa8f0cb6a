//! Paths to each destination: their health, link events, and failover between them.
//!
//! A route has its own path first and may have fallbacks ([`RouterConfig::fallbacks`]).
//! Sends take the first path that is up (and not congested); a path goes down when its link
//! says the peer is gone ([`LinkEvent::PeerDown`]) or refuses a frame as unreachable, and
//! comes back when its link says the peer is up, takes a frame, or delivers a frame from it.
//! Under [`Health::failover`] the router also judges paths from what it sees (a run of
//! unconfirmed sends or link errors takes a path down; a path that is down is probed and
//! comes back after several acknowledgements on it and its hold time), and a send whose
//! acknowledgement timed out sends its next frame on another healthy path (SCTP's rule,
//! RFC 4960 s6.4), getting a budget there when its own is spent; see `docs/failover.md`. Each change of the path sends take is counted and reported
//! ([`Router::poll_path_change`]). A frame is written for the path it leaves on (tag and
//! checksum flags), so a retransmission after a failover carries the new path's tag.

use super::*;

/// Path changes kept for [`Router::poll_path_change`]; older ones are dropped (still counted
/// in [`RouterStats::path_changes`]).
pub const PATH_CHANGES_KEPT: usize = 1024;

/// What was seen of a path, as its health takes it.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub(super) enum Sign {
    /// Its link said the peer is gone, or refused a frame as unreachable (`refused`).
    Down { refused: bool },
    /// Its link said the peer is up.
    Up,
    /// Its link refused a frame as congested.
    Congested,
    /// Its link took a frame.
    Taken,
    /// A frame from the peer arrived on it (`ack`: an acknowledgement, which answers a frame
    /// sent on it and so proves both directions).
    Heard { ack: bool },
    /// A send's acknowledgement did not come back in time (`offered`: when its last frame
    /// left), or its link failed otherwise (`offered` is now).
    Unconfirmed { offered: Time },
}

impl<T> Router<T> {
    /// Tells the router what a link knows about a peer. A peer going down on the active path
    /// moves the destination's sends to the next path that is up (if any) and retransmits
    /// its unacknowledged sends there at once; a path coming back up is taken again when it
    /// comes first (under [`Health::failover`], once its hysteresis allows).
    pub fn handle_link_event(&mut self, now: Time, event: LinkEvent) {
        match event {
            LinkEvent::PeerUp { link, peer } => {
                self.path_sign(now, peer, link, Sign::Up);
                self.session_up(now, peer);
            }
            LinkEvent::PeerDown { link, peer } => {
                self.path_sign(now, peer, link, Sign::Down { refused: false })
            }
            LinkEvent::Congested { link, peer } => self.path_sign(now, peer, link, Sign::Congested),
        }
    }

    /// The next change of the path a destination's sends take.
    pub fn poll_path_change(&mut self) -> Option<PathChange> {
        self.path_changes.pop_front()
    }

    /// Replaces the paths to `to` while running, in order of preference: the first becomes
    /// the route's own, the rest its fallbacks; the route's delivery settings stay. A path
    /// kept keeps what the router knows of it (health, RTT); a new one starts up. Sends take
    /// the best path at once: a change is reported ([`Router::poll_path_change`]) and, when
    /// the path they took is gone or down, sends waiting for an acknowledgement go again on
    /// the new one. Returns false (and changes nothing) when `to` has no route or `paths`
    /// is empty. Sends handed to an in-process lane ([`Router::direct_lane`]) are not
    /// affected.
    pub fn set_paths(&mut self, now: Time, to: SystemId, paths: &[Path]) -> bool {
        let health = self.config.health;
        let Some(r) = self.routes.get_mut(&to) else {
            return false;
        };
        let Some(first) = paths.first() else {
            return false;
        };
        let unhealthy = |ps: &[PathState]| ps.iter().filter(|p| !p.up || p.congested).count();
        let before = unhealthy(&r.paths) as u32;
        let old_active = r.paths[r.active].path;
        let mut old = std::mem::take(&mut r.paths);
        for path in paths {
            if r.paths.iter().any(|p| p.path.link == path.link) {
                continue;
            }
            let state = match old.iter().position(|p| p.path.link == path.link) {
                Some(i) => {
                    let mut p = old.swap_remove(i);
                    p.path = *path;
                    p
                }
                None => {
                    let mut p = PathState::new(*path);
                    p.hold = health.hold;
                    p
                }
            };
            r.paths.push(state);
        }
        r.route.link = first.link;
        r.route.tag = first.tag;
        let after = unhealthy(&r.paths) as u32;
        self.unhealthy_paths = self.unhealthy_paths - before + after;
        let kept = r.paths.iter().position(|p| p.path.link == old_active.link);
        let lost = kept.is_none_or(|i| !r.paths[i].up);
        r.active = kept.unwrap_or(0);
        r.active = r.best();
        let now_path = r.paths[r.active].path;
        if r.paths.iter().any(|p| !p.up) {
            arm_probe(r, &mut self.timers, now, to, &health);
        }
        self.judging = health.judges() && self.routes.values().any(|r| r.paths.len() > 1);
        if now_path != old_active {
            self.stats.path_changes += 1;
            if self.path_changes.len() >= PATH_CHANGES_KEPT {
                self.path_changes.pop_front();
            }
            self.path_changes.push_back(PathChange {
                to,
                from: old_active,
                now: now_path,
            });
            if lost {
                self.retransmit_now(now, to);
            }
        }
        true
    }

    /// A frame from `peer` arrived on `link`: that path works (cheap unless some path is
    /// marked unhealthy, or the router judges paths and it is an acknowledgement).
    pub(super) fn path_heard(&mut self, now: Time, peer: SystemId, link: usize, ack: bool) {
        if self.unhealthy_paths > 0 || (ack && self.judging) {
            self.path_sign(now, peer, link, Sign::Heard { ack });
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
        let sign = match result {
            Ok(()) if self.unhealthy_paths > 0 => Sign::Taken,
            Ok(()) => return,
            Err(TransmitError::Congested(_)) => Sign::Congested,
            Err(e) if e.unreachable() => Sign::Down { refused: true },
            // A missing session says nothing about the path: the handshake runs on it.
            Err(
                TransmitError::TooLarge(_)
                | TransmitError::Refused(_)
                | TransmitError::NoSession(_),
            ) => return,
            Err(_) if self.judging => Sign::Unconfirmed { offered: now },
            Err(_) => return,
        };
        self.path_sign(now, peer, link, sign);
    }

    /// Feeds what was seen of the path on `link` towards `to` to its health, and moves the
    /// destination's sends to its best path.
    pub(super) fn path_sign(&mut self, now: Time, to: SystemId, link: usize, sign: Sign) {
        let health = self.config.health;
        let Some(r) = self.routes.get_mut(&to) else {
            return;
        };
        // Only routes with a choice are judged; a route of one path keeps the original rule.
        let judged = health.judges() && r.paths.len() > 1;
        let Some(p) = r.path_mut(link) else {
            return;
        };
        let was_healthy = p.up && !p.congested;
        if judged {
            judge(p, sign, now, &health);
        } else {
            match sign {
                Sign::Down { .. } => {
                    p.up = false;
                    p.congested = false;
                }
                Sign::Up | Sign::Taken | Sign::Heard { .. } => {
                    p.up = true;
                    p.congested = false;
                }
                Sign::Congested => {
                    p.up = true;
                    p.congested = true;
                }
                Sign::Unconfirmed { .. } => {}
            }
        }
        let healthy = p.up && !p.congested;
        let went_down = judged && was_healthy && !p.up;
        match (was_healthy, healthy) {
            (true, false) => self.unhealthy_paths += 1,
            (false, true) => self.unhealthy_paths -= 1,
            _ => {}
        }
        if went_down {
            arm_probe(r, &mut self.timers, now, to, &health);
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
        let budget = r.route.attempts;
        // However often the route moves, a send's attempts stay bounded: one budget per path.
        let most = budget.saturating_mul(r.paths.len() as u32);
        self.stats.path_changes += 1;
        if self.path_changes.len() >= PATH_CHANGES_KEPT {
            // Nobody polls them: the oldest go (every change is still counted).
            self.path_changes.pop_front();
        }
        self.path_changes.push_back(change);
        if failed_over {
            if judged {
                // Sends caught on the lost path get the route's budget again on this one
                // (what was spent there says nothing about the path taken now), up to one
                // budget per path in all.
                for (id, p) in self.pending.iter_mut() {
                    if id.to == to {
                        let fresh = p.attempts.saturating_add(budget).min(most);
                        p.route.attempts = p.route.attempts.max(fresh);
                    }
                }
            }
            self.retransmit_now(now, to);
        }
    }

    /// A probe of `to`'s paths that are down fell due: one frame on each (a copy of the
    /// oldest acknowledged send waiting for its outcome), and the next probe armed while any
    /// path is down. A path whose last probe went unanswered starts its count again.
    pub(super) fn probe_due(&mut self, now: Time, to: SystemId, deadline: Time) {
        let interval = self.config.health.probe_interval;
        let Some(r) = self.routes.get_mut(&to) else {
            return;
        };
        if r.probe_at != Some(deadline) {
            return; // superseded
        }
        r.probe_at = None;
        if r.paths.iter().all(|p| p.up) {
            return;
        }
        // A send's copy probed within the interval already (see `probe_soon`).
        let recent = r
            .probed_at
            .is_some_and(|t| now.saturating_since(t) < interval);
        // The oldest waiting send whose frame the router holds (not one being transmitted).
        let waiting = |(id, p): &(&SendId, &Pending<T>)| id.to == to && p.route.acknowledged;
        let carrier = self
            .pending
            .iter()
            .filter(waiting)
            .filter(|(_, p)| p.frame.is_some())
            .map(|(id, _)| *id)
            .min();
        // With nothing waiting there is nothing to probe with: the timer stops, and the next
        // send to `to` starts it again (`probe_soon`), so an idle pair costs no wake-ups.
        if carrier.is_some() || self.pending.iter().any(|e| waiting(&e)) {
            let at = now + interval;
            r.probe_at = Some(at);
            self.timers.insert((at, Timer::Probe(to)));
        }
        if let Some(id) = carrier.filter(|_| !recent) {
            self.emit_probes(now, id);
        }
    }

    /// Probes every path of `id.to` that is down with a copy of send `id`'s frame (its
    /// frame must be with the router), ahead of anything queued. A path whose last probe went
    /// unanswered starts its count of answers again.
    fn emit_probes(&mut self, now: Time, id: SendId) {
        let Some(r) = self.routes.get_mut(&id.to) else {
            return;
        };
        r.probed_at = Some(now);
        for p in r.paths.iter_mut().filter(|p| !p.up) {
            if !p.answered {
                p.good_run = 0;
            }
            p.answered = false;
            self.transmits
                .push_front(TransmitItem::Probe { id, path: p.path });
        }
    }

    /// Send `id` was just queued while some path is unhealthy: if a path of its destination
    /// is down, its copy probes that path now when the last probe is an interval old (a pair
    /// whose sends are acknowledged faster than the interval has none waiting when the probe
    /// timer falls due), and the timer runs again if it had stopped.
    pub(super) fn probe_soon(&mut self, now: Time, id: SendId) {
        let health = self.config.health;
        let Some(r) = self.routes.get_mut(&id.to) else {
            return;
        };
        if r.paths.len() < 2 || r.paths.iter().all(|p| p.up) {
            return;
        }
        arm_probe(r, &mut self.timers, now, id.to, &health);
        let due = r
            .probed_at
            .is_none_or(|t| now.saturating_since(t) >= health.probe_interval);
        if due && !health.probe_interval.is_zero() {
            self.emit_probes(now, id);
        }
    }

    /// Where the next frame of a send to `to` goes, whose last frame was written for `last`:
    /// the active path, or after a timeout on a route the router judges, an alternate one
    /// ([`RouteState::retry_path`]); the route's settings on that path.
    pub(super) fn next_path(
        &self,
        to: SystemId,
        last: usize,
        timed_out: bool,
        to_untried: bool,
        tried: u64,
    ) -> Option<Route> {
        let r = self.routes.get(&to)?;
        let alternate = timed_out && self.judging && r.paths.len() > 1;
        let untried = to_untried.then(|| r.untried(tried)).flatten();
        let path = match (untried, alternate) {
            (Some(path), _) => path,
            (None, true) => r.retry_path(last, tried),
            (None, false) => r.paths[r.active].path,
        };
        Some(Route {
            link: path.link,
            tag: path.tag,
            ..r.route
        })
    }

    /// Send `id`'s attempt budget is spent. When its route is judged and has a path that
    /// none of its frames took (healthy or not: a path judged down on a stall may work),
    /// the send gets the route's budget again (up to one budget per path in all) and its
    /// next frame goes there: true. Otherwise false, and the send ends. So a send does not
    /// end unconfirmed while a path that might carry it was never tried.
    pub(super) fn untried_path(&mut self, id: SendId) -> bool {
        if !self.judging {
            return false;
        }
        let (Some(r), Some(p)) = (self.routes.get(&id.to), self.pending.get_mut(&id)) else {
            return false;
        };
        let budget = r.route.attempts;
        let most = budget.saturating_mul(r.paths.len() as u32);
        if r.paths.len() < 2 || r.untried(p.tried).is_none() || p.attempts >= most {
            return false;
        }
        p.route.attempts = p.attempts.saturating_add(budget).min(most);
        p.timed_out = true;
        p.to_untried = true;
        true
    }

    /// Sends to `to` that wait for an acknowledgement or a retry go again now (on the path
    /// just taken), while attempts remain; those whose last frame left on that path and
    /// wait for its acknowledgement (sent there after a timeout) keep waiting.
    fn retransmit_now(&mut self, now: Time, to: SystemId) {
        let taken = self.route_link(to);
        let waiting: Vec<(SendId, Time)> = self
            .pending
            .iter()
            .filter(|(id, p)| {
                id.to == to && (p.frame.is_some() || p.unbuilt) && p.attempts < p.route.attempts
            })
            .filter(|(_, p)| !(p.awaiting_ack && Some(p.route.link) == taken))
            .filter_map(|(id, p)| p.deadline.map(|d| (*id, d)))
            .collect();
        for (id, deadline) in waiting {
            self.timers.remove(&(deadline, Timer::Retransmit(id)));
            if let Some(p) = self.pending.get_mut(&id) {
                p.deadline = Some(now);
                // Its next frame leaves on the path just taken: the old path's wait is over.
                p.awaiting_ack = false;
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

/// Arms `r`'s probe timer one interval from `now`, unless it is armed or probes are off.
fn arm_probe(
    r: &mut RouteState,
    timers: &mut BTreeSet<(Time, Timer)>,
    now: Time,
    to: SystemId,
    health: &Health,
) {
    if r.probe_at.is_none() && !health.probe_interval.is_zero() {
        let at = now + health.probe_interval;
        r.probe_at = Some(at);
        timers.insert((at, Timer::Probe(to)));
    }
}

/// [`Health::failover`]'s judgement of one sign on path `p`: a run of unconfirmed sends takes
/// it down; while down, acknowledgements on it (and its link's word that the peer is up)
/// count towards its return, which also waits for its hold time.
fn judge(p: &mut PathState, sign: Sign, now: Time, health: &Health) {
    match sign {
        Sign::Down { refused } => {
            if p.up {
                go_down(p, now, health);
                p.refused = refused;
            } else {
                p.good_run = 0;
                p.refused &= refused;
            }
        }
        Sign::Congested => p.congested = p.up,
        Sign::Taken => {
            p.congested = false;
            if !p.up && p.refused {
                good_sign(p, now, health);
            }
        }
        Sign::Up | Sign::Heard { ack: true } => {
            if p.up {
                p.bad_run = 0;
                p.last_bad = None;
                p.congested = false;
            } else {
                good_sign(p, now, health);
            }
        }
        // One direction only: a frame from the peer does not say ours arrive.
        Sign::Heard { ack: false } => {}
        Sign::Unconfirmed { offered } => {
            if p.up {
                // One count per round, as SCTP counts a path's timeouts (RFC 4960 s8.2):
                // sends whose frames all left before the last count timing out together (a
                // stall of this process, a burst in flight) are one sign, not many.
                let new_round = p.last_bad.is_none_or(|t| offered > t);
                if new_round {
                    p.last_bad = Some(now);
                    p.bad_run += 1;
                    if p.bad_run >= health.down_after {
                        go_down(p, now, health);
                    }
                }
            } else {
                p.good_run = 0;
            }
        }
    }
}

fn go_down(p: &mut PathState, now: Time, health: &Health) {
    // Down again soon after it came back: it flaps, and waits longer before the next return.
    let came_back = p.up_at != Time::ZERO;
    p.hold = if came_back && now.saturating_since(p.up_at) < p.hold * 2 {
        (p.hold * 2).min(health.hold * 32)
    } else {
        health.hold
    };
    p.up = false;
    p.congested = false;
    p.bad_run = 0;
    p.last_bad = None;
    p.good_run = 0;
    p.answered = false;
    p.down_at = now;
}

fn good_sign(p: &mut PathState, now: Time, health: &Health) {
    p.good_run += 1;
    p.answered = true;
    if p.good_run >= health.up_after.max(1) && now.saturating_since(p.down_at) >= p.hold {
        p.up = true;
        p.up_at = now;
        p.bad_run = 0;
        p.good_run = 0;
        p.congested = false;
    }
}

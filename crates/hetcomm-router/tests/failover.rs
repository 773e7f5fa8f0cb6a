//! Failover in virtual time, seeded: two sans-IO routers joined by two links (a fast lossy
//! one, preferred, and a slower reliable fallback), the preferred one blackholed, lost and
//! flapping while a stream of acknowledged sends runs. Each test checks every send's one
//! outcome against what entered the receiver's inbox (delivered exactly once, nothing twice),
//! the path changes and their timing, the order of delivery where asked, and the bound on
//! probes. A failing test prints its seed.

use std::cmp::Reverse;
use std::collections::{BTreeMap, BTreeSet, BinaryHeap};
use std::time::Duration;

use hetcomm_core::wire::AckStatus;
use hetcomm_core::*;
use hetcomm_router::*;
use rand::{Rng, SeedableRng};
use rand_chacha::ChaCha8Rng;

const A: SystemId = SystemId(0);
const B: SystemId = SystemId(1);
const WIFI: Path = Path { link: 0, tag: b'W' };
const WIRED: Path = Path { link: 1, tag: b'T' };
const MS: u64 = 1_000;

fn ms(n: u64) -> Time {
    Time::from_micros(n * MS)
}

fn route() -> Route {
    Route {
        link: WIFI.link,
        tag: WIFI.tag,
        acknowledged: true,
        attempts: 4,
        max_frame: 1 << 16,
        max_in_flight: 1024,
        max_in_flight_bytes: usize::MAX,
    }
}

/// What the preferred link does over time: frames sent in a window are lost (the link takes
/// them, as a UDP socket does, and nothing arrives).
#[derive(Clone, Default)]
struct Outages(Vec<(Time, Time)>);

impl Outages {
    fn down_at(&self, t: Time) -> bool {
        self.0.iter().any(|&(from, to)| t >= from && t < to)
    }
}

/// A frame in flight: (arrival, order, to router, link, bytes).
type OnWire = (Time, u64, usize, usize, Vec<u8>);

/// One world: A sends to B, B acknowledges, both with the wifi path first and the wired one
/// as fallback.
struct World {
    seed: u64,
    rng: ChaCha8Rng,
    routers: [Router<u64>; 2],
    now: Time,
    /// Frames in flight.
    wire: BinaryHeap<Reverse<OnWire>>,
    order: u64,
    /// Delays per link, and the wifi link's random loss.
    delay: [Duration; 2],
    loss: f64,
    outages: Outages,
    /// Link events to give A at given times.
    events: Vec<(Time, LinkEvent)>,
    /// What B's inbox got, in order: sequence numbers.
    inbox: Vec<u64>,
    /// Outcomes of A's sends by message number, with the path named.
    outcomes: BTreeMap<u64, (Outcome, Option<Path>, Time)>,
    /// (when, change) of A's path changes.
    changes: Vec<(Time, PathChange)>,
    /// Frames A put on each link.
    frames_on: [u64; 2],
    /// When A put a send's frame on the wired link (not probes, not acknowledgements).
    sends_on_wired: Vec<Time>,
    sent: u64,
}

impl World {
    fn new(seed: u64, ordered: bool) -> World {
        World::with_route(seed, ordered, route())
    }

    fn with_route(seed: u64, ordered: bool, route: Route) -> World {
        let health = Health::failover();
        let mut ca = RouterConfig::new(A, 1, vec![(B, route)]).with_fallback(B, WIRED);
        ca.health = health;
        let mut cb = RouterConfig::new(B, 2, vec![(A, route)]).with_fallback(A, WIRED);
        cb.health = health;
        if ordered {
            cb.ordered_sources.insert(A);
        }
        World {
            seed,
            rng: ChaCha8Rng::seed_from_u64(seed),
            routers: [Router::new(ca), Router::new(cb)],
            now: Time::ZERO,
            wire: BinaryHeap::new(),
            order: 0,
            delay: [Duration::from_millis(2), Duration::from_millis(8)],
            loss: 0.02,
            outages: Outages::default(),
            events: Vec::new(),
            inbox: Vec::new(),
            outcomes: BTreeMap::new(),
            changes: Vec::new(),
            frames_on: [0; 2],
            sends_on_wired: Vec::new(),
            sent: 0,
        }
    }

    /// Whatever a router wants done now: frames onto the wire, deliveries answered, outcomes
    /// and path changes recorded.
    fn pump(&mut self, i: usize) {
        let now = self.now;
        loop {
            let mut busy = false;
            while let Some(tx) = self.routers[i].poll_transmit(now) {
                busy = true;
                let lost = tx.link == WIFI.link
                    && (self.outages.down_at(now) || self.rng.gen_bool(self.loss));
                if i == 0 {
                    self.frames_on[tx.link] += 1;
                    if tx.link == WIRED.link && tx.send.is_some() {
                        self.sends_on_wired.push(now);
                    }
                }
                if !lost {
                    let at = now + self.delay[tx.link];
                    self.order += 1;
                    self.wire
                        .push(Reverse((at, self.order, 1 - i, tx.link, tx.frame.clone())));
                }
                if tx.send.is_some() || tx.probe.is_some() {
                    self.routers[i].transmit_result(now, tx, Ok(()));
                }
            }
            while let Some(d) = self.routers[i].poll_delivery() {
                busy = true;
                assert_eq!(i, 1, "seed {}: only B receives", self.seed);
                self.inbox.push(d.header.seq);
                if let Some(token) = d.token {
                    self.routers[i].delivery_result(now, token, AckStatus::Delivered);
                }
            }
            while let Some(Event::Outcome {
                token,
                outcome,
                path,
                ..
            }) = self.routers[i].poll_event()
            {
                busy = true;
                let earlier = self.outcomes.insert(token, (outcome, path, now));
                assert!(
                    earlier.is_none(),
                    "seed {}: send {token} ended twice",
                    self.seed
                );
            }
            while let Some(c) = self.routers[i].poll_path_change() {
                if i == 0 {
                    self.changes.push((now, c));
                }
            }
            if !busy {
                return;
            }
        }
    }

    fn send(&mut self) {
        let to = Address {
            system: B,
            module: ModuleId(0),
        };
        let req = SendRequest::new(ModuleId(0), to, MessageType(1), b"payload");
        let token = self.sent;
        self.routers[0]
            .send(self.now, req, token)
            .unwrap_or_else(|e| panic!("seed {}: send {token} refused: {e}", self.seed));
        self.sent += 1;
        self.pump(0);
    }

    /// Runs until `until`, sending one message every `every` until `stop_sending`.
    fn run(&mut self, until: Time, every: Duration, stop_sending: Time) {
        let mut next_send = Time::ZERO;
        self.events.sort_by_key(|(t, _)| *t);
        let mut events = std::mem::take(&mut self.events).into_iter().peekable();
        loop {
            let mut next = until;
            if next_send < stop_sending {
                next = next.min(next_send);
            }
            if let Some(Reverse((t, ..))) = self.wire.peek() {
                next = next.min(*t);
            }
            for r in &self.routers {
                if let Some(t) = r.poll_timeout() {
                    next = next.min(t);
                }
            }
            if let Some((t, _)) = events.peek() {
                next = next.min(*t);
            }
            if next >= until {
                self.now = until;
                return;
            }
            self.now = next.max(self.now);
            let now = self.now;
            if events.peek().is_some_and(|(t, _)| *t <= now) {
                let (_, e) = events.next().expect("peeked");
                self.routers[0].handle_link_event(now, e);
                self.pump(0);
            }
            while let Some(Reverse((t, ..))) = self.wire.peek() {
                if *t > now {
                    break;
                }
                let Some(Reverse((_, _, to, link, frame))) = self.wire.pop() else {
                    break;
                };
                self.routers[to].handle_frame(now, link, &frame);
                self.pump(to);
            }
            for i in 0..2 {
                if self.routers[i].poll_timeout().is_some_and(|t| t <= now) {
                    self.routers[i].handle_timeout(now);
                    self.pump(i);
                }
            }
            if next_send <= now && next_send < stop_sending {
                self.send();
                next_send = now + every;
            }
        }
    }

    /// Every send ended once and was delivered; B's inbox holds each exactly once.
    fn assert_every_send_delivered_exactly_once(&self) {
        let seed = self.seed;
        assert_eq!(
            self.outcomes.len() as u64,
            self.sent,
            "seed {seed}: a send without an outcome"
        );
        for (token, (outcome, path, _)) in &self.outcomes {
            assert!(
                matches!(outcome, Outcome::Delivered { .. }),
                "seed {seed}: send {token} ended {outcome}"
            );
            assert!(
                path.is_some(),
                "seed {seed}: send {token}'s outcome names no path"
            );
        }
        let distinct: BTreeSet<u64> = self.inbox.iter().copied().collect();
        assert_eq!(
            distinct.len(),
            self.inbox.len(),
            "seed {seed}: a message entered B's inbox twice"
        );
        assert_eq!(
            distinct.len() as u64,
            self.sent,
            "seed {seed}: B's inbox misses messages"
        );
        let stats = self.routers[0].stats();
        assert_eq!(stats.delivered, self.sent, "seed {seed}: {stats:?}");
        assert_eq!(stats.in_flight(), 0, "seed {seed}");
    }

    /// The paths A's outcomes name, counted, for sends that ended in `[from, to)`.
    fn outcomes_on(&self, from: Time, to: Time) -> [u64; 2] {
        let mut n = [0; 2];
        for (_, path, at) in self.outcomes.values() {
            if *at >= from && *at < to {
                if let Some(p) = path {
                    n[p.link] += 1;
                }
            }
        }
        n
    }
}

fn seeds() -> impl Iterator<Item = u64> {
    let first: u64 = std::env::var("HETCOMM_FAILOVER_FIRST_SEED")
        .ok()
        .and_then(|s| s.parse().ok())
        .unwrap_or(1);
    first..first + 8
}

#[test]
fn a_blackholed_preferred_path_fails_over_and_traffic_comes_back() {
    for seed in seeds() {
        let mut w = World::new(seed, false);
        w.outages = Outages(vec![(ms(1_000), ms(2_500))]);
        w.run(ms(6_000), Duration::from_millis(10), ms(4_000));
        w.assert_every_send_delivered_exactly_once();
        let changes: Vec<(Link, Link)> = w
            .changes
            .iter()
            .map(|(_, c)| (c.from.link, c.now.link))
            .collect();
        assert_eq!(changes, [(0, 1), (1, 0)], "seed {seed}: {:?}", w.changes);
        let (away, back) = (w.changes[0].0, w.changes[1].0);
        // Down after `down_after` rounds of unconfirmed sends: within a few timeouts.
        assert!(
            away > ms(1_000) && away < ms(1_400),
            "seed {seed}: failed over at {away:?}"
        );
        // Back once three probes were answered after the outage (and the hold time passed).
        assert!(
            back >= ms(2_500) && back < ms(2_800),
            "seed {seed}: came back at {back:?}"
        );
        assert_eq!(w.routers[0].route_link(B), Some(0), "seed {seed}");
        // Outcomes name the path that carried them: the wired one during the outage, the
        // wifi one before and after, except for a send whose wifi frame (or its
        // acknowledgement) was lost to the random loss: its retransmission took the wired
        // path, which confirmed it.
        let during = w.outcomes_on(ms(1_400), ms(2_500));
        assert_eq!(during[0], 0, "seed {seed}: {during:?}");
        assert!(during[1] > 90, "seed {seed}: {during:?}");
        let after = w.outcomes_on(ms(2_900), ms(6_000));
        assert!(after[1] < after[0] / 10, "seed {seed}: {after:?}");
        assert!(after[0] > 90, "seed {seed}: {after:?}");
        let recovered_after = w
            .outcomes
            .values()
            .filter(|(_, p, at)| *at >= ms(2_900) && *p == Some(WIRED));
        for (o, ..) in recovered_after {
            assert!(o.attempts() >= 2, "seed {seed}: on wired at once: {o}");
        }
        assert_eq!(w.routers[0].stats().path_changes, 2, "seed {seed}");
    }
}

type Link = usize;

#[test]
fn a_peer_lost_by_the_link_fails_over_at_once_and_returns_after_the_hysteresis() {
    for seed in seeds() {
        let mut w = World::new(seed, false);
        // The wifi link says B left at 1 s (and nothing arrives), and that it is back at 2 s.
        w.outages = Outages(vec![(ms(1_000), ms(2_000))]);
        w.events = vec![
            (ms(1_000), LinkEvent::PeerDown { link: 0, peer: B }),
            (ms(2_000), LinkEvent::PeerUp { link: 0, peer: B }),
        ];
        w.run(ms(5_000), Duration::from_millis(10), ms(3_500));
        w.assert_every_send_delivered_exactly_once();
        assert_eq!(w.changes.len(), 2, "seed {seed}: {:?}", w.changes);
        assert_eq!(
            w.changes[0].0,
            ms(1_000),
            "seed {seed}: at once on the event"
        );
        // A PeerUp alone does not bring it back: acknowledgements of its probes must follow.
        let back = w.changes[1].0;
        assert!(
            back > ms(2_000) && back < ms(2_300),
            "seed {seed}: came back at {back:?}"
        );
    }
}

#[test]
fn sends_in_flight_when_the_path_goes_are_recovered_on_the_next_exactly_once_and_in_order() {
    for seed in seeds() {
        // Ordered delivery at B; a dense burst in flight when the wifi path goes.
        let mut w = World::new(seed, true);
        w.loss = 0.0;
        w.outages = Outages(vec![(ms(500), ms(3_000))]);
        w.run(ms(5_000), Duration::from_millis(1), ms(700));
        w.assert_every_send_delivered_exactly_once();
        let sorted = {
            let mut s = w.inbox.clone();
            s.sort_unstable();
            s
        };
        assert_eq!(w.inbox, sorted, "seed {seed}: delivered out of order");
        // The sends that were on the wifi path when it went: their frames left on it, were
        // lost, and their outcomes name the wired path that carried them.
        let recovered = w
            .outcomes
            .values()
            .filter(|(o, p, _)| o.attempts() > 1 && *p == Some(WIRED))
            .count();
        assert!(recovered > 5, "seed {seed}: {recovered} recovered");
        assert_eq!(w.routers[1].stats().gaps_skipped, 0, "seed {seed}");
    }
}

#[test]
fn probes_of_a_path_that_is_down_are_bounded_by_the_probe_interval() {
    for seed in seeds() {
        let mut w = World::new(seed, false);
        w.outages = Outages(vec![(ms(500), ms(10_500))]);
        w.run(ms(11_000), Duration::from_millis(10), ms(11_000));
        w.assert_every_send_delivered_exactly_once();
        let probes = w.routers[0].stats().probes;
        eprintln!("seed {seed}: {probes} probes, frames {:?}", w.frames_on);
        let interval = Health::failover().probe_interval;
        // At most one probe per interval from when the path went down (after 0.5 s) to the
        // end of the run, and steadily one per interval while it is down.
        let bound = (Duration::from_millis(10_500).as_micros() / interval.as_micros()) as u64 + 1;
        assert!(
            probes >= bound * 9 / 10,
            "seed {seed}: {probes} probes, bound {bound}"
        );
        assert!(
            probes <= bound,
            "seed {seed}: {probes} probes, bound {bound}"
        );
        // One frame per probe on the wifi link while it is down, besides what left on it
        // before it was judged down.
        assert!(
            w.frames_on[0] < 50 + bound + 600,
            "seed {seed}: {:?}",
            w.frames_on
        );
    }
}

#[test]
fn a_flapping_path_does_not_make_traffic_flap() {
    for seed in seeds() {
        let mut w = World::new(seed, false);
        // Up 300 ms, down 300 ms, for 12 s: twenty outages.
        w.outages = Outages(
            (0..20)
                .map(|k| (ms(1_000 + 600 * k), ms(1_300 + 600 * k)))
                .collect(),
        );
        w.run(ms(15_000), Duration::from_millis(10), ms(13_000));
        w.assert_every_send_delivered_exactly_once();
        let changes = w.changes.len();
        eprintln!(
            "seed {seed}: {changes} path changes, hold now {:?}",
            w.routers[0].paths(B)[0].hold
        );
        // Undamped, the route would follow every outage (40 changes); the hold time doubles
        // while the path flaps, so it stays on the fallback for most of it.
        assert!(
            changes <= 12,
            "seed {seed}: {changes} path changes: {:?}",
            w.changes
        );
        assert!(changes >= 2, "seed {seed}");
        assert!(
            w.routers[0].paths(B)[0].hold > Health::failover().hold,
            "seed {seed}: the hold time grew"
        );
    }
}

#[test]
fn a_route_with_one_path_is_not_judged() {
    // The same lossy schedule with outages on a route without a fallback, judged and not:
    // the same outcomes, no path change, no probe (the original rule holds for one path).
    let run = |health: Health| {
        let mut cfg = RouterConfig::new(A, 1, vec![(B, route())]);
        cfg.health = health;
        let mut w = World::new(7, false);
        w.routers[0] = Router::new(cfg);
        w.loss = 0.1;
        w.outages = Outages(vec![(ms(1_000), ms(1_200)), (ms(2_000), ms(2_030))]);
        w.run(ms(4_000), Duration::from_millis(10), ms(3_000));
        assert!(w.changes.is_empty());
        assert_eq!(w.routers[0].stats().probes, 0);
        (w.outcomes, w.inbox, w.routers[0].stats())
    };
    let judged = run(Health::failover());
    let original = run(Health::default());
    assert!(
        judged.0.values().any(|(o, ..)| o.is_unconfirmed()),
        "the outage costs sends"
    );
    assert_eq!(judged, original);
}

#[test]
fn a_send_whose_acknowledgement_times_out_goes_on_the_alternate_path_at_once() {
    // SCTP's rule (RFC 4960 s6.4): the retransmission after a timeout takes the other healthy
    // path, so the first frame on the fallback leaves one retransmission timeout after the
    // cut, long before the path is judged down; the path is judged down after `down_after`
    // rounds of timeouts. Dense sends, in order at B, none lost to the cut.
    for seed in seeds() {
        let mut w = World::new(seed, true);
        w.loss = 0.0;
        let cut = ms(500);
        w.outages = Outages(vec![(cut, ms(3_000))]);
        w.run(cut, Duration::from_millis(1), ms(700));
        let rto = w.routers[0].paths(B)[0].rto;
        w.run(ms(5_000), Duration::from_millis(1), ms(700));
        w.assert_every_send_delivered_exactly_once();
        let first = w
            .sends_on_wired
            .iter()
            .copied()
            .find(|&t| t >= cut)
            .unwrap_or_else(|| panic!("seed {seed}: nothing went on the wired path"));
        // The first frame lost left at the cut at the latest (one every millisecond): its
        // timeout, and its retransmission on the wired path, come one RTO after it.
        let since = first.saturating_since(cut);
        assert!(
            since <= rto + Duration::from_millis(1),
            "seed {seed}: first on wired {since:?} after the cut, RTO {rto:?}"
        );
        // Judged down after `down_after` rounds of timeouts without an acknowledgement on it.
        let (away, change) = w.changes[0];
        assert_eq!((change.from, change.now), (WIFI, WIRED), "seed {seed}");
        let judged = away.saturating_since(cut);
        let rounds = Health::failover().down_after;
        assert!(
            judged >= rto * rounds && judged <= (rto + Duration::from_millis(2)) * (rounds + 1),
            "seed {seed}: judged down {judged:?} after the cut, RTO {rto:?}"
        );
        assert!(first < away, "seed {seed}: on wired only once judged down");
        let mut sorted = w.inbox.clone();
        sorted.sort_unstable();
        assert_eq!(w.inbox, sorted, "seed {seed}: delivered out of order");
        assert_eq!(w.routers[1].stats().gaps_skipped, 0, "seed {seed}");
        // Every send caught by the cut (its first frame lost) was confirmed by the wired path.
        let caught = w
            .outcomes
            .values()
            .filter(|(o, p, _)| o.attempts() > 1 && *p == Some(WIRED))
            .count();
        assert!(caught >= 3, "seed {seed}: {caught} caught");
    }
}

#[test]
fn a_send_whose_budget_is_spent_still_tries_a_path_it_never_took() {
    // One attempt per send and a lossy preferred path: each lost frame would end its send
    // unconfirmed with a path left untried. It goes on the wired path instead, and single
    // losses (an acknowledgement in between) do not take the wifi path down.
    for seed in seeds() {
        let one = Route {
            attempts: 1,
            ..route()
        };
        let mut w = World::with_route(seed, false, one);
        w.loss = 0.05;
        w.run(ms(4_000), Duration::from_millis(10), ms(3_000));
        w.assert_every_send_delivered_exactly_once();
        assert!(w.changes.is_empty(), "seed {seed}: {:?}", w.changes);
        let on_wired: Vec<u32> = w
            .outcomes
            .values()
            .filter(|(_, p, _)| *p == Some(WIRED))
            .map(|(o, ..)| o.attempts())
            .collect();
        assert!(on_wired.len() >= 5, "seed {seed}: {on_wired:?}");
        assert!(
            on_wired.iter().all(|&a| a == 2),
            "seed {seed}: one frame lost on wifi, one on wired: {on_wired:?}"
        );
    }
}

#[test]
fn a_send_ends_unconfirmed_once_every_path_was_tried() {
    // Both paths blackholed: the budget is one per path, then the send ends unconfirmed
    // (its frames left: they may have arrived), never delivered, with both paths tried.
    let one = Route {
        attempts: 1,
        ..route()
    };
    let mut w = World::with_route(3, false, one);
    w.loss = 0.0;
    w.delay = [Duration::from_millis(2), Duration::from_millis(8)];
    w.run(ms(1_000), Duration::from_millis(10), ms(1_000));
    let sent_before = w.sent;
    // From now on nothing arrives on either path: wired frames are dropped by making them
    // arrive never (outages cover wifi; wired is cut by its delay).
    w.outages = Outages(vec![(ms(1_000), ms(100_000))]);
    w.delay[1] = Duration::from_secs(1_000);
    w.run(ms(3_000), Duration::from_millis(10), ms(1_010));
    let last = w.sent - 1;
    assert!(w.sent > sent_before, "a send after the cut");
    let (outcome, path, _) = &w.outcomes[&last];
    assert!(outcome.is_unconfirmed(), "{outcome}");
    assert_eq!(outcome.attempts(), 2, "one attempt per path: {outcome}");
    assert!(path.is_some());
}

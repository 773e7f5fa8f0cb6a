//! A seeded world of sans-IO routers: a lossy, duplicating, reordering network between them,
//! inboxes that refuse, links that refuse, restarts — and the ground truth of what entered
//! which inbox, against which every outcome is judged.

use std::cmp::Reverse;
use std::collections::{BTreeMap, BTreeSet, BinaryHeap};
use std::time::Duration;

use hetcomm_core::wire::{self, AckStatus};
use hetcomm_core::*;
use hetcomm_router::*;
use rand::{Rng, SeedableRng};
use rand_chacha::ChaCha8Rng;

/// Everything that shapes one schedule. The same value always gives the same run.
#[derive(Clone, Debug, PartialEq)]
pub struct Params {
    /// Seeds every random choice of the run.
    pub seed: u64,
    /// Systems in the fleet (2 to 5), all on one shared link, every pair connected.
    pub systems: u16,
    /// Sends attempted (some are refused at admission: backpressure).
    pub sends: u32,
    /// Chance a frame (data or acknowledgement) is lost.
    pub loss: f64,
    /// Chance a frame arrives twice.
    pub duplicate: f64,
    /// Largest extra delay of a frame beyond the base delay (reorders frames), µs.
    pub jitter_us: u64,
    /// Chance a link refuses a frame (`TransmitError`): the frame does not leave.
    pub link_refusal: f64,
    /// Chance an inbox refuses a message (inbox full).
    pub inbox_refusal: f64,
    /// Chance a send names a module the destination does not have.
    pub unknown_module: f64,
    /// Chance a send is a native broadcast to every other system.
    pub broadcast: f64,
    /// Chance, per send, that a random system restarts (a new incarnation, empty state).
    pub restart: f64,
    /// Chance a send starts a burst: the next sends go out back to back.
    pub burst: f64,
    /// Largest pause between sends outside bursts, µs.
    pub send_gap_us: u64,
    /// Longest an inbox takes to say whether it took a message, µs.
    pub verdict_delay_us: u64,
    /// The receivers' duplicate window (sequence numbers remembered beyond the contiguous
    /// prefix).
    pub dedup_window: usize,
    /// Attempts per acknowledged send.
    pub attempts: u32,
    /// Sends in flight allowed per destination.
    pub max_in_flight: u32,
    /// Whether each system's routes are acknowledged, by system index (bit i); others send
    /// unacknowledged.
    pub acknowledged_mask: u32,
    /// Whether receivers deliver each sender's messages in order.
    pub ordered: bool,
    /// Whether the senders' wall clocks (which only stamp headers) are stepped by ± hours
    /// during the run, as NTP or an operator would. The routers' own time never steps.
    pub wall_steps: bool,
    /// Whether links behave as secured ones do: a data frame that wants an acknowledgement
    /// is refused (`TransmitError::NoSession`, nothing leaves) until a session with its
    /// destination exists; the refusal starts a handshake, which completes after a while
    /// (`LinkEvent::PeerUp`) or, for some pairs (a wrong key, a refusing receiver), never.
    pub sessions: bool,
    /// Whether every route has a second path (link 1, reliable) after its own (link 0), and
    /// the routers judge their paths (`Health::failover`, with short times).
    pub two_paths: bool,
    /// Whether link 0 has outages: windows in which every frame put on it is lost (the link
    /// still takes them, as a UDP socket does); for some, the link also says the peers are
    /// down at the start and up at the end (`LinkEvent::PeerDown` / `PeerUp`).
    pub outages: bool,
}

impl Params {
    /// A schedule drawn from `seed`: the parameters themselves are random too.
    pub fn random(seed: u64, sends: u32) -> Params {
        let mut rng = ChaCha8Rng::seed_from_u64(seed ^ 0x9e37_79b9_7f4a_7c15);
        let pick = |rng: &mut ChaCha8Rng, xs: &[f64]| xs[rng.gen_range(0..xs.len())];
        Params {
            seed,
            systems: rng.gen_range(2..=4),
            sends,
            loss: pick(&mut rng, &[0.0, 0.01, 0.1, 0.3]),
            duplicate: pick(&mut rng, &[0.0, 0.05, 0.2]),
            jitter_us: [0, 200, 5_000, 300_000][rng.gen_range(0..4)],
            link_refusal: pick(&mut rng, &[0.0, 0.02, 0.2]),
            inbox_refusal: pick(&mut rng, &[0.0, 0.05, 0.3]),
            unknown_module: pick(&mut rng, &[0.0, 0.02]),
            broadcast: pick(&mut rng, &[0.0, 0.1]),
            restart: pick(&mut rng, &[0.0, 0.0, 0.002]),
            burst: pick(&mut rng, &[0.0, 0.01, 0.05]),
            send_gap_us: [10, 1_000, 50_000][rng.gen_range(0..3)],
            verdict_delay_us: [0, 100, 20_000][rng.gen_range(0..3)],
            dedup_window: [2, 8, 64, 4096][rng.gen_range(0..4)],
            attempts: rng.gen_range(1..=6),
            max_in_flight: [4, 64, 1 << 16][rng.gen_range(0..3)],
            acknowledged_mask: rng.gen_range(0..32),
            ordered: rng.gen_bool(0.5),
            wall_steps: rng.gen_bool(0.5),
            sessions: rng.gen_bool(0.4),
            two_paths: rng.gen_bool(0.5),
            outages: rng.gen_bool(0.5),
        }
    }
}

/// The link every system has: one shared medium reaching every other system (the first path
/// of every route, and the one broadcasts take).
const LINK: usize = 0;
/// The second path of every route when [`Params::two_paths`]: reliable, slower.
const FALLBACK: Path = Path { link: 1, tag: b'T' };
/// Extra delay of the fallback link.
const FALLBACK_DELAY_US: u64 = 400;
/// The module every system has; sends to any other module are refused as unknown.
const MODULE: ModuleId = ModuleId(1);
const MISSING_MODULE: ModuleId = ModuleId(9);
/// Frames take this long at least.
const BASE_DELAY_US: u64 = 100;

/// What the world knows of one send (one destination's share of a broadcast is a send).
#[derive(Debug)]
struct SendRecord {
    from: u16,
    to: u16,
    tag: u64,
    acknowledged: bool,
    /// The sender's life the send belongs to; its outcome dies with it.
    life: u32,
    /// Whether a data frame of this send was taken by the link.
    data_left: bool,
    /// The destination's life when the send began.
    dest_life: u32,
    outcomes: Vec<Outcome>,
    /// The paths its outcomes named.
    paths: Vec<Option<Path>>,
    /// The links a data frame of it left on.
    left_on: BTreeSet<usize>,
}

/// A frame on the way.
#[derive(Debug, PartialEq, Eq, PartialOrd, Ord)]
struct InFlight {
    at: u64,
    order: u64,
    to: u16,
    link: usize,
    frame: Vec<u8>,
}

/// A handshake on the way: a session from `from` to `to` comes up at `at`, if both are still
/// the processes that began it.
#[derive(Debug, PartialEq, Eq, PartialOrd, Ord)]
struct Handshake {
    at: u64,
    order: u64,
    from: u16,
    to: u16,
    lives: (u32, u32),
}

/// A message an inbox took or refused, whose verdict the router has not been told yet.
#[derive(Debug, PartialEq, Eq, PartialOrd, Ord)]
struct Verdict {
    at: u64,
    order: u64,
    system: u16,
    life: u32,
    token_index: usize,
    status: u8,
}

struct System {
    router: Router<usize>,
    life: u32,
    tokens: Vec<Option<DeliveryToken>>,
}

/// The world: routers, the network between them, and the truth.
pub struct World {
    params: Params,
    rng: ChaCha8Rng,
    /// Draws for wall-clock steps, apart from `rng` (see [`Params::wall_steps`]).
    steps: ChaCha8Rng,
    now: u64,
    systems: Vec<System>,
    network: BinaryHeap<Reverse<InFlight>>,
    verdicts: BinaryHeap<Reverse<Verdict>>,
    order: u64,
    records: Vec<SendRecord>,
    /// (tag, receiving system, receiver's life) → times it entered that inbox.
    inbox: BTreeMap<(u64, u16, u32), u32>,
    /// Per system, unacknowledged messages its inbox refused in its current life (the
    /// driver's own drop count: the router never hears of them).
    refused_silently: Vec<u64>,
    /// Router calls made.
    pub events: u64,
    /// The senders' wall clock minus the routers' clock, µs (stepped when `wall_steps`).
    wall_offset: i64,
    /// Sessions up, (from, to), and handshakes under way (see [`Params::sessions`]).
    sessions: BTreeSet<(u16, u16)>,
    handshakes: BinaryHeap<Reverse<Handshake>>,
    /// Pairs whose handshakes never complete.
    refusing: BTreeSet<(u16, u16)>,
    /// Link 0's outages, (from, to) µs (see [`Params::outages`]), and those its link
    /// reports as peers down and up.
    outages: Vec<(u64, u64)>,
    /// Link events to give: (at, system, event), sorted by time, the next first.
    link_events: std::collections::VecDeque<(u64, u16, LinkEvent)>,
}

impl World {
    /// A fresh world for `params`.
    pub fn new(params: Params) -> World {
        let rng = ChaCha8Rng::seed_from_u64(params.seed);
        let mut world = World {
            systems: Vec::new(),
            refused_silently: vec![0; usize::from(params.systems)],
            steps: ChaCha8Rng::seed_from_u64(params.seed ^ 0x57e9),
            params,
            rng,
            now: 1_000,
            network: BinaryHeap::new(),
            verdicts: BinaryHeap::new(),
            order: 0,
            records: Vec::new(),
            inbox: BTreeMap::new(),
            events: 0,
            wall_offset: 1_700_000_000_000_000,
            sessions: BTreeSet::new(),
            handshakes: BinaryHeap::new(),
            refusing: BTreeSet::new(),
            outages: Vec::new(),
            link_events: Default::default(),
        };
        if world.params.outages {
            // From a stream of their own, so that the rest of the run draws what it would.
            let mut pick = ChaCha8Rng::seed_from_u64(world.params.seed ^ 0x0d7a);
            let span = u64::from(world.params.sends) * (world.params.send_gap_us / 2 + 50);
            let mut at = 1_000 + pick.gen_range(0..=span / 4 + 1);
            let mut events = Vec::new();
            for _ in 0..pick.gen_range(1..=4) {
                let len = [5_000, 50_000, 400_000][pick.gen_range(0..3)];
                world.outages.push((at, at + len));
                if pick.gen_bool(0.5) {
                    for s in 0..world.params.systems {
                        for p in (0..world.params.systems).filter(|&p| p != s) {
                            let peer = SystemId(p);
                            events.push((at, s, LinkEvent::PeerDown { link: LINK, peer }));
                            events.push((at + len, s, LinkEvent::PeerUp { link: LINK, peer }));
                        }
                    }
                }
                at += len + pick.gen_range(1_000..=span / 4 + 2_000);
            }
            events.sort_by_key(|e| e.0);
            world.link_events = events.into();
        }
        if world.params.sessions {
            let mut pick = ChaCha8Rng::seed_from_u64(world.params.seed ^ 0x5e55);
            for from in 0..world.params.systems {
                for to in 0..world.params.systems {
                    if from != to && pick.gen_bool(0.1) {
                        world.refusing.insert((from, to));
                    }
                }
            }
        }
        for s in 0..world.params.systems {
            let router = world.router(s, 1);
            world.systems.push(System {
                router,
                life: 1,
                tokens: Vec::new(),
            });
        }
        world
    }

    fn router(&self, s: u16, incarnation: u32) -> Router<usize> {
        let p = &self.params;
        let acknowledged = p.acknowledged_mask & (1 << s) != 0;
        let route = Route {
            link: LINK,
            tag: b'W',
            acknowledged,
            attempts: if acknowledged { p.attempts } else { 1 },
            max_frame: 1 << 12,
            max_in_flight: p.max_in_flight,
            max_in_flight_bytes: usize::MAX,
        };
        let routes = (0..p.systems)
            .filter(|&d| d != s)
            .map(|d| (SystemId(d), route))
            .collect();
        let mut config = RouterConfig::new(SystemId(s), incarnation, routes);
        if p.two_paths {
            config.fallbacks = (0..p.systems)
                .filter(|&d| d != s)
                .map(|d| (SystemId(d), FALLBACK))
                .collect();
            config.health = Health {
                hold: Duration::from_millis(30),
                probe_interval: Duration::from_millis(5),
                ..Health::failover()
            };
        }
        config.dedup_window = p.dedup_window;
        // Short timers keep the runs short; the hold gives up gaps the network will never fill.
        config.timing.initial_rto = Duration::from_millis(20);
        config.timing.hold_timeout = Duration::from_millis(200);
        if p.ordered {
            config.ordered_sources = (0..p.systems)
                .filter(|&o| o != s)
                .map(SystemId)
                .collect::<BTreeSet<_>>();
        }
        Router::new(config)
    }

    fn time(&self) -> Time {
        Time::from_micros(self.now)
    }

    /// Runs the whole schedule, then drains it until nothing is pending anywhere.
    pub fn run(&mut self) {
        let mut next_send = self.now;
        let mut sent = 0;
        let mut burst_left = 0u32;
        loop {
            let network = self.network.peek().map(|Reverse(f)| f.at);
            let verdict = self.verdicts.peek().map(|Reverse(v)| v.at);
            let handshake = self.handshakes.peek().map(|Reverse(h)| h.at);
            let timer = self
                .systems
                .iter()
                .filter_map(|s| s.router.poll_timeout())
                .map(Time::as_micros)
                .min();
            let send = (sent < self.params.sends).then_some(next_send);
            let event = self.link_events.front().map(|e| e.0);
            let candidates = [network, verdict, handshake, timer, send, event];
            let Some(at) = candidates.into_iter().flatten().min() else {
                return;
            };
            self.now = self.now.max(at);
            if send == Some(at) {
                sent += 1;
                self.one_send();
                if burst_left == 0 && self.rng.gen_bool(self.params.burst) {
                    burst_left = self
                        .rng
                        .gen_range(10..(3 * self.params.dedup_window as u32 + 20));
                }
                let gap = if burst_left > 0 {
                    burst_left -= 1;
                    0
                } else {
                    self.rng.gen_range(0..=self.params.send_gap_us)
                };
                next_send = self.now + gap;
                if self.rng.gen_bool(self.params.restart) {
                    let s = self.rng.gen_range(0..self.params.systems);
                    self.restart(s);
                }
            } else if network == Some(at) {
                let Reverse(f) = self.network.pop().expect("peeked");
                self.events += 1;
                let now = self.time();
                self.systems[usize::from(f.to)]
                    .router
                    .handle_frame(now, f.link, &f.frame);
                self.pump(f.to);
            } else if event == Some(at) {
                let (_, s, e) = self.link_events.pop_front().expect("peeked");
                self.events += 1;
                let now = self.time();
                self.systems[usize::from(s)]
                    .router
                    .handle_link_event(now, e);
                self.pump(s);
            } else if handshake == Some(at) {
                let Reverse(h) = self.handshakes.pop().expect("peeked");
                let lives = (
                    self.systems[usize::from(h.from)].life,
                    self.systems[usize::from(h.to)].life,
                );
                if lives == h.lives {
                    self.sessions.insert((h.from, h.to));
                    self.events += 1;
                    let now = self.time();
                    let peer = SystemId(h.to);
                    self.systems[usize::from(h.from)]
                        .router
                        .handle_link_event(now, LinkEvent::PeerUp { link: LINK, peer });
                    self.pump(h.from);
                }
            } else if verdict == Some(at) {
                let Reverse(v) = self.verdicts.pop().expect("peeked");
                let now = self.time();
                let system = &mut self.systems[usize::from(v.system)];
                if system.life != v.life {
                    continue; // the process that held it died
                }
                if let Some(token) = system.tokens[v.token_index].take() {
                    let status = AckStatus::from_u8(v.status).expect("a status we wrote");
                    self.events += 1;
                    system.router.delivery_result(now, token, status);
                    self.pump(v.system);
                }
            } else {
                let now = self.time();
                for s in 0..self.params.systems {
                    let router = &mut self.systems[usize::from(s)].router;
                    if router.poll_timeout().is_some_and(|t| t <= now) {
                        self.events += 1;
                        router.handle_timeout(now);
                        self.pump(s);
                    }
                }
            }
        }
    }

    fn one_send(&mut self) {
        let p = &self.params;
        let from = self.rng.gen_range(0..p.systems);
        let module = if self.rng.gen_bool(p.unknown_module) {
            MISSING_MODULE
        } else {
            MODULE
        };
        let tag = self.records.len() as u64;
        let payload = tag.to_le_bytes();
        // A step of the wall clock between sends: only the stamp may see it. Its draws come
        // from a stream of their own, so that a run with steps is the same run as without.
        if p.wall_steps && self.steps.gen_bool(0.01) {
            let hour = 3_600_000_000i64;
            self.wall_offset += if self.steps.gen_bool(0.5) {
                hour
            } else {
                -hour
            };
        }
        let stamp = Time::from_micros(self.now.saturating_add_signed(self.wall_offset));
        let acknowledged = p.acknowledged_mask & (1 << from) != 0;
        let life = self.systems[usize::from(from)].life;
        let now = self.time();
        let broadcast = self.rng.gen_bool(p.broadcast);
        let records = &mut self.records;
        let router = &mut self.systems[usize::from(from)].router;
        self.events += 1;
        if broadcast {
            let dests = router.broadcast_group(LINK);
            let req = SendRequest {
                broadcast: true,
                timestamp: stamp,
                ..SendRequest::new(
                    MODULE,
                    Address {
                        system: wire::TO_ALL_SYSTEM,
                        module,
                    },
                    MessageType(1),
                    &payload,
                )
            };
            let start = records.len();
            let result = router.send_broadcast(now, req, &dests, |to| {
                records.push(SendRecord {
                    from,
                    to: to.0,
                    tag,
                    acknowledged,
                    life,
                    data_left: false,
                    dest_life: 0,
                    outcomes: Vec::new(),
                    paths: Vec::new(),
                    left_on: BTreeSet::new(),
                });
                records.len() - 1
            });
            if result.is_err() {
                records.truncate(start); // refused as a whole: nothing was numbered
            }
            for r in &mut records[start..] {
                r.dest_life = self.systems[usize::from(r.to)].life;
            }
        } else {
            let mut to = self.rng.gen_range(0..p.systems - 1);
            if to >= from {
                to += 1;
            }
            let req = SendRequest {
                timestamp: stamp,
                ..SendRequest::new(
                    MODULE,
                    Address {
                        system: SystemId(to),
                        module,
                    },
                    MessageType(1),
                    &payload,
                )
            };
            let dest_life = self.systems[usize::from(to)].life;
            let router = &mut self.systems[usize::from(from)].router;
            if router.send(now, req, records.len()).is_ok() {
                records.push(SendRecord {
                    from,
                    to,
                    tag,
                    acknowledged,
                    life,
                    data_left: false,
                    dest_life,
                    outcomes: Vec::new(),
                    paths: Vec::new(),
                    left_on: BTreeSet::new(),
                });
            }
        }
        self.pump(from);
    }

    /// A system's process dies and starts again: a new incarnation with nothing remembered;
    /// its unresolved sends die with it (no outcome is expected for them).
    fn restart(&mut self, s: u16) {
        let incarnation = self.systems[usize::from(s)].life + 1;
        let router = self.router(s, incarnation);
        let system = &mut self.systems[usize::from(s)];
        system.router = router;
        system.life = incarnation;
        system.tokens.clear();
        self.refused_silently[usize::from(s)] = 0;
        // A new process has no sessions, and its peers' sessions with the old one are gone.
        self.sessions.retain(|&(a, b)| a != s && b != s);
    }

    /// Performs everything router `s` asks for after an input.
    fn pump(&mut self, s: u16) {
        let now = self.time();
        loop {
            let mut progressed = false;
            while let Some(tx) = self.systems[usize::from(s)].router.poll_transmit(now) {
                progressed = true;
                self.transmit(s, tx);
            }
            while let Some(d) = self.systems[usize::from(s)].router.poll_delivery() {
                progressed = true;
                self.deliver(s, d);
            }
            while let Some(Event::Outcome {
                token,
                outcome,
                path,
                ..
            }) = self.systems[usize::from(s)].router.poll_event()
            {
                self.records[token].outcomes.push(outcome);
                self.records[token].paths.push(path);
            }
            if !progressed {
                return;
            }
        }
    }

    fn transmit(&mut self, s: u16, tx: Transmit) {
        let p = &self.params;
        let decoded = wire::decode(&tx.frame).expect("routers write valid frames");
        let h = decoded.header;
        // A secured link keeps nothing it cannot send yet that wants an acknowledgement: it
        // refuses it and starts a handshake (unacknowledged frames and acknowledgements it
        // would hold for the session; here they pass, as if the wait were nil).
        let wants_session = p.sessions
            && h.kind == FrameKind::Data
            && h.ack_requested()
            && !h.to_all()
            && !self.sessions.contains(&(s, tx.to.0));
        if wants_session {
            let to = tx.to.0;
            let begun = self
                .handshakes
                .iter()
                .any(|Reverse(hs)| (hs.from, hs.to) == (s, to));
            if !begun && !self.refusing.contains(&(s, to)) {
                self.order += 1;
                self.handshakes.push(Reverse(Handshake {
                    at: self.now + self.rng.gen_range(200..=30_000),
                    order: self.order,
                    from: s,
                    to,
                    lives: (
                        self.systems[usize::from(s)].life,
                        self.systems[usize::from(to)].life,
                    ),
                }));
            }
            self.events += 1;
            let now = self.time();
            let refusal = TransmitError::NoSession(format!("no session with {to}"));
            self.systems[usize::from(s)]
                .router
                .transmit_result(now, tx, Err(refusal));
            return;
        }
        let refused = self.rng.gen_bool(p.link_refusal);
        if !refused && h.kind == FrameKind::Data {
            let tag = u64::from_le_bytes(decoded.payload.try_into().expect("8-byte payloads"));
            let life = self.systems[usize::from(s)].life;
            let dest = (!h.to_all()).then_some(h.destination.system.0);
            // A send's record sits at the index of its tag (a broadcast's shares after it).
            let shares = self.records[tag as usize..].iter_mut();
            for r in shares.take_while(|r| r.tag == tag) {
                if r.from == s && r.life == life && dest.is_none_or(|d| d == r.to) {
                    r.data_left = true;
                    r.left_on.insert(tx.link);
                }
            }
        }
        if !refused {
            let targets: Vec<u16> = if h.to_all() {
                (0..p.systems).filter(|&d| d != s).collect()
            } else {
                vec![tx.to.0]
            };
            // Link 0 loses what it is given during an outage; the fallback loses nothing.
            let lossy = tx.link == LINK;
            let out = lossy
                && self
                    .outages
                    .iter()
                    .any(|&(a, b)| self.now >= a && self.now < b);
            for to in targets {
                let copies = if self.rng.gen_bool(p.duplicate) { 2 } else { 1 };
                for _ in 0..copies {
                    if self.rng.gen_bool(p.loss) && lossy || out {
                        continue;
                    }
                    let extra = if lossy { 0 } else { FALLBACK_DELAY_US };
                    let at = self.now + BASE_DELAY_US + extra + self.rng.gen_range(0..=p.jitter_us);
                    self.order += 1;
                    self.network.push(Reverse(InFlight {
                        at,
                        order: self.order,
                        to,
                        link: tx.link,
                        frame: tx.frame.clone(),
                    }));
                }
            }
        }
        if tx.send.is_some() || tx.probe.is_some() {
            let result = match refused {
                false => Ok(()),
                true => Err(TransmitError::Unreachable(
                    "the oracle's link refused".into(),
                )),
            };
            self.events += 1;
            let now = self.time();
            self.systems[usize::from(s)]
                .router
                .transmit_result(now, tx, result);
        }
    }

    fn deliver(&mut self, s: u16, d: Delivery) {
        let tag = u64::from_le_bytes(d.payload[..].try_into().expect("8-byte payloads"));
        let status = if d.header.destination.module != MODULE {
            AckStatus::UnknownModule
        } else if self.rng.gen_bool(self.params.inbox_refusal) {
            AckStatus::InboxFull
        } else {
            AckStatus::Delivered
        };
        let life = self.systems[usize::from(s)].life;
        if status == AckStatus::Delivered {
            *self.inbox.entry((tag, s, life)).or_default() += 1;
        }
        match d.token {
            Some(token) => {
                let system = &mut self.systems[usize::from(s)];
                system.tokens.push(Some(token));
                let at = self.now + self.rng.gen_range(0..=self.params.verdict_delay_us);
                self.order += 1;
                self.verdicts.push(Reverse(Verdict {
                    at,
                    order: self.order,
                    system: s,
                    life,
                    token_index: system.tokens.len() - 1,
                    status: status as u8,
                }));
            }
            None if status != AckStatus::Delivered => self.refused_silently[usize::from(s)] += 1,
            None => {}
        }
    }

    /// Every false statement the run made, as sentences (empty when it told the truth).
    pub fn falsehoods(&self) -> Vec<String> {
        let mut wrong = Vec::new();
        for ((tag, s, life), n) in &self.inbox {
            if *n > 1 {
                wrong.push(format!(
                    "message {tag} entered system {s}'s inbox {n} times (life {life})"
                ));
            }
        }
        for r in &self.records {
            let alive = self.systems[usize::from(r.from)].life == r.life;
            let arrived: u32 = self
                .inbox
                .range((r.tag, r.to, 0)..=(r.tag, r.to, u32::MAX))
                .map(|(_, n)| n)
                .sum();
            let what = format!("send {} ({} → {})", r.tag, r.from, r.to);
            if !alive {
                if !r.outcomes.is_empty() && r.outcomes.len() != 1 {
                    wrong.push(format!("{what}: {} outcomes", r.outcomes.len()));
                }
                continue;
            }
            let [outcome] = r.outcomes.as_slice() else {
                wrong.push(format!("{what}: {} outcomes, not one", r.outcomes.len()));
                continue;
            };
            // A receiver that restarted forgot what its previous process took or refused (a late
            // copy may enter the new one's inbox): outcomes are then true of the process that
            // answered, which the world does not single out.
            let one_receiver = r.dest_life == self.systems[usize::from(r.to)].life;
            let lie = match outcome {
                Outcome::Delivered { .. } if !r.acknowledged => Some("delivered without an ack"),
                Outcome::Delivered { .. } if arrived == 0 => {
                    Some("delivered, but never in the inbox")
                }
                Outcome::Failed { .. } if arrived > 0 && one_receiver => {
                    Some("failed, but it is in the inbox")
                }
                Outcome::Sent { .. } if r.acknowledged => Some("sent on an acknowledged route"),
                Outcome::Unconfirmed { .. } if !r.data_left => {
                    Some("unconfirmed, but no data frame ever left")
                }
                _ => None,
            };
            if let Some(lie) = lie {
                wrong.push(format!("{what}: {lie}: {outcome:?}"));
            }
            // The path an outcome names carried it: a confirmation came back on the path a
            // copy went by, so a data frame of it left there; any outcome after a frame
            // left names a path.
            let path = r.paths.first().copied().flatten();
            let confirmed = matches!(outcome, Outcome::Delivered { .. })
                || matches!(
                    outcome.reason(),
                    Some(FailReason::InboxFull | FailReason::UnknownModule)
                );
            match path {
                Some(p) if confirmed && !r.left_on.contains(&p.link) => wrong.push(format!(
                    "{what}: {outcome:?} names link {}, but no data frame left on it ({:?})",
                    p.link, r.left_on
                )),
                None if r.data_left && !r.left_on.is_empty() => wrong.push(format!(
                    "{what}: {outcome:?} names no path, but frames left on {:?}",
                    r.left_on
                )),
                _ => {}
            }
        }
        for (i, system) in self.systems.iter().enumerate() {
            let s = system.router.stats();
            let mine = |r: &&SendRecord| usize::from(r.from) == i && r.life == system.life;
            let count = |f: fn(&Outcome) -> bool| {
                self.records
                    .iter()
                    .filter(mine)
                    .filter(|r| r.outcomes.first().is_some_and(f))
                    .count() as u64
            };
            let expected = (
                self.records.iter().filter(mine).count() as u64,
                count(|o| matches!(o, Outcome::Delivered { .. })),
                count(|o| matches!(o, Outcome::Sent { .. })),
                count(|o| matches!(o, Outcome::Unconfirmed { .. })),
                count(|o| matches!(o, Outcome::Failed { .. })),
                0,
            );
            let counted = (
                s.sends,
                s.delivered,
                s.sent,
                s.unconfirmed,
                s.failed,
                s.in_flight(),
            );
            if counted != expected {
                wrong.push(format!(
                    "system {i}: (sends, delivered, sent, unconfirmed, failed, in flight) \
                     counted {counted:?}, truth {expected:?}"
                ));
            }
            let entered: u64 = self
                .inbox
                .iter()
                .filter(|((_, to, life), _)| usize::from(*to) == i && *life == system.life)
                .map(|(_, n)| u64::from(*n))
                .sum();
            if s.received != entered + self.refused_silently[i] {
                wrong.push(format!(
                    "system {i}: received counted {}, truth {entered} in the inbox + {} \
                     refused without an acknowledgement",
                    s.received, self.refused_silently[i]
                ));
            }
        }
        wrong
    }

    /// Every outcome, in send order, and every router's counters: what a run told its users.
    pub fn told(&self) -> String {
        let outcomes: Vec<String> = self
            .records
            .iter()
            .map(|r| format!("{:?}", r.outcomes))
            .collect();
        let stats: Vec<String> = self
            .systems
            .iter()
            .map(|s| format!("{:?}", s.router.stats()))
            .collect();
        format!("{}\n{}", outcomes.join("\n"), stats.join("\n"))
    }

    /// Outcomes by kind: delivered, sent, unconfirmed, failed, and of the failed those for
    /// want of a session.
    pub fn tally(&self) -> [u64; 5] {
        let mut t = [0; 5];
        for o in self.records.iter().filter_map(|r| r.outcomes.first()) {
            let i = match o {
                Outcome::Delivered { .. } => 0,
                Outcome::Sent { .. } | Outcome::Relayed { .. } => 1,
                Outcome::Unconfirmed { .. } => 2,
                Outcome::Failed { .. } => 3,
            };
            t[i] += 1;
            if matches!(o.reason(), Some(FailReason::NoSession(_))) {
                t[4] += 1;
            }
        }
        t
    }

    /// Path changes and probes, summed over the routers (schedules with two paths).
    pub fn switching(&self) -> (u64, u64) {
        self.systems.iter().fold((0, 0), |(c, p), s| {
            let st = s.router.stats();
            (c + st.path_changes, p + st.probes)
        })
    }

    /// Sends whose outcome the world recorded.
    pub fn sends(&self) -> usize {
        self.records.len()
    }
}

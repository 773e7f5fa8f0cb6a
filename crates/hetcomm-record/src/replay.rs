//! Replaying a recording: the recorded sends (first attempts; retransmissions are the
//! router's business) sent again by the same systems and modules, with the recorded timing
//! (or scaled), into a live fleet or a simulation.

use std::collections::{HashMap, VecDeque};
use std::path::Path;
use std::time::{Duration, Instant};

use hetcomm::sim::SimFleet;
use hetcomm::{Comm, MessageType, Module, Outcome, SendOptions, Ticket, Time};

use crate::format::{Addr, Event};
use crate::reader::{read_timed, ReadError, ReadReport};

/// Which recorded sends to replay.
#[derive(Clone, Debug, Default)]
pub struct ReplayFilter {
    /// Only sends of these systems (empty: every recorded sender).
    pub systems: Vec<String>,
    /// Only sends from these modules (empty: every module).
    pub modules: Vec<String>,
    /// Replay the recorded *receipts* instead: every message a recorded system's inbox took,
    /// sent again from its recorded source, with its recorded timing. A recording of a live
    /// system (`hetcomm record`) holds only what it received; this replays that as the same
    /// messages arriving again (`systems` and `modules` then name the sources).
    pub receipts: bool,
}

impl ReplayFilter {
    /// Whether a send from `source` passes.
    pub fn accepts(&self, source: &Addr) -> bool {
        (self.systems.is_empty() || self.systems.contains(&source.system))
            && (self.modules.is_empty() || self.modules.contains(&source.module))
    }
}

/// One send to replay.
#[derive(Clone, Debug, PartialEq)]
pub struct ReplayItem {
    /// When, microseconds after the recording's origin.
    pub offset_us: u64,
    /// Sending system and module.
    pub source: Addr,
    /// Destination system and module.
    pub destination: Addr,
    /// Message type id.
    pub message_type: u32,
    /// Priority.
    pub priority: u8,
    /// The payload's bytes.
    pub payload: Vec<u8>,
}

impl ReplayItem {
    /// The item for a recorded event: a send's first attempt that passes `filter` (or, with
    /// [`ReplayFilter::receipts`], a message an inbox took). Err when its payload cannot be
    /// rebuilt.
    pub fn from_event(
        event: Event,
        origin_us: u64,
        filter: &ReplayFilter,
    ) -> Option<Result<ReplayItem, String>> {
        let (time_us, message) = match event {
            Event::Send(send) if !filter.receipts && send.attempt == 1 => {
                (send.time_us, send.message)
            }
            Event::Receipt(r) if filter.receipts && r.status == "delivered" => {
                (r.time_us, r.message)
            }
            _ => return None,
        };
        if !filter.accepts(&message.source) {
            return None;
        }
        Some(message.payload_bytes().map(|payload| ReplayItem {
            offset_us: time_us.saturating_sub(origin_us),
            payload,
            source: message.source,
            destination: message.destination,
            message_type: message.message_type,
            priority: message.priority,
        }))
    }
}

/// Every replayable send of a recording, in memory (small recordings; [`replay_sim`] and
/// [`replay_realtime`] stream instead).
pub fn load(
    path: impl AsRef<Path>,
    filter: &ReplayFilter,
) -> Result<(Vec<ReplayItem>, ReadReport, Vec<String>), ReadError> {
    let mut items = Vec::new();
    let mut errors = Vec::new();
    let report = read_timed(&path, |o, e| match ReplayItem::from_event(e, o, filter) {
        Some(Ok(i)) => items.push(i),
        Some(Err(m)) => errors.push(m),
        None => {}
    })?;
    Ok((items, report, errors))
}

/// How the replayed sends went.
#[derive(Clone, Debug, Default, PartialEq, Eq)]
pub struct ReplayStats {
    /// Sends made.
    pub sent: u64,
    /// Sends refused at once (unknown system or module in this fleet, `X` pair,
    /// backpressure); the first reason is in `first_refusal`.
    pub refused: u64,
    /// Why the first refused send was refused.
    pub first_refusal: Option<String>,
    /// Recorded sends whose payload could not be rebuilt.
    pub unreadable: u64,
    /// Outcomes: delivered.
    pub delivered: u64,
    /// Outcomes: sent without confirmation, or relayed (a broker confirmed taking it).
    pub sent_unconfirmable: u64,
    /// Outcomes: unconfirmed.
    pub unconfirmed: u64,
    /// Outcomes: failed.
    pub failed: u64,
    /// Sends whose outcome had not come when the replay ended.
    pub pending: u64,
}

/// Sends replay items through the systems of a fleet, keeping count of their outcomes.
pub struct Player {
    systems: HashMap<String, Comm>,
    modules: HashMap<(String, String), Module>,
    tickets: VecDeque<Ticket>,
    /// Counts so far.
    pub stats: ReplayStats,
}

impl Player {
    /// A player sending through `systems` (the open systems of the fleet to replay into).
    pub fn new(systems: &[Comm]) -> Player {
        Player {
            systems: systems
                .iter()
                .map(|c| (c.name().to_string(), c.clone()))
                .collect(),
            modules: HashMap::new(),
            tickets: VecDeque::new(),
            stats: ReplayStats::default(),
        }
    }

    /// Sends one item now (its timing is the caller's business).
    pub fn send(&mut self, item: &ReplayItem) {
        let key = (item.source.system.clone(), item.source.module.clone());
        let module = match self.modules.get(&key) {
            Some(m) => Ok(m),
            None => match self.systems.get(&item.source.system) {
                None => Err(format!(
                    "system {} is not open in this replay",
                    item.source.system
                )),
                Some(c) => c
                    .module(&item.source.module)
                    .map(|m| &*self.modules.entry(key).or_insert(m))
                    .map_err(|e| e.to_string()),
            },
        };
        let result = module.and_then(|m| {
            m.send_raw(
                &item.destination.system,
                &item.destination.module,
                MessageType(item.message_type),
                &item.payload,
                SendOptions::priority(item.priority),
            )
            .map_err(|e| e.to_string())
        });
        match result {
            Ok(ticket) => {
                self.stats.sent += 1;
                self.tickets.push_back(ticket);
                if self.tickets.len() > 4096 {
                    self.collect();
                }
            }
            Err(e) => {
                self.stats.refused += 1;
                self.stats.first_refusal.get_or_insert(format!(
                    "{} → {}: {e}",
                    item.source.system, item.destination.system
                ));
            }
        }
    }

    /// Counts the outcomes that have come (tickets in order; stops at the first pending one).
    pub fn collect(&mut self) {
        while let Some(t) = self.tickets.front() {
            let Some(outcome) = t.try_outcome() else {
                break;
            };
            self.count(&outcome);
            self.tickets.pop_front();
        }
    }

    fn count(&mut self, o: &Outcome) {
        match o {
            Outcome::Delivered { .. } => self.stats.delivered += 1,
            Outcome::Sent { .. } | Outcome::Relayed { .. } => self.stats.sent_unconfirmable += 1,
            Outcome::Unconfirmed { .. } => self.stats.unconfirmed += 1,
            _ => self.stats.failed += 1,
        }
    }

    /// Counts every outcome that has come; the rest are pending.
    pub fn finish(mut self) -> ReplayStats {
        for t in std::mem::take(&mut self.tickets) {
            match t.try_outcome() {
                Some(o) => self.count(&o),
                None => self.stats.pending += 1,
            }
        }
        self.stats
    }
}

/// What a replay did.
#[derive(Clone, Debug, Default)]
pub struct ReplayReport {
    /// What reading the recording found.
    pub read: ReadReport,
    /// How the sends went.
    pub stats: ReplayStats,
    /// Recorded time covered (last replayed send's offset), seconds.
    pub recorded_s: f64,
    /// Wall time the replay took.
    pub wall: Duration,
}

/// Replays into a simulation: each send at `start + offset / speed` of virtual time (`start`
/// is the simulation's time when called), then lets the simulation settle (up to 60 virtual
/// seconds) so outcomes come in.
pub fn replay_sim(
    path: impl AsRef<Path>,
    sim: &SimFleet,
    filter: &ReplayFilter,
    speed: f64,
) -> Result<ReplayReport, ReadError> {
    let wall = Instant::now();
    let start = sim.now();
    let mut player = Player::new(sim.systems());
    let mut last = 0u64;
    let read = read_timed(path, |o, e| match ReplayItem::from_event(e, o, filter) {
        Some(Ok(item)) => {
            let at = start + scaled(item.offset_us, speed);
            if at > sim.now() {
                sim.run_until(at);
                player.collect();
            }
            last = last.max(item.offset_us);
            player.send(&item);
        }
        Some(Err(_)) => player.stats.unreadable += 1,
        None => {}
    })?;
    sim.run_idle(sim.now() + Duration::from_secs(60));
    Ok(ReplayReport {
        read,
        stats: player.finish(),
        recorded_s: last as f64 / 1e6,
        wall: wall.elapsed(),
    })
}

/// Replays into live systems of this process in real time: each send at `offset / speed`
/// after the call, then waits up to `settle` for outcomes.
pub fn replay_realtime(
    path: impl AsRef<Path>,
    systems: &[Comm],
    filter: &ReplayFilter,
    speed: f64,
    settle: Duration,
) -> Result<ReplayReport, ReadError> {
    let wall = Instant::now();
    let mut player = Player::new(systems);
    let mut last = 0u64;
    let read = read_timed(path, |o, e| match ReplayItem::from_event(e, o, filter) {
        Some(Ok(item)) => {
            let due = wall + scaled(item.offset_us, speed);
            std::thread::sleep(due.saturating_duration_since(Instant::now()));
            last = last.max(item.offset_us);
            player.send(&item);
        }
        Some(Err(_)) => player.stats.unreadable += 1,
        None => {}
    })?;
    let deadline = Instant::now() + settle;
    loop {
        player.collect();
        if player.tickets.is_empty() || Instant::now() >= deadline {
            break;
        }
        std::thread::sleep(Duration::from_millis(10));
    }
    Ok(ReplayReport {
        read,
        stats: player.finish(),
        recorded_s: last as f64 / 1e6,
        wall: wall.elapsed(),
    })
}

fn scaled(offset_us: u64, speed: f64) -> Duration {
    let s = offset_us as f64 / 1e6 / speed.max(1e-9);
    Duration::try_from_secs_f64(s).unwrap_or(Duration::MAX / 4)
}

/// The time a recorded offset maps to from `start`.
pub fn at(start: Time, offset_us: u64, speed: f64) -> Time {
    start + scaled(offset_us, speed)
}

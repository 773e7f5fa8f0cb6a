//! Running the probes: which pairs run on which clock, the schedule, the echoing callbacks,
//! and turning receipt times into samples.

use std::collections::{BTreeMap, HashMap, HashSet};
use std::sync::{Arc, Mutex};
use std::time::{Duration, Instant};

use hetcomm::config::{Fleet, TransportDef, TransportKind, TransportSettings};
use hetcomm::sim::{SimFleet, SimOptions};
use hetcomm::{Comm, LocalFleet, MessageType, Module, RawMessage, SendOptions, SystemId, Time};

use super::{
    validate, Clock, Direction, Distribution, ExperimentError, LatencyConfig, LatencyReport,
    PairReport, Sample,
};

/// The probes' message type (a raw payload: sequence number, then zeros).
pub const PROBE: MessageType = MessageType(0x4C41_5450);
/// The echoes' message type (the probe's payload, sent back).
pub const ECHO: MessageType = MessageType(0x4C41_5445);

/// An ordered pair to measure.
#[derive(Clone, Debug)]
struct Pair {
    from: SystemId,
    to: SystemId,
    from_name: String,
    to_name: String,
    transport: String,
    kind: String,
    return_transport: Option<String>,
    clock: Clock,
}

fn transport_label(t: &TransportDef) -> String {
    if t.tag.is_ascii_uppercase() && t.name.len() > 1 {
        format!("{} ({})", t.name, t.tag as char)
    } else {
        t.name.clone()
    }
}

/// Every ordered pair the table connects, with the clock it runs on.
fn pairs(fleet: &Fleet, realtime: bool) -> Vec<Pair> {
    let mut out = Vec::new();
    for a in &fleet.systems {
        for b in &fleet.systems {
            if a.id == b.id {
                continue;
            }
            let Some(there) = fleet.route(a.id, b.id) else {
                continue;
            };
            let back = fleet.route(b.id, a.id);
            let emulated = |t: &TransportDef| t.kind == TransportKind::Emulated;
            let virtual_time = !realtime && emulated(there) && back.is_none_or(emulated);
            out.push(Pair {
                from: a.id,
                to: b.id,
                from_name: a.name.clone(),
                to_name: b.name.clone(),
                transport: transport_label(there),
                kind: there.kind.to_string(),
                return_transport: back.map(transport_label),
                clock: if virtual_time {
                    Clock::Virtual
                } else {
                    Clock::Real
                },
            });
        }
    }
    out
}

/// Gives every `udp` / `tcp` endpoint with port 0 a free port of its host, so that the
/// systems, all opened in this process, know each other's ports (each would otherwise bind a
/// port of its own that the others never learn). Returns one line per endpoint changed.
fn assign_free_ports(fleet: &mut Fleet) -> Result<Vec<String>, ExperimentError> {
    let mut notes = Vec::new();
    // Every probe socket stays bound until all are chosen, so no port is handed out twice.
    let mut held: Vec<Box<dyn std::any::Any>> = Vec::new();
    let names: HashMap<SystemId, String> = fleet
        .systems
        .iter()
        .map(|s| (s.id, s.name.clone()))
        .collect();
    for t in &mut fleet.transports {
        let udp = t.kind == TransportKind::Udp;
        let TransportSettings::Ip(ip) = &mut t.settings else {
            continue;
        };
        for (id, endpoint) in ip.endpoints.iter_mut() {
            let Some((host, "0")) = endpoint.rsplit_once(':') else {
                continue;
            };
            let probe = format!("{host}:0");
            let bound = if udp {
                std::net::UdpSocket::bind(&probe).and_then(|s| {
                    let port = s.local_addr()?.port();
                    held.push(Box::new(s));
                    Ok(port)
                })
            } else {
                std::net::TcpListener::bind(&probe).and_then(|s| {
                    let port = s.local_addr()?.port();
                    held.push(Box::new(s));
                    Ok(port)
                })
            };
            let port = bound.map_err(ExperimentError::io(format!(
                "finding a free port for {} on transport `{}` ({endpoint})",
                names.get(id).map(String::as_str).unwrap_or("?"),
                t.name
            )))?;
            *endpoint = format!("{host}:{port}");
            notes.push(format!(
                "transport `{}`: {} listens on {endpoint} (port 0 in the fleet file: a free port \
                 chosen for this run, all systems being in this process)",
                t.name,
                names.get(id).map(String::as_str).unwrap_or("?")
            ));
        }
    }
    Ok(notes)
}

/// The module the probes use: `Plan` if the fleet has it, else its first module.
fn module_name(fleet: &Fleet) -> Result<String, ExperimentError> {
    fleet
        .module_by_name("Plan")
        .or(fleet.modules.first())
        .map(|m| m.name.clone())
        .ok_or_else(|| ExperimentError::Invalid("the fleet defines no modules".into()))
}

/// Key of a receipt: (probe's sender, probe's receiver, sequence number, which delay).
type Key = (SystemId, SystemId, u32, Direction);

/// What the callbacks share: receipt times, and the modules echoes leave from.
struct Shared {
    clock: Clock,
    epoch: Instant,
    /// Receipt time, ns on the pass's clock.
    arrivals: Mutex<HashMap<Key, u64>>,
    duplicates: Mutex<HashMap<(SystemId, SystemId), u64>>,
    /// Echo refusals per probe pair.
    echo_refused: Mutex<HashMap<(SystemId, SystemId), u64>>,
    /// (receiver, sender) pairs that echo: the table has the way back and the pair runs here.
    echoes: HashSet<(SystemId, SystemId)>,
    /// Every system's probe module, to echo from; emptied at the end (the callbacks would
    /// otherwise hold their systems open).
    modules: Mutex<HashMap<SystemId, Module>>,
}

impl Shared {
    fn now_ns(&self, raw: &RawMessage) -> u64 {
        match self.clock {
            // The router stamps the inbox entry with virtual time (µs).
            Clock::Virtual => raw.envelope.received_at.as_micros() * 1000,
            Clock::Real => self.epoch.elapsed().as_nanos() as u64,
        }
    }

    fn record(&self, key: Key, at: u64) {
        let fresh = match self
            .arrivals
            .lock()
            .unwrap_or_else(|e| e.into_inner())
            .entry(key)
        {
            std::collections::hash_map::Entry::Occupied(_) => false,
            std::collections::hash_map::Entry::Vacant(v) => {
                v.insert(at);
                true
            }
        };
        if !fresh {
            *self
                .duplicates
                .lock()
                .unwrap_or_else(|e| e.into_inner())
                .entry((key.0, key.1))
                .or_default() += 1;
        }
    }

    fn on_probe(&self, me: SystemId, raw: RawMessage) {
        let at = self.now_ns(&raw);
        let Some(seq) = seq_of(&raw.payload) else {
            return;
        };
        let from = raw.envelope.source().system;
        self.record((from, me, seq, Direction::OneWay), at);
        if !self.echoes.contains(&(me, from)) {
            return;
        }
        let module = self
            .modules
            .lock()
            .unwrap_or_else(|e| e.into_inner())
            .get(&me)
            .cloned();
        if let Some(m) = module {
            let sent = m.send_raw(
                raw.envelope.source_system,
                raw.envelope.source_module,
                ECHO,
                &raw.payload,
                SendOptions::default(),
            );
            if sent.is_err() {
                *self
                    .echo_refused
                    .lock()
                    .unwrap_or_else(|e| e.into_inner())
                    .entry((me, from))
                    .or_default() += 1;
            }
        }
    }

    fn on_echo(&self, me: SystemId, raw: RawMessage) {
        let at = self.now_ns(&raw);
        if let Some(seq) = seq_of(&raw.payload) {
            let to = raw.envelope.source().system;
            self.record((me, to, seq, Direction::RoundTrip), at);
        }
    }
}

fn seq_of(payload: &[u8]) -> Option<u32> {
    payload
        .get(..4)
        .map(|b| u32::from_le_bytes([b[0], b[1], b[2], b[3]]))
}

/// The systems of one pass, simulated or real.
enum Driver {
    Sim(SimFleet),
    Real(LocalFleet),
}

impl Driver {
    fn systems(&self) -> &[Comm] {
        match self {
            Driver::Sim(s) => s.systems(),
            Driver::Real(f) => f.systems(),
        }
    }
}

/// One send on the schedule: (due, ns since the pass's start; pair index; sequence number).
type Slot = (u64, usize, u32);

fn schedule(n_pairs: usize, per_pair: u32, rate_hz: f64) -> Vec<Slot> {
    let period_ns = 1e9 / rate_hz;
    let mut slots: Vec<Slot> = (0..n_pairs)
        .flat_map(|p| {
            (0..per_pair).map(move |k| {
                let at = (k as f64 + p as f64 / n_pairs as f64) * period_ns;
                (at.round() as u64, p, k)
            })
        })
        .collect();
    slots.sort_unstable();
    slots
}

/// What a pass measured: per pair, the send time of each sequence number sent (ns) and the
/// refusals.
struct Sends {
    sent_at: Vec<BTreeMap<u32, u64>>,
    refused: Vec<u64>,
    refused_reason: Vec<Option<String>>,
}

/// Runs the pairs of one clock.
fn run_pass(
    fleet: &Fleet,
    pairs: &[Pair],
    clock: Clock,
    config: &LatencyConfig,
    module: &str,
    notes: &mut Vec<String>,
) -> Result<(Sends, Arc<Shared>), ExperimentError> {
    let driver = match clock {
        Clock::Virtual => Driver::Sim(SimFleet::open(
            fleet.clone(),
            SimOptions {
                seed: config.seed,
                ..SimOptions::default()
            },
        )?),
        Clock::Real => {
            let mut fleet = fleet.clone();
            notes.extend(assign_free_ports(&mut fleet)?);
            Driver::Real(LocalFleet::open(fleet)?)
        }
    };
    let mut modules = HashMap::new();
    for comm in driver.systems() {
        modules.insert(comm.id(), comm.module(module)?);
    }
    let shared = Arc::new(Shared {
        clock,
        epoch: Instant::now(),
        arrivals: Mutex::new(HashMap::new()),
        duplicates: Mutex::new(HashMap::new()),
        echo_refused: Mutex::new(HashMap::new()),
        echoes: pairs
            .iter()
            .filter(|p| p.return_transport.is_some())
            .map(|p| (p.to, p.from))
            .collect(),
        modules: Mutex::new(modules.clone()),
    });
    for (&id, m) in &modules {
        // Echo on the delivering thread, without a hand-off to a callback thread (under
        // simulation callbacks are inline anyway).
        m.set_inline_callbacks(true);
        let s = shared.clone();
        m.on_raw(PROBE, move |raw| s.on_probe(id, raw));
        let s = shared.clone();
        m.on_raw(ECHO, move |raw| s.on_echo(id, raw));
    }

    let per_pair = config.warmup + config.messages;
    let slots = schedule(pairs.len(), per_pair, config.rate_hz);
    let mut payload = vec![0u8; config.size_bytes];
    let mut sends = Sends {
        sent_at: vec![BTreeMap::new(); pairs.len()],
        refused: vec![0; pairs.len()],
        refused_reason: vec![None; pairs.len()],
    };
    let start = Instant::now();
    for &(due, p, seq) in &slots {
        let pair = &pairs[p];
        let sent_at = match &driver {
            Driver::Sim(sim) => {
                sim.run_until(Time::from_micros(due / 1000));
                sim.now().as_micros() * 1000
            }
            Driver::Real(_) => {
                let due = start + Duration::from_nanos(due);
                let wait = due.saturating_duration_since(Instant::now());
                if !wait.is_zero() {
                    std::thread::sleep(wait);
                }
                shared.epoch.elapsed().as_nanos() as u64
            }
        };
        payload[..4].copy_from_slice(&seq.to_le_bytes());
        let counted = seq >= config.warmup;
        match modules[&pair.from].send_raw(
            &pair.to_name,
            module,
            PROBE,
            &payload,
            SendOptions::default(),
        ) {
            Ok(_) => {
                if counted {
                    sends.sent_at[p].insert(seq, sent_at);
                }
            }
            Err(e) => {
                if counted {
                    sends.refused[p] += 1;
                    sends.refused_reason[p].get_or_insert_with(|| e.to_string());
                }
            }
        }
    }
    // Let the last receipts and echoes arrive.
    let expected: usize = sends
        .sent_at
        .iter()
        .zip(pairs)
        .map(|(s, p)| s.len() * if p.return_transport.is_some() { 2 } else { 1 })
        .sum();
    let counted = |shared: &Shared| {
        shared
            .arrivals
            .lock()
            .unwrap_or_else(|e| e.into_inner())
            .keys()
            .filter(|k| k.2 >= config.warmup)
            .count()
    };
    match &driver {
        Driver::Sim(sim) => {
            let end = sim.now().as_micros() + config.drain.as_micros() as u64;
            sim.run_idle(Time::from_micros(end));
        }
        Driver::Real(_) => {
            let deadline = Instant::now() + config.drain;
            while counted(&shared) < expected && Instant::now() < deadline {
                std::thread::sleep(Duration::from_millis(1));
            }
        }
    }
    shared
        .modules
        .lock()
        .unwrap_or_else(|e| e.into_inner())
        .clear();
    drop(modules);
    drop(driver);
    Ok((sends, shared))
}

/// Runs the experiment on `fleet` (see the module docs). `thesis` gives, per (from, to)
/// name, what the thesis publishes for the pair (`--against-thesis`), None otherwise.
pub fn run(
    fleet: &Fleet,
    config: &LatencyConfig,
    thesis: Option<&super::ThesisFigures>,
) -> Result<LatencyReport, ExperimentError> {
    validate(config)?;
    let module = module_name(fleet)?;
    let all = pairs(fleet, config.realtime);
    if all.is_empty() {
        return Err(ExperimentError::Invalid(
            "the fleet's table has no traffic: no pair to measure".into(),
        ));
    }
    let mut pair_reports: Vec<Option<PairReport>> = vec![None; all.len()];
    let mut samples = Vec::new();
    let mut clock_methods = BTreeMap::new();
    let mut notes = Vec::new();
    for clock in [Clock::Virtual, Clock::Real] {
        let idx: Vec<usize> = (0..all.len()).filter(|&i| all[i].clock == clock).collect();
        if idx.is_empty() {
            continue;
        }
        clock_methods.insert(clock.name().to_string(), clock.method().to_string());
        let pass: Vec<Pair> = idx.iter().map(|&i| all[i].clone()).collect();
        let (sends, shared) = run_pass(fleet, &pass, clock, config, &module, &mut notes)?;
        let arrivals =
            std::mem::take(&mut *shared.arrivals.lock().unwrap_or_else(|e| e.into_inner()));
        let duplicates = shared
            .duplicates
            .lock()
            .unwrap_or_else(|e| e.into_inner())
            .clone();
        let echo_refused = shared
            .echo_refused
            .lock()
            .unwrap_or_else(|e| e.into_inner())
            .clone();
        for (k, pair) in pass.iter().enumerate() {
            let sent_at = &sends.sent_at[k];
            let start = sent_at.values().next().copied().unwrap_or(0);
            let mut one_way = Vec::new();
            let mut round_trip = Vec::new();
            for (&seq, &at) in sent_at {
                for (direction, out) in [
                    (Direction::OneWay, &mut one_way),
                    (Direction::RoundTrip, &mut round_trip),
                ] {
                    if let Some(&got) = arrivals.get(&(pair.from, pair.to, seq, direction)) {
                        let delay = got.saturating_sub(at);
                        out.push(delay);
                        samples.push(Sample {
                            from: pair.from_name.clone(),
                            to: pair.to_name.clone(),
                            transport: pair.transport.clone(),
                            clock,
                            direction,
                            seq: seq - config.warmup,
                            sent_us: (at - start) as f64 / 1e3,
                            delay_us: delay as f64 / 1e3,
                        });
                    }
                }
            }
            let sent = sent_at.len() as u64 + sends.refused[k];
            let left = sent_at.len() as u64;
            let span_ns = sent_at.values().next_back().copied().unwrap_or(0) - start;
            let has_back = pair.return_transport.is_some();
            pair_reports[idx[k]] = Some(PairReport {
                from: pair.from_name.clone(),
                to: pair.to_name.clone(),
                transport: pair.transport.clone(),
                kind: pair.kind.clone(),
                return_transport: pair.return_transport.clone(),
                clock,
                sent,
                refused: sends.refused[k],
                refused_reason: sends.refused_reason[k].clone(),
                lost_one_way: left - one_way.len() as u64,
                lost_round_trip: has_back.then(|| left - round_trip.len() as u64),
                echoes_refused: echo_refused
                    .get(&(pair.to, pair.from))
                    .copied()
                    .unwrap_or(0),
                duplicates: duplicates.get(&(pair.from, pair.to)).copied().unwrap_or(0),
                one_way: Distribution::from_nanos(&one_way),
                round_trip: has_back.then(|| Distribution::from_nanos(&round_trip)),
                achieved_rate_hz: if left > 1 && span_ns > 0 {
                    (left - 1) as f64 * 1e9 / span_ns as f64
                } else {
                    0.0
                },
                thesis: thesis.map(|f| f(&pair.from_name, &pair.to_name)),
            });
        }
    }
    Ok(LatencyReport {
        experiment: "latency".into(),
        fleet: fleet.name.clone(),
        messages: config.messages,
        warmup: config.warmup,
        rate_hz: config.rate_hz,
        size_bytes: config.size_bytes,
        seed: config.seed,
        clock_methods,
        notes,
        against_thesis: thesis.is_some(),
        pairs: pair_reports.into_iter().flatten().collect(),
        samples,
    })
}

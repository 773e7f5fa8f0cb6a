//! Running the probes: which pairs run on which clock, the schedule, the echoing callbacks,
//! and turning receipt times into samples.

use parking_lot::Mutex;
use std::collections::{BTreeMap, HashMap, HashSet};
use std::sync::atomic::{AtomicBool, AtomicUsize, Ordering};
use std::sync::Arc;
use std::time::{Duration, Instant};

use hetcomm::config::{
    Fleet, IpSettings, RegisteredSettings, TransportDef, TransportKind, TransportSettings,
};
use hetcomm::sim::{SimFleet, SimOptions};
use hetcomm::{Comm, LocalFleet, MessageType, Module, RawMessage, SendOptions, SystemId, Time};

use crate::reliability::module_name;

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
        let Some(mut ip) = t.settings.registered::<IpSettings>().cloned() else {
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
        t.settings = TransportSettings::Registered(RegisteredSettings::new(ip));
    }
    Ok(notes)
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
        let fresh = match self.arrivals.lock().entry(key) {
            std::collections::hash_map::Entry::Occupied(_) => false,
            std::collections::hash_map::Entry::Vacant(v) => {
                v.insert(at);
                true
            }
        };
        if !fresh {
            *self.duplicates.lock().entry((key.0, key.1)).or_default() += 1;
        }
    }

    /// A probe reached `me`: its receipt time, and the echo from `echo_from` (the receiving
    /// thread's module in real time; None under simulation, where the shared map has it).
    fn on_probe(&self, me: SystemId, raw: RawMessage, echo_from: Option<&Module>) {
        let at = self.now_ns(&raw);
        let Some(seq) = seq_of(&raw.payload) else {
            return;
        };
        let from = raw.envelope.source().system;
        self.record((from, me, seq, Direction::OneWay), at);
        if !self.echoes.contains(&(me, from)) {
            return;
        }
        let module = match echo_from {
            Some(m) => Some(m.clone()),
            None => self.modules.lock().get(&me).cloned(),
        };
        if let Some(m) = module {
            let sent = m.send_raw(
                raw.envelope.source_system,
                raw.envelope.source_module,
                ECHO,
                &raw.payload,
                SendOptions::default(),
            );
            if sent.is_err() {
                *self.echo_refused.lock().entry((me, from)).or_default() += 1;
            }
        }
    }

    /// Whether the echo of probe `seq` of `pair` is back.
    fn arrived(&self, pair: &Pair, seq: u32) -> bool {
        self.arrivals
            .lock()
            .contains_key(&(pair.from, pair.to, seq, Direction::RoundTrip))
    }

    /// Takes one message from a module's inbox.
    fn on_message(&self, me: SystemId, raw: RawMessage, module: Option<&Module>) {
        match raw.envelope.message_type() {
            PROBE => self.on_probe(me, raw, module),
            ECHO => self.on_echo(me, raw),
            _ => {}
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

/// A send's time on the pass's clock (ns), or why `send` refused it.
type SendResult = Result<u64, String>;

/// Sends probe `seq` of `pair` from `from` (the payload: the sequence number, then zeros).
fn probe(
    from: &Module,
    pair: &Pair,
    module: &str,
    seq: u32,
    payload: &mut [u8],
) -> Result<(), String> {
    payload[..4].copy_from_slice(&seq.to_le_bytes());
    from.send_raw(
        &pair.to_name,
        module,
        PROBE,
        payload,
        SendOptions::default(),
    )
    .map(|_| ())
    .map_err(|e| e.to_string())
}

/// In a closed loop, how long a probe waits for the previous one's echo before it goes anyway
/// (that echo then counts as lost unless it still comes).
pub const ECHO_WAIT: Duration = Duration::from_secs(1);

/// One system's thread in real time: its probes, when due, and what arrives meanwhile.
struct Sender {
    id: SystemId,
    module: Module,
    module_name: String,
    pairs: Vec<Pair>,
    /// This system's probes, in time order.
    slots: Vec<Slot>,
    size: usize,
    /// Each probe waits for the previous one's echo (see [`LatencyConfig::closed_loop`]).
    closed_loop: bool,
    start: Instant,
    shared: Arc<Shared>,
    stop: Arc<AtomicBool>,
    /// Threads still sending: this one counts itself out after its last probe.
    sending: Arc<AtomicUsize>,
}

impl Sender {
    fn run(self) -> Vec<(usize, u32, SendResult)> {
        let mut results = Vec::with_capacity(self.slots.len());
        let mut payload = vec![0u8; self.size];
        let mut next = 0;
        let mut counted_out = false;
        let mut last_sent: Option<Instant> = None;
        loop {
            let wait = match self.slots.get(next) {
                Some(&(due, p, seq)) => {
                    let due = self.start + Duration::from_nanos(due);
                    let now = Instant::now();
                    let ready = !self.closed_loop
                        || seq == 0
                        || last_sent.is_some_and(|t: Instant| t.elapsed() >= ECHO_WAIT)
                        || self.shared.arrived(&self.pairs[p], seq - 1);
                    if !ready {
                        // The echo arrives on this thread: `recv` returns with it.
                        Duration::from_millis(1)
                    } else if now >= due {
                        last_sent = Some(Instant::now());
                        let at = self.shared.epoch.elapsed().as_nanos() as u64;
                        let pair = &self.pairs[p];
                        let r = probe(&self.module, pair, &self.module_name, seq, &mut payload);
                        results.push((p, seq, r.map(|()| at)));
                        next += 1;
                        continue;
                    } else {
                        due - now
                    }
                }
                None => {
                    if !counted_out {
                        counted_out = true;
                        self.sending.fetch_sub(1, Ordering::AcqRel);
                    }
                    if self.stop.load(Ordering::Acquire) {
                        break;
                    }
                    Duration::from_millis(5)
                }
            };
            match self.module.recv_raw_timeout(Some(wait)) {
                Ok(raw) => self.shared.on_message(self.id, raw, Some(&self.module)),
                Err(hetcomm::RecvError::Timeout(_)) => {}
                // Closed: nothing more will arrive.
                Err(_) => {
                    if !counted_out {
                        self.sending.fetch_sub(1, Ordering::AcqRel);
                    }
                    break;
                }
            }
        }
        results
    }
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
    let per_pair = config.warmup + config.messages;
    let slots = schedule(pairs.len(), per_pair, config.rate_hz);
    let mut sends = Sends {
        sent_at: vec![BTreeMap::new(); pairs.len()],
        refused: vec![0; pairs.len()],
        refused_reason: vec![None; pairs.len()],
    };
    let mut record = |p: usize, seq: u32, result: SendResult| {
        if seq < config.warmup {
            return;
        }
        match result {
            Ok(at) => {
                sends.sent_at[p].insert(seq, at);
            }
            Err(e) => {
                sends.refused[p] += 1;
                sends.refused_reason[p].get_or_insert(e);
            }
        }
    };
    match &driver {
        // Under simulation: callbacks, run at the delivery in virtual time, and the sends
        // from here, the clock moved to each one's time.
        Driver::Sim(sim) => {
            for (&id, m) in &modules {
                let s = shared.clone();
                m.on_any(move |raw| s.on_message(id, raw, None));
            }
            let mut payload = vec![0u8; config.size_bytes];
            for &(due, p, seq) in &slots {
                sim.run_until(Time::from_micros(due / 1000));
                let at = sim.now().as_micros() * 1000;
                let result = probe(
                    &modules[&pairs[p].from],
                    &pairs[p],
                    module,
                    seq,
                    &mut payload,
                );
                record(p, seq, result.map(|()| at));
            }
            let end = sim.now().as_micros() + config.drain.as_micros() as u64;
            sim.run_idle(Time::from_micros(end));
        }
        // In real time: a thread per system, as a robot's loop, that sends its probes when
        // they are due and otherwise waits in `recv`. A thread waiting in `recv` reads its
        // system's sockets itself (the runtime's reactor), so a probe reaches the receiver
        // and its echo comes back without a hand-off to another thread.
        Driver::Real(_) => {
            let start = Instant::now();
            let stop = Arc::new(AtomicBool::new(false));
            let sending = Arc::new(AtomicUsize::new(modules.len()));
            let mut threads = Vec::new();
            for (&id, m) in &modules {
                let mine: Vec<Slot> = slots
                    .iter()
                    .filter(|s| pairs[s.1].from == id)
                    .copied()
                    .collect();
                let ctx = Sender {
                    id,
                    module: m.clone(),
                    module_name: module.to_string(),
                    pairs: pairs.to_vec(),
                    slots: mine,
                    size: config.size_bytes,
                    closed_loop: config.closed_loop,
                    start,
                    shared: shared.clone(),
                    stop: stop.clone(),
                    sending: sending.clone(),
                };
                let thread = std::thread::Builder::new()
                    .name(format!("latency-{}", id.0))
                    .spawn(move || ctx.run())
                    .map_err(ExperimentError::io("starting a system's thread"))?;
                threads.push(thread);
            }
            // Let the last receipts and echoes arrive.
            let total: usize = slots
                .iter()
                .filter(|s| s.2 >= config.warmup)
                .map(|s| {
                    if pairs[s.1].return_transport.is_some() {
                        2
                    } else {
                        1
                    }
                })
                .sum();
            let counted = || {
                shared
                    .arrivals
                    .lock()
                    .keys()
                    .filter(|k| k.2 >= config.warmup)
                    .count()
            };
            while sending.load(Ordering::Acquire) > 0 {
                std::thread::sleep(Duration::from_millis(1));
            }
            let deadline = Instant::now() + config.drain;
            while counted() < total && Instant::now() < deadline {
                std::thread::sleep(Duration::from_millis(1));
            }
            stop.store(true, Ordering::Release);
            for t in threads {
                let results = t
                    .join()
                    .map_err(|_| ExperimentError::Invalid("a system's thread panicked".into()))?;
                for (p, seq, result) in results {
                    record(p, seq, result);
                }
            }
        }
    }
    shared.modules.lock().clear();
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
    let mut all = pairs(fleet, config.realtime);
    if !config.pairs.is_empty() {
        for (from, to) in &config.pairs {
            for name in [from, to] {
                if fleet.system_by_name(name).is_none() {
                    return Err(ExperimentError::Invalid(format!(
                        "--pair {from}:{to}: the fleet has no system `{name}`"
                    )));
                }
            }
            if !all.iter().any(|p| &p.from_name == from && &p.to_name == to) {
                return Err(ExperimentError::Invalid(format!(
                    "--pair {from}:{to}: the table has no traffic from {from} to {to} (X)"
                )));
            }
        }
        all.retain(|p| {
            config
                .pairs
                .iter()
                .any(|(f, t)| *f == p.from_name && *t == p.to_name)
        });
    }
    if all.is_empty() {
        return Err(ExperimentError::Invalid(
            "the fleet's table has no traffic: no pair to measure".into(),
        ));
    }
    if config.closed_loop {
        for p in &all {
            if p.clock == Clock::Virtual {
                return Err(ExperimentError::Invalid(format!(
                    "--closed-loop runs in real time only: {} → {} is on emulated links (add \
                     --realtime to emulate them in real time)",
                    p.from_name, p.to_name
                )));
            }
            if p.return_transport.is_none() {
                return Err(ExperimentError::Invalid(format!(
                    "--closed-loop waits for each probe's echo, but {} → {} has no way back (the \
                     table has no pair {} → {}); leave it out with --pair",
                    p.from_name, p.to_name, p.to_name, p.from_name
                )));
            }
        }
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
        let arrivals = std::mem::take(&mut *shared.arrivals.lock());
        let duplicates = shared.duplicates.lock().clone();
        let echo_refused = shared.echo_refused.lock().clone();
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
        closed_loop: config.closed_loop,
        size_bytes: config.size_bytes,
        seed: config.seed,
        clock_methods,
        notes,
        against_thesis: thesis.is_some(),
        pairs: pair_reports.into_iter().flatten().collect(),
        samples,
    })
}

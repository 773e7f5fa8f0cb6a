//! Per-pair statistics for the live monitor, and how they reach it from other processes.
//!
//! Each process that wants to be seen runs a [`Publisher`] over its open systems: a
//! [`PairStats`] observer per system counts, per destination, sends, retransmissions and
//! outcomes (with delivery latencies), and per source the messages received; once a period
//! the publisher sends one [`StatsReport`] per system, as a JSON datagram, to the monitor's
//! UDP address. The monitor ([`MonitorState`]) merges the reports of every process: the
//! sender's side of a pair comes from the source system's report, the receipts from the
//! destination's. Reports carry counters, names and inbox depths, never payloads; they go
//! outside the fleet's secured links, so point them at a local or trusted address only.

use parking_lot::Mutex;
use std::collections::{BTreeMap, HashMap};
use std::net::{SocketAddr, UdpSocket};
use std::sync::atomic::{AtomicBool, Ordering};
use std::sync::Arc;
use std::thread::JoinHandle;
use std::time::{Duration, Instant};

use hetcomm::observe::{OutcomeRecord, ReceiptRecord, SendRecord};
use hetcomm::{Comm, Observer, ObserverHandle, Outcome, Time};
use serde::{Deserialize, Serialize};

use crate::events::FleetNames;

/// The environment variable naming the monitor's address (`host:port`, several separated by
/// commas) for the commands that
/// publish statistics (`hetcomm demo`, `listen`, `replay`, `record`).
pub const MONITOR_ENV: &str = "HETCOMM_MONITOR";
/// The monitor's default UDP address.
pub const DEFAULT_MONITOR_ADDR: &str = "127.0.0.1:7450";

/// Counters of one ordered pair, as its source (sends, outcomes) and its destination
/// (receipts) saw it; cumulative since the publisher started.
#[derive(Clone, Debug, Default, PartialEq, Serialize, Deserialize)]
pub struct PairCounters {
    /// Sending system.
    pub source: String,
    /// Destination system.
    pub destination: String,
    /// The transport's name (or tag) carrying the pair.
    pub transport: String,
    /// Sends (first attempts).
    pub sends: u64,
    /// Extra attempts.
    pub retransmissions: u64,
    /// Outcomes: delivered.
    pub delivered: u64,
    /// Outcomes: sent without confirmation (unacknowledged transports).
    pub sent: u64,
    /// Outcomes: unconfirmed.
    pub unconfirmed: u64,
    /// Outcomes: failed.
    pub failed: u64,
    /// Messages the destination handed to its inboxes (from its own report).
    pub received: u64,
    /// Delivery latency over the last period, median, microseconds.
    pub latency_p50_us: Option<u64>,
    /// Delivery latency over the last period, 99th percentile, microseconds.
    pub latency_p99_us: Option<u64>,
}

/// One module's inbox.
#[derive(Clone, Debug, Default, PartialEq, Serialize, Deserialize)]
pub struct InboxReport {
    /// Module name.
    pub module: String,
    /// Messages queued now.
    pub depth: usize,
    /// Its bound.
    pub capacity: usize,
    /// Messages lost to overflow so far.
    pub dropped: u64,
}

/// One path switch of a system (docs/failover.md).
#[derive(Clone, Debug, Default, PartialEq, Serialize, Deserialize)]
pub struct SwitchReport {
    /// The destination whose sends moved.
    pub destination: String,
    /// The transport left.
    pub from: String,
    /// The transport taken.
    pub to: String,
    /// The system's switches so far, this one included.
    pub number: u64,
}

/// What one system reports once a period.
#[derive(Clone, Debug, Default, PartialEq, Serialize, Deserialize)]
pub struct StatsReport {
    /// The system.
    pub system: String,
    /// When, microseconds since the UNIX epoch.
    pub time_us: u64,
    /// Pairs this system sends on (source side) and receives on (`received` only).
    pub pairs: Vec<PairCounters>,
    /// Its modules' inboxes.
    pub inboxes: Vec<InboxReport>,
    /// Its path switches so far (0 in reports of versions without failover).
    #[serde(default)]
    pub path_switches: u64,
    /// Its last path switches (up to 4, oldest first).
    #[serde(default, skip_serializing_if = "Vec::is_empty")]
    pub last_switches: Vec<SwitchReport>,
}

#[derive(Default)]
struct Acc {
    transport: String,
    c: PairCounters,
    latencies: Vec<u64>,
}

/// An observer counting one system's traffic per pair.
pub struct PairStats {
    system: String,
    names: FleetNames,
    /// Keyed by (source, destination) system id.
    pairs: Mutex<BTreeMap<(u16, u16), Acc>>,
    id: u16,
}

impl PairStats {
    /// Counters for `comm` (not yet registered: see [`PairStats::attach`]).
    pub fn new(comm: &Comm) -> Arc<PairStats> {
        Arc::new(PairStats {
            system: comm.name().to_string(),
            id: comm.id().0,
            names: FleetNames::new(comm.fleet()),
            pairs: Mutex::new(BTreeMap::new()),
        })
    }

    /// Registers the counters with `comm`.
    pub fn attach(self: &Arc<Self>, comm: &Comm) -> ObserverHandle {
        comm.observe(self.clone())
    }

    fn with(&self, key: (u16, u16), tag: Option<u8>, f: impl FnOnce(&mut Acc)) {
        let mut pairs = self.pairs.lock();
        let acc = pairs.entry(key).or_default();
        if let Some(tag) = tag {
            if acc.transport.is_empty() {
                acc.transport = match self.names.transport(tag) {
                    Some(name) => name.to_string(),
                    None => (tag as char).to_string(),
                };
            }
        }
        f(acc);
    }

    /// The report for now: cumulative counters, the last period's latencies (which it
    /// clears), and `comm`'s inboxes.
    pub fn report(&self, comm: &Comm) -> StatsReport {
        let mut pairs = Vec::new();
        for (&(s, d), acc) in self.pairs.lock().iter_mut() {
            let mut c = acc.c.clone();
            c.source = self.names.system(s);
            c.destination = self.names.system(d);
            c.transport = acc.transport.clone();
            acc.latencies.sort_unstable();
            c.latency_p50_us = quantile(&acc.latencies, 0.50);
            c.latency_p99_us = quantile(&acc.latencies, 0.99);
            acc.latencies.clear();
            pairs.push(c);
        }
        let stats = comm.stats();
        let last_switches = stats
            .path_switches
            .iter()
            .skip(stats.path_switches.len().saturating_sub(4))
            .map(|s| SwitchReport {
                destination: s.to.clone(),
                from: s.from.clone(),
                to: s.now.clone(),
                number: s.number,
            })
            .collect();
        let inboxes = stats
            .inboxes
            .into_iter()
            .map(|(module, s)| InboxReport {
                module,
                depth: s.len,
                capacity: s.capacity,
                dropped: s.dropped(),
            })
            .collect();
        StatsReport {
            system: self.system.clone(),
            time_us: Time::now_wall().as_micros(),
            pairs,
            inboxes,
            path_switches: stats.router.path_changes,
            last_switches,
        }
    }
}

/// The `q` quantile of sorted samples (nearest rank).
pub fn quantile(sorted: &[u64], q: f64) -> Option<u64> {
    if sorted.is_empty() {
        return None;
    }
    let rank = ((q * sorted.len() as f64).ceil() as usize).clamp(1, sorted.len());
    Some(sorted[rank - 1])
}

impl Observer for PairStats {
    fn on_send(&self, r: &SendRecord<'_>) {
        let key = (self.id, r.header.destination.system.0);
        self.with(key, Some(r.header.transport), |a| a.c.sends += 1);
    }
    fn on_retransmit(&self, r: &SendRecord<'_>) {
        let key = (self.id, r.header.destination.system.0);
        self.with(key, Some(r.header.transport), |a| a.c.retransmissions += 1);
    }
    fn on_receipt(&self, r: &ReceiptRecord<'_>) {
        let key = (r.header.source.system.0, self.id);
        self.with(key, Some(r.header.transport), |a| a.c.received += 1);
    }
    fn on_outcome(&self, r: &OutcomeRecord<'_>) {
        self.with((self.id, r.id.to.0), None, |a| match r.outcome {
            Outcome::Delivered { latency, .. } => {
                a.c.delivered += 1;
                a.latencies.push(latency.as_micros() as u64);
            }
            // Relayed (a broker confirmed taking it) is still only sent, not delivered.
            Outcome::Sent { .. } | Outcome::Relayed { .. } => a.c.sent += 1,
            Outcome::Unconfirmed { .. } => a.c.unconfirmed += 1,
            Outcome::Failed { .. } => a.c.failed += 1,
        });
    }
}

/// Sends a [`StatsReport`] per system to a monitor once a period, and once more when dropped.
pub struct Publisher {
    stop: Arc<AtomicBool>,
    thread: Option<JoinHandle<()>>,
    _handles: Vec<ObserverHandle>,
}

impl Publisher {
    /// Starts publishing `systems`' statistics to each of `monitors` every `period`.
    pub fn start(
        systems: &[Comm],
        monitors: Vec<SocketAddr>,
        period: Duration,
    ) -> std::io::Result<Publisher> {
        let bind: SocketAddr = if !monitors.iter().any(|m| m.is_ipv6()) {
            "0.0.0.0:0".parse().expect("literal address")
        } else {
            "[::]:0".parse().expect("literal address")
        };
        let socket = UdpSocket::bind(bind)?;
        let mut handles = Vec::new();
        let mut watched = Vec::new();
        for comm in systems {
            let stats = PairStats::new(comm);
            handles.push(stats.attach(comm));
            watched.push((comm.clone(), stats));
        }
        let stop = Arc::new(AtomicBool::new(false));
        let stop2 = stop.clone();
        let thread = std::thread::Builder::new()
            .name("hetcomm-stats".into())
            .spawn(move || {
                let publish = || {
                    for (comm, stats) in &watched {
                        if let Ok(bytes) = serde_json::to_vec(&stats.report(comm)) {
                            // A monitor that is not running is not an error: reports are
                            // best-effort (a lost one only delays a refresh).
                            for monitor in &monitors {
                                let _ = socket.send_to(&bytes, monitor);
                            }
                        }
                    }
                };
                let mut next = Instant::now() + period;
                while !stop2.load(Ordering::Relaxed) {
                    std::thread::sleep(
                        next.saturating_duration_since(Instant::now())
                            .min(Duration::from_millis(50)),
                    );
                    if Instant::now() < next {
                        continue;
                    }
                    next += period;
                    publish();
                }
                // A last report when stopped: a process shorter than a period (`hetcomm
                // send`) is seen at all, and a longer one's last moments are not lost.
                publish();
            })?;
        Ok(Publisher {
            stop,
            thread: Some(thread),
            _handles: handles,
        })
    }

    /// Starts publishing when [`MONITOR_ENV`] names an address (or several, comma-separated);
    /// Ok(None) when it is unset.
    pub fn from_env(systems: &[Comm]) -> Result<Option<Publisher>, String> {
        let Ok(addr) = std::env::var(MONITOR_ENV) else {
            return Ok(None);
        };
        let monitors = addr
            .split(',')
            .map(|a| resolve(a.trim()))
            .collect::<Result<Vec<_>, _>>()
            .map_err(|e| format!("{MONITOR_ENV}={addr}: {e}"))?;
        Publisher::start(systems, monitors, Duration::from_secs(1))
            .map(Some)
            .map_err(|e| format!("{MONITOR_ENV}={addr}: {e}"))
    }
}

/// `host:port` as a socket address.
pub fn resolve(addr: &str) -> Result<SocketAddr, String> {
    use std::net::ToSocketAddrs;
    addr.to_socket_addrs()
        .map_err(|e| e.to_string())?
        .next()
        .ok_or_else(|| "no address".to_string())
}

impl Drop for Publisher {
    fn drop(&mut self) {
        self.stop.store(true, Ordering::Relaxed);
        if let Some(t) = self.thread.take() {
            let _ = t.join();
        }
    }
}

/// One row of the monitor: a pair with its rate.
#[derive(Clone, Debug, Default, PartialEq, Serialize, Deserialize)]
pub struct PairRow {
    /// The counters (sender side from the source's report, `received` from the
    /// destination's).
    #[serde(flatten)]
    pub counters: PairCounters,
    /// Sends per second over the last two reports of the source.
    pub rate: f64,
}

/// One system's inboxes, as last reported.
#[derive(Clone, Debug, Default, PartialEq, Serialize, Deserialize)]
pub struct SystemRow {
    /// The system.
    pub system: String,
    /// Seconds since its last report.
    pub age_s: f64,
    /// Its inboxes.
    pub inboxes: Vec<InboxReport>,
    /// Its path switches so far.
    #[serde(default)]
    pub path_switches: u64,
    /// Its last path switch, if any.
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub last_switch: Option<SwitchReport>,
}

#[derive(Clone)]
struct Seen {
    report: StatsReport,
    at: Instant,
    previous_sends: HashMap<String, (u64, u64)>,
    rates: HashMap<String, f64>,
}

/// What the monitor knows: the latest report of every system, merged into rows.
#[derive(Default)]
pub struct MonitorState {
    systems: BTreeMap<String, Seen>,
    /// Datagrams that were not reports.
    pub bad_reports: u64,
}

impl MonitorState {
    /// Takes one datagram.
    pub fn ingest_bytes(&mut self, bytes: &[u8], now: Instant) {
        match serde_json::from_slice::<StatsReport>(bytes) {
            Ok(r) => self.ingest(r, now),
            Err(_) => self.bad_reports += 1,
        }
    }

    /// Takes one report.
    pub fn ingest(&mut self, report: StatsReport, now: Instant) {
        let previous = self.systems.remove(&report.system);
        let mut previous_sends = HashMap::new();
        let mut rates = HashMap::new();
        for p in report.pairs.iter().filter(|p| p.source == report.system) {
            if let Some(prev) = &previous {
                if let Some(&(sends, t)) = prev.previous_sends.get(&p.destination) {
                    let dt = report.time_us.saturating_sub(t) as f64 / 1e6;
                    if dt > 0.0 {
                        rates.insert(
                            p.destination.clone(),
                            p.sends.saturating_sub(sends) as f64 / dt,
                        );
                    }
                }
            }
            previous_sends.insert(p.destination.clone(), (p.sends, report.time_us));
        }
        self.systems.insert(
            report.system.clone(),
            Seen {
                report,
                at: now,
                previous_sends,
                rates,
            },
        );
    }

    /// Every pair seen, sorted by source then destination.
    pub fn pairs(&self) -> Vec<PairRow> {
        let mut rows: BTreeMap<(String, String), PairRow> = BTreeMap::new();
        for seen in self.systems.values() {
            let me = &seen.report.system;
            for p in &seen.report.pairs {
                let row = rows
                    .entry((p.source.clone(), p.destination.clone()))
                    .or_default();
                row.counters.source = p.source.clone();
                row.counters.destination = p.destination.clone();
                if row.counters.transport.is_empty() {
                    row.counters.transport = p.transport.clone();
                }
                if p.source == *me {
                    let received = row.counters.received;
                    let transport = row.counters.transport.clone();
                    row.counters = PairCounters {
                        received,
                        transport,
                        ..p.clone()
                    };
                    row.rate = seen.rates.get(&p.destination).copied().unwrap_or(0.0);
                }
                if p.destination == *me {
                    row.counters.received = p.received;
                }
            }
        }
        rows.into_values().collect()
    }

    /// Every system seen, with its inboxes.
    pub fn systems(&self, now: Instant) -> Vec<SystemRow> {
        self.systems
            .values()
            .map(|s| SystemRow {
                system: s.report.system.clone(),
                age_s: now.saturating_duration_since(s.at).as_secs_f64(),
                inboxes: s.report.inboxes.clone(),
                path_switches: s.report.path_switches,
                last_switch: s.report.last_switches.last().cloned(),
            })
            .collect()
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn quantiles_are_nearest_rank() {
        let v: Vec<u64> = (1..=100).collect();
        assert_eq!(quantile(&v, 0.5), Some(50));
        assert_eq!(quantile(&v, 0.99), Some(99));
        assert_eq!(quantile(&[7], 0.99), Some(7));
        assert_eq!(quantile(&[], 0.5), None);
    }

    /// A system's path switches reach its row; a report without them (an older version's)
    /// still parses, with none.
    #[test]
    fn path_switches_reach_the_system_row() {
        let mut m = MonitorState::default();
        let now = Instant::now();
        let old = r#"{"system":"A","time_us":1,"pairs":[],"inboxes":[]}"#;
        m.ingest_bytes(old.as_bytes(), now);
        assert_eq!(m.bad_reports, 0);
        assert_eq!(m.systems(now)[0].path_switches, 0);
        let switch = SwitchReport {
            destination: "B".into(),
            from: "wifi".into(),
            to: "bt".into(),
            number: 3,
        };
        let report = StatsReport {
            system: "A".into(),
            time_us: 2,
            path_switches: 3,
            last_switches: vec![switch.clone()],
            ..Default::default()
        };
        m.ingest_bytes(&serde_json::to_vec(&report).unwrap(), now);
        let row = &m.systems(now)[0];
        assert_eq!(
            (row.path_switches, row.last_switch.as_ref()),
            (3, Some(&switch))
        );
    }

    #[test]
    fn reports_of_both_ends_merge_into_one_row_with_a_rate() {
        let pair = |sends, received| PairCounters {
            source: "A".into(),
            destination: "B".into(),
            transport: "udp".into(),
            sends,
            delivered: sends,
            received,
            ..Default::default()
        };
        let mut m = MonitorState::default();
        let now = Instant::now();
        let report = |system: &str, time_us, p| StatsReport {
            system: system.into(),
            time_us,
            pairs: vec![p],
            inboxes: vec![],
            ..Default::default()
        };
        m.ingest(report("A", 1_000_000, pair(10, 0)), now);
        m.ingest(report("B", 1_000_000, pair(0, 9)), now);
        m.ingest(report("A", 2_000_000, pair(60, 0)), now);
        let rows = m.pairs();
        assert_eq!(rows.len(), 1);
        assert_eq!(rows[0].counters.sends, 60);
        assert_eq!(rows[0].counters.received, 9);
        assert_eq!(rows[0].rate, 50.0);
        m.ingest_bytes(b"not json", now);
        assert_eq!(m.bad_reports, 1);
    }
}

//! The delay analysis the thesis leaves for future work (§6.1): how long a message takes from
//! one system to another, per ordered pair of the fleet and per transport, under a given load.
//!
//! For every ordered pair (A, B) the table connects, A's module sends
//! [`LatencyConfig::messages`] probes of [`LatencyConfig::size_bytes`] payload bytes to the same
//! module of B, [`LatencyConfig::rate_hz`] per second, all pairs at once (pair *i* of *n*
//! offset by *i*/(*n*·rate) so that their sends interleave). B echoes each probe back to A on
//! the pair (B, A) when the table has that pair. Two delays per probe:
//!
//! - **one way**: B's receipt (B's router put it in B's inbox and B took it: a callback at
//!   the delivery under simulation, B's thread waiting in `recv` in real time) minus A's send
//!   call;
//! - **round trip**: A's receipt of the echo minus A's send call.
//!
//! Where the time comes from ([`Clock`]): a pair whose messages travel only on `emulated`
//! transports (there and back) runs in the virtual-time simulator, seeded, so the same seed
//! gives the same figures; every other pair runs in real time, every system of the fleet
//! opened in this process over the fleet's real transports (real sockets for `udp` / `tcp`),
//! each with a thread that sends its probes when due and otherwise waits in `recv` (reading
//! its sockets itself), timed on the monotonic clock. Sender and receiver then read the same clock, so one-way
//! delays need no clock-offset estimate ([`CLOCK_METHOD_VIRTUAL`], [`CLOCK_METHOD_REAL`]).
//! [`LatencyConfig::realtime`] runs every pair in real time (emulated links then emulated in
//! real time by their wrapper).
//!
//! The load is open loop by default (probes leave on schedule); [`LatencyConfig::closed_loop`]
//! keeps one probe in flight per pair, as a ping–pong (real time only).
//!
//! The first [`LatencyConfig::warmup`] probes of each pair are sent but not counted (links
//! connecting, caches warming). Lost probes and echoes are counted per pair, never hidden.
//!
//! The report holds every sample ([`LatencyReport::samples`], written as `samples.csv`), the
//! distributions per pair ([`Distribution`]: p50/p90/p99/p99.9/max), and plots (a histogram
//! and a CDF per pair, [`plot`]). [`thesis`] has the §5.1 fleet of the thesis and the delays
//! its Table 12 publishes, for `--against-thesis`.

mod output;
pub mod plot;
mod run;
pub mod thesis;

pub use output::{csv_samples, csv_summary, text, write_files};
pub use run::run;

use serde::{Deserialize, Serialize};

pub use crate::reliability::ExperimentError;

/// What a published reference says about the pair (from, to): `--against-thesis` passes
/// [`thesis::published`].
pub type ThesisFigures = dyn Fn(&str, &str) -> String;

/// How the clocks of a pair's two ends are read, for pairs run in the simulator.
pub const CLOCK_METHOD_VIRTUAL: &str = "virtual time of the simulator (1 µs resolution): both \
     ends read the one virtual clock, so no clock offset arises or is estimated";

/// How the clocks of a pair's two ends are read, for pairs run in real time.
pub const CLOCK_METHOD_REAL: &str = "real time, every system in this one process, on its \
     monotonic clock (std::time::Instant, ns): one-way = receipt − send on the same clock, so no \
     clock offset arises or is estimated (not round-trip halves); round trip = echo receipt − \
     send; the wall clock is not used";

/// The payload's first four bytes: the probe's sequence number (little endian).
pub const MIN_SIZE_BYTES: usize = 4;

/// The experiment's settings.
#[derive(Clone, Debug, PartialEq)]
pub struct LatencyConfig {
    /// Counted probes per ordered pair.
    pub messages: u32,
    /// Probes per pair sent first and not counted.
    pub warmup: u32,
    /// Probes per second per ordered pair (the load; every pair sends at once).
    pub rate_hz: f64,
    /// Payload bytes of each probe (and echo); at least [`MIN_SIZE_BYTES`].
    pub size_bytes: usize,
    /// Seed of the simulator (emulated links' loss and jitter).
    pub seed: u64,
    /// Run every pair in real time, emulated links included.
    pub realtime: bool,
    /// Closed loop: a pair's next probe leaves only once the previous one's echo is back (or
    /// after a second without it), and not before its time at [`LatencyConfig::rate_hz`]: one
    /// probe in flight per pair, as a ping–pong. Real time only; every pair needs a way back.
    pub closed_loop: bool,
    /// Only these ordered pairs (from, to), by friendly name; empty: every pair the table
    /// connects.
    pub pairs: Vec<(String, String)>,
    /// After the last probe, how long to wait for the last receipts and echoes (virtual time
    /// in the simulator, real time otherwise).
    pub drain: std::time::Duration,
}

impl Default for LatencyConfig {
    fn default() -> Self {
        LatencyConfig {
            messages: 1000,
            warmup: 10,
            rate_hz: 200.0,
            size_bytes: 64,
            seed: 2019,
            realtime: false,
            closed_loop: false,
            pairs: Vec::new(),
            drain: std::time::Duration::from_secs(2),
        }
    }
}

/// Checks the settings on their own (the command line's names in the messages).
pub fn validate(config: &LatencyConfig) -> Result<(), ExperimentError> {
    let bad = |m: String| Err(ExperimentError::Invalid(m));
    if config.messages == 0 {
        return bad("--messages must be at least 1".into());
    }
    if !(config.rate_hz.is_finite() && config.rate_hz > 0.0 && config.rate_hz <= 1e6) {
        return bad(format!(
            "--rate must be a number of messages per second in (0, 1000000], got {}",
            config.rate_hz
        ));
    }
    if config.size_bytes < MIN_SIZE_BYTES {
        return bad(format!(
            "--size must be at least {MIN_SIZE_BYTES} bytes (the probe's sequence number), got {}",
            config.size_bytes
        ));
    }
    let max = hetcomm::wire::MAX_PAYLOAD;
    if config.size_bytes > max {
        return bad(format!(
            "--size must be at most {max} bytes (the largest payload), got {}",
            config.size_bytes
        ));
    }
    Ok(())
}

/// Which clock a pair was timed on.
#[derive(Clone, Copy, Debug, PartialEq, Eq, Hash, PartialOrd, Ord, Serialize, Deserialize)]
#[serde(rename_all = "lowercase")]
pub enum Clock {
    /// The simulator's virtual time.
    Virtual,
    /// The monotonic clock of this process, in real time.
    Real,
}

impl Clock {
    /// `virtual` or `real`.
    pub fn name(self) -> &'static str {
        match self {
            Clock::Virtual => "virtual",
            Clock::Real => "real",
        }
    }

    /// How the two ends' clocks relate ([`CLOCK_METHOD_VIRTUAL`], [`CLOCK_METHOD_REAL`]).
    pub fn method(self) -> &'static str {
        match self {
            Clock::Virtual => CLOCK_METHOD_VIRTUAL,
            Clock::Real => CLOCK_METHOD_REAL,
        }
    }
}

/// One-way or round trip.
#[derive(Clone, Copy, Debug, PartialEq, Eq, Hash, PartialOrd, Ord, Serialize, Deserialize)]
#[serde(rename_all = "kebab-case")]
pub enum Direction {
    /// Send to receipt.
    OneWay,
    /// Send to the echo's receipt.
    RoundTrip,
}

impl Direction {
    /// `one-way` or `round-trip`.
    pub fn name(self) -> &'static str {
        match self {
            Direction::OneWay => "one-way",
            Direction::RoundTrip => "round-trip",
        }
    }
}

/// A distribution of delays, µs (percentiles by nearest rank).
#[derive(Clone, Debug, Default, PartialEq, Serialize, Deserialize)]
pub struct Distribution {
    /// Samples.
    pub count: u64,
    /// Smallest.
    pub min_us: f64,
    /// Mean.
    pub mean_us: f64,
    /// 50th percentile.
    pub p50_us: f64,
    /// 90th percentile.
    pub p90_us: f64,
    /// 99th percentile.
    pub p99_us: f64,
    /// 99.9th percentile.
    pub p999_us: f64,
    /// Largest.
    pub max_us: f64,
}

impl Distribution {
    /// The distribution of delays given in nanoseconds.
    pub fn from_nanos(delays: &[u64]) -> Distribution {
        if delays.is_empty() {
            return Distribution::default();
        }
        let mut d = delays.to_vec();
        d.sort_unstable();
        let n = d.len();
        let us = |ns: u64| ns as f64 / 1e3;
        let rank = |q: f64| us(d[((q * n as f64).ceil() as usize).clamp(1, n) - 1]);
        Distribution {
            count: n as u64,
            min_us: us(d[0]),
            mean_us: d.iter().map(|&x| x as f64).sum::<f64>() / n as f64 / 1e3,
            p50_us: rank(0.50),
            p90_us: rank(0.90),
            p99_us: rank(0.99),
            p999_us: rank(0.999),
            max_us: us(d[n - 1]),
        }
    }
}

/// The figures of one ordered pair.
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
pub struct PairReport {
    /// Sending system.
    pub from: String,
    /// Receiving system (it echoes).
    pub to: String,
    /// The transport the table gives the pair (name, and its table letter if it has one).
    pub transport: String,
    /// Its kind (`udp`, `emulated`, …).
    pub kind: String,
    /// The transport of the way back (pair (to, from)); None when the table has no such pair.
    pub return_transport: Option<String>,
    /// Which clock timed it.
    pub clock: Clock,
    /// Counted probes handed to `send` (warm-up excluded).
    pub sent: u64,
    /// Of those, refused by `send` (nothing left: backpressure, an unreachable peer, …).
    pub refused: u64,
    /// Why the first refused send was refused.
    pub refused_reason: Option<String>,
    /// Sent probes that never reached the receiver.
    pub lost_one_way: u64,
    /// Sent probes whose echo never came back (None without a way back).
    pub lost_round_trip: Option<u64>,
    /// Echoes the receiver's `send` refused (they count as lost round trips).
    pub echoes_refused: u64,
    /// Second copies of a probe or echo that reached a module (the routers suppress them; a
    /// non-zero count is a defect).
    pub duplicates: u64,
    /// One-way delays.
    pub one_way: Distribution,
    /// Round trips (None without a way back).
    pub round_trip: Option<Distribution>,
    /// The load achieved: counted probes over the time from the first to the last, per second.
    pub achieved_rate_hz: f64,
    /// What the thesis publishes for this pair, or why nothing (`--against-thesis` only).
    pub thesis: Option<String>,
}

/// One measured delay.
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
pub struct Sample {
    /// Sending system of the probe.
    pub from: String,
    /// Receiving system of the probe.
    pub to: String,
    /// The pair's transport.
    pub transport: String,
    /// Which clock.
    pub clock: Clock,
    /// One way or round trip.
    pub direction: Direction,
    /// Probe sequence number within the pair (counted probes start after the warm-up).
    pub seq: u32,
    /// When it was sent, µs since the pair's run started on its clock.
    pub sent_us: f64,
    /// The delay, µs.
    pub delay_us: f64,
}

/// A whole run.
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
pub struct LatencyReport {
    /// `latency`.
    pub experiment: String,
    /// The fleet's name.
    pub fleet: Option<String>,
    /// Counted probes per pair.
    pub messages: u32,
    /// Uncounted probes per pair, sent first.
    pub warmup: u32,
    /// Probes per second per pair.
    pub rate_hz: f64,
    /// Closed loop: each probe waited for the previous one's echo.
    pub closed_loop: bool,
    /// Payload bytes per probe.
    pub size_bytes: usize,
    /// Simulator seed.
    pub seed: u64,
    /// The clock method of each clock used, by clock name.
    pub clock_methods: std::collections::BTreeMap<String, String>,
    /// What the run changed or noticed about the fleet (free ports given to port-0 endpoints).
    pub notes: Vec<String>,
    /// Whether the thesis's figures are beside ours (`--against-thesis`).
    pub against_thesis: bool,
    /// One report per ordered pair, by (from, to) id.
    pub pairs: Vec<PairReport>,
    /// Every sample (not in the JSON: `samples.csv`).
    #[serde(skip)]
    pub samples: Vec<Sample>,
}

impl LatencyReport {
    /// The report of the pair `from` → `to`.
    pub fn pair(&self, from: &str, to: &str) -> Option<&PairReport> {
        self.pairs.iter().find(|p| p.from == from && p.to == to)
    }
}

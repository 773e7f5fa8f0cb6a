//! The reliability analysis of the thesis (§5.2), in virtual time.
//!
//! Per trial, a fresh [`SimFleet`] is opened (seed = base seed + trial). Every system that has
//! at least one route sends, from its `Plan` module (or the fleet's first module) to the same
//! module of the destination:
//!
//! 1. one broadcast of [`Message1`] at virtual time 0 (one copy per destination the table
//!    allows: two in Table 17), then
//! 2. five point-to-point [`Message2`] to destinations drawn uniformly among the systems it has
//!    a route to, one every [`ReliabilityConfig::spacing`] (1 × spacing, 2 × spacing, …).
//!
//! The destinations come from a ChaCha8 generator seeded with the base seed, drawn once for all
//! trials, so both modes see the same destinations. Then the simulation runs until nothing is
//! scheduled (bounded by [`ReliabilityConfig::time_limit`]); outcomes are read with
//! `try_outcome` and receivals with `try_recv_raw`, never with blocking calls.
//!
//! Counting follows the thesis's Tables 19–20, per (system, transport), where the transport of
//! a message is the one the fleet's table assigns to its (source, destination) pair
//! ([`Fleet::route`]):
//!
//! - *transmit attempts*: messages the system handed to that transport (one per destination,
//!   the first transmission; the thesis's 420 = 3 systems × 7 × 20 trials);
//! - *transmit successes*: of those, the ones whose send ended well (`Sent` in thesis mode:
//!   the transport accepted a transmission; `Delivered` in acknowledged mode);
//! - *receivals*: messages the system received whose pair used that transport (unique ones:
//!   a second copy of a message counts as a duplicate, not a receival);
//! - *additional attempts*: transmissions beyond the first.

use std::collections::{BTreeMap, HashMap, HashSet};
use std::path::Path;
use std::time::Duration;

use hetcomm::config::{DeliveryMode, Fleet, TransportSettings};
use hetcomm::sim::{LossVisibility, SimFleet, SimNetStats, SimOptions};
use hetcomm::{Comm, LocalFleet};
use hetcomm::{FailReason, Message, Outcome, SystemId, Ticket, Time};
use rand::{Rng, SeedableRng};
use rand_chacha::ChaCha8Rng;
use serde::{Deserialize, Serialize};

/// Retransmission timing of a router (re-exported from `hetcomm-router`).
pub use hetcomm_router::Timing;

/// The thesis's result: 413 of 420 messages received (Tables 19–20, §5.2.2).
pub const THESIS_RECEIVED: u64 = 413;
/// Messages the thesis sent: 3 systems × (2 broadcast copies + 5 point-to-point) × 20 trials.
pub const THESIS_TOTAL: u64 = 420;
/// Trials the thesis ran.
pub const THESIS_TRIALS: u32 = 20;
/// Point-to-point messages per system per trial (Fig. 29).
pub const POINT_TO_POINT: u32 = 5;

/// Default attempt budget of the acknowledged mode (first transmission included).
///
/// Chosen so that 30% loss on the Bluetooth link still delivers every message of the 20-trial
/// experiment. Both directions are lossy, so with i.i.d. loss a round trip survives with
/// probability 0.7² = 0.49 and a message fails with probability 0.51⁶⁴ ≈ 2·10⁻¹⁹ (24 attempts
/// would already do: 0.51²⁴·210 messages ≈ 2·10⁻⁵ per run). Bursty loss at the same mean
/// (Gilbert–Elliott, mean burst 3 frames) needs far more: the chain advances per frame, so a
/// sender retransmitting into a bad state stays there with probability 2/3 per attempt, and the
/// acknowledgement direction has its own chain; the failure tail then decays only ≈ 0.80 per
/// attempt. Measured over seeds 1–2000 (30% bursty, 20 trials): the most attempts any message
/// needed was 43, and about 10% of runs lose a message with 24 attempts. 64 leaves a margin
/// of ≈ 0.8²¹ below that; an unreachable peer then takes ≈ 10 s of virtual time to give up.
pub const DEFAULT_ATTEMPTS: u32 = 64;

/// Default retransmission timing of the acknowledged mode: the Bluetooth Classic round trip is
/// about 5 ms (2 × 2.5 ms ± 1.25 ms) and the wired one 0.2 ms, so a first timeout of 20 ms and
/// a floor of 10 ms never fire before an acknowledgement could be back; the backoff doubles it
/// up to 160 ms, so a budget of 64 attempts ends within about 10 s of virtual time.
pub fn default_timing() -> Timing {
    Timing {
        initial_rto: Duration::from_millis(20),
        min_rto: Duration::from_millis(10),
        max_rto: Duration::from_millis(160),
        backoff: 2.0,
        ..Timing::default()
    }
}

/// The broadcast message of Fig. 29 (type id 0, as the thesis's factory function).
#[derive(Serialize, Deserialize, Message, Debug, Clone, PartialEq)]
#[message(id = 0)]
pub struct Message1 {
    /// Trial number.
    pub trial: u32,
    /// Sending system's id.
    pub sender: u16,
}

/// The point-to-point message of Fig. 29 (type id 1).
#[derive(Serialize, Deserialize, Message, Debug, Clone, PartialEq)]
#[message(id = 1)]
pub struct Message2 {
    /// Trial number.
    pub trial: u32,
    /// Sending system's id.
    pub sender: u16,
    /// 1–5: which of the sender's point-to-point messages this is.
    pub index: u8,
}

/// How the experiment delivers.
#[derive(Clone, Copy, Debug, PartialEq, Eq, Hash, PartialOrd, Ord, Serialize, Deserialize)]
#[serde(rename_all = "lowercase")]
pub enum Mode {
    /// Unacknowledged delivery, losses reported by the transport, retries up to the
    /// transport's `attempts` (3): the thesis's situation.
    Thesis,
    /// Acknowledged delivery, silent losses, RTT-based retransmission up to
    /// [`ReliabilityConfig::attempts`].
    Acknowledged,
}

impl Mode {
    /// Both modes, thesis first.
    pub const ALL: [Mode; 2] = [Mode::Thesis, Mode::Acknowledged];

    /// The name used on the command line and in reports.
    pub fn name(self) -> &'static str {
        match self {
            Mode::Thesis => "thesis",
            Mode::Acknowledged => "acknowledged",
        }
    }

    /// Parses a mode name.
    pub fn parse(s: &str) -> Option<Mode> {
        Mode::ALL.into_iter().find(|m| m.name() == s)
    }
}

impl std::fmt::Display for Mode {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        f.write_str(self.name())
    }
}

/// Loss applied to the lossy transport (letter [`ReliabilityConfig::lossy_letter`]).
#[derive(Clone, Copy, Debug, PartialEq, Serialize, Deserialize)]
#[serde(tag = "model", rename_all = "lowercase")]
pub enum LossModel {
    /// Whatever the fleet says (by default the `bluetooth-classic` profile: Gilbert–Elliott,
    /// 7% mean loss, mean burst 3 frames).
    Profile,
    /// Independent loss: `loss_percent`, with the profile's burst loss turned off.
    Iid {
        /// Loss per frame, percent.
        percent: f64,
    },
    /// Gilbert–Elliott loss: `burst_loss_percent` and `burst_length_mean`, with any
    /// independent loss turned off.
    Bursty {
        /// Long-run loss, percent.
        percent: f64,
        /// Mean burst length, frames (≥ 1).
        burst_length: f64,
    },
}

impl LossModel {
    /// A one-line description.
    pub fn describe(&self) -> String {
        match *self {
            LossModel::Profile => "as configured (default: bluetooth-classic profile, \
                                   Gilbert–Elliott 7% mean loss, mean burst 3 frames)"
                .to_string(),
            LossModel::Iid { percent } => format!("i.i.d. {percent}% per frame"),
            LossModel::Bursty {
                percent,
                burst_length,
            } => format!("Gilbert–Elliott {percent}% mean loss, mean burst {burst_length} frames"),
        }
    }

    /// The model's long-run loss in percent, if it overrides the fleet.
    pub fn percent(&self) -> Option<f64> {
        match *self {
            LossModel::Profile => None,
            LossModel::Iid { percent } | LossModel::Bursty { percent, .. } => Some(percent),
        }
    }
}

/// The experiment's settings.
#[derive(Clone, Debug)]
pub struct ReliabilityConfig {
    /// Trials (the thesis ran 20).
    pub trials: u32,
    /// Base seed: destinations, and each trial's simulation seed (base + trial).
    pub seed: u64,
    /// Attempt budget of the acknowledged mode (first transmission included).
    pub attempts: u32,
    /// Modes to run, in order.
    pub modes: Vec<Mode>,
    /// Loss on the lossy transport.
    pub loss: LossModel,
    /// The table letter of the transport [`ReliabilityConfig::loss`] applies to (`B`).
    pub lossy_letter: char,
    /// Router retransmission timing in acknowledged mode (thesis mode keeps the router's
    /// defaults: it only uses the pause before retrying a refused transmission).
    pub timing: Timing,
    /// Virtual time between a system's consecutive sends (the broadcast at 0).
    pub spacing: Duration,
    /// Point-to-point messages per system per trial.
    pub point_to_point: u32,
    /// Longest virtual time a trial may run before its leftovers are counted as in flight.
    pub time_limit: Duration,
    /// Run on the real transports with the wall clock (e.g. `R` on a ROS master) instead of
    /// the virtual-time simulator. Losses are then whatever the real (or real-time emulated)
    /// links do, and are never reported to the sender, so thesis mode retries only
    /// transports that refuse a frame.
    pub realtime: bool,
    /// A scenario file's faults, injections and taps, applied to every trial with scenario
    /// time 0 at the trial's start (`hetcomm experiment reliability --scenario FILE`).
    pub scenario: Option<hetcomm::config::scenario::Scenario>,
}

impl Default for ReliabilityConfig {
    fn default() -> Self {
        ReliabilityConfig {
            trials: THESIS_TRIALS,
            seed: 2019,
            attempts: DEFAULT_ATTEMPTS,
            modes: Mode::ALL.to_vec(),
            loss: LossModel::Profile,
            lossy_letter: 'B',
            timing: default_timing(),
            spacing: Duration::from_millis(5),
            point_to_point: POINT_TO_POINT,
            time_limit: Duration::from_secs(120),
            realtime: false,
            scenario: None,
        }
    }
}

/// Why the experiment could not run.
#[derive(Debug, thiserror::Error)]
pub enum ExperimentError {
    /// A setting is out of range or does not fit the fleet.
    #[error("{0}")]
    Invalid(String),
    /// The fleet file did not load.
    #[error("fleet file: {0}")]
    Fleet(String),
    /// The simulation could not be opened.
    #[error("opening the simulation: {0}")]
    Open(#[from] hetcomm::OpenError),
    /// A send was refused before anything was transmitted.
    #[error("send from {from} to {to} was refused: {reason}")]
    Send {
        /// Sending system.
        from: String,
        /// Destination.
        to: String,
        /// Why.
        reason: String,
    },
    /// Reading or writing a file failed.
    #[error("{context}: {source}")]
    Io {
        /// What was being done.
        context: String,
        /// The error.
        source: std::io::Error,
    },
    /// Drawing or encoding a plot failed.
    #[error("plot: {0}")]
    Plot(String),
}

impl ExperimentError {
    pub(crate) fn io(context: impl Into<String>) -> impl FnOnce(std::io::Error) -> Self {
        let context = context.into();
        move |source| ExperimentError::Io { context, source }
    }
}

/// The default fleet's files (Tables 16–18 and the fleet file mapping R and B), embedded:
/// (file name, contents).
pub const DEFAULT_FLEET_FILES: [(&str, &str); 4] = [
    ("fleet.toml", include_str!("../data/fleet.toml")),
    ("table16-ids.txt", include_str!("../data/table16-ids.txt")),
    (
        "table17-table.txt",
        include_str!("../data/table17-table.txt"),
    ),
    (
        "table18-bluetooth.txt",
        include_str!("../data/table18-bluetooth.txt"),
    ),
];

/// Writes the default fleet's files into `dir` (created if missing) and returns the path of
/// its `fleet.toml`.
pub fn write_default_fleet(dir: &Path) -> Result<std::path::PathBuf, ExperimentError> {
    std::fs::create_dir_all(dir)
        .map_err(ExperimentError::io(format!("creating {}", dir.display())))?;
    for (name, text) in DEFAULT_FLEET_FILES {
        let path = dir.join(name);
        std::fs::write(&path, text)
            .map_err(ExperimentError::io(format!("writing {}", path.display())))?;
    }
    Ok(dir.join("fleet.toml"))
}

/// Loads a fleet file, turning its located errors into one message.
pub fn load_fleet(path: &Path) -> Result<Fleet, ExperimentError> {
    hetcomm::load_fleet(path).map_err(|e| ExperimentError::Fleet(e.to_string()))
}

/// The default fleet: Tables 16–18 with R = emulated `wired`, B = emulated
/// `bluetooth-classic`. The embedded files are written to a private temporary directory,
/// loaded, and removed.
pub fn default_fleet() -> Result<Fleet, ExperimentError> {
    use std::sync::atomic::{AtomicU64, Ordering};
    static COUNTER: AtomicU64 = AtomicU64::new(0);
    let dir = std::env::temp_dir().join(format!(
        "hetcomm-experiments-{}-{}",
        std::process::id(),
        COUNTER.fetch_add(1, Ordering::Relaxed)
    ));
    let result = write_default_fleet(&dir).and_then(|path| load_fleet(&path));
    let _ = std::fs::remove_dir_all(&dir);
    let mut fleet = result?;
    // The fleet came from a temporary file; don't leave its path in the model.
    fleet.source = None;
    Ok(fleet)
}

/// One transport as a mode configured it.
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
pub struct TransportInfo {
    /// Its table letter (tag byte).
    pub letter: String,
    /// Its name in the fleet file.
    pub name: String,
    /// Its kind.
    pub kind: String,
    /// `acknowledged` or `unacknowledged`.
    pub delivery: String,
    /// Attempt budget.
    pub attempts: u32,
    /// Emulation profile, if any.
    pub profile: Option<String>,
    /// Emulation parameters set explicitly (overriding the profile).
    pub params: BTreeMap<String, f64>,
}

/// Counts of one system on one transport (a cell group of Tables 19 and 20).
#[derive(Clone, Debug, Default, PartialEq, Eq, Serialize, Deserialize)]
pub struct TransportCounts {
    /// The transport's letter.
    pub transport: String,
    /// Messages handed to the transport (first transmissions).
    pub transmit_attempts: u64,
    /// Of those, sends that ended well (`Sent` or `Delivered`).
    pub transmit_successes: u64,
    /// Unique messages received over this transport.
    pub receivals: u64,
    /// Transmissions beyond the first.
    pub additional_attempts: u64,
    /// Sends that ended unconfirmed: frames left, no acknowledgement came back (the message
    /// may or may not have arrived; compare `receivals`).
    pub unconfirmed: u64,
    /// Sends that failed (certainly not delivered).
    pub failed: u64,
}

/// One row of Tables 19 and 20.
#[derive(Clone, Debug, PartialEq, Eq, Serialize, Deserialize)]
pub struct SystemRow {
    /// The system's name.
    pub system: String,
    /// One entry per transport, in the order of [`ModeReport::transports`].
    pub per_transport: Vec<TransportCounts>,
}

/// Delay statistics, milliseconds of virtual time (send to receipt of received messages).
#[derive(Clone, Debug, Default, PartialEq, Serialize, Deserialize)]
pub struct DelayStats {
    /// Messages measured.
    pub count: u64,
    /// Mean.
    pub mean_ms: f64,
    /// 50th percentile (nearest rank).
    pub p50_ms: f64,
    /// 99th percentile (nearest rank).
    pub p99_ms: f64,
    /// Largest.
    pub max_ms: f64,
}

impl DelayStats {
    /// Statistics of delays given in microseconds.
    pub fn from_micros(mut delays: Vec<u64>) -> DelayStats {
        if delays.is_empty() {
            return DelayStats::default();
        }
        delays.sort_unstable();
        let n = delays.len();
        let rank = |q: f64| delays[((q * n as f64).ceil() as usize).clamp(1, n) - 1] as f64 / 1e3;
        DelayStats {
            count: n as u64,
            mean_ms: delays.iter().map(|&d| d as f64).sum::<f64>() / n as f64 / 1e3,
            p50_ms: rank(0.50),
            p99_ms: rank(0.99),
            max_ms: delays[n - 1] as f64 / 1e3,
        }
    }
}

/// The send-side accounting: every accepted send ends in exactly one of these.
#[derive(Clone, Debug, Default, PartialEq, Eq, Serialize, Deserialize)]
pub struct Accounting {
    /// Sends the routers accepted (`RouterStats::sends`, summed).
    pub accepted: u64,
    /// Ended delivered (acknowledged).
    pub delivered: u64,
    /// Ended sent without confirmation (unacknowledged).
    pub sent: u64,
    /// Ended unconfirmed: frames left, no acknowledgement came back.
    pub unconfirmed: u64,
    /// Ended failed (certainly not delivered).
    pub failed: u64,
    /// Not ended when the trial stopped (`RouterStats::in_flight`, summed).
    pub in_flight: u64,
    /// Tickets without an outcome when the trial stopped (should equal `in_flight`).
    pub unresolved_tickets: u64,
    /// `accepted == delivered + sent + unconfirmed + failed + in_flight`, and the tickets agree
    /// with the routers' counters.
    pub balanced: bool,
}

/// What one mode measured over all trials.
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
pub struct ModeReport {
    /// `thesis` or `acknowledged`.
    pub mode: Mode,
    /// What the mode means, in a sentence.
    pub description: String,
    /// `silent` or `reported`.
    pub losses: String,
    /// The transports as configured for this mode, in table-column order.
    pub transports: Vec<TransportInfo>,
    /// Retransmission timing in milliseconds: initial, min, max RTO and the backoff factor.
    pub timing: TimingInfo,
    /// Tables 19–20, one row per sending system.
    pub systems: Vec<SystemRow>,
    /// Messages sent (one per destination).
    pub messages: u64,
    /// Unique messages received.
    pub received: u64,
    /// `received / messages`, percent.
    pub delivery_ratio_percent: f64,
    /// Messages that reached a module's inbox more than once (must be 0).
    pub duplicates_delivered: u64,
    /// Messages a receiver got before an earlier message of the same sender (acknowledged
    /// mode runs its transports with `ordered = true`, so this must be 0 there).
    pub out_of_order: u64,
    /// Duplicate frames the receiving routers suppressed (retransmissions whose ack was lost).
    pub duplicates_suppressed: u64,
    /// Send-side accounting.
    pub accounting: Accounting,
    /// Failures by reason.
    pub failure_reasons: BTreeMap<String, u64>,
    /// Transmissions of data frames (first attempts and retransmissions).
    pub transmissions: u64,
    /// Mean transmissions per message.
    pub attempts_per_message: f64,
    /// Most transmissions any one message needed.
    pub max_attempts: u32,
    /// Send-to-receipt delay of the received messages.
    pub delay: DelayStats,
    /// Frames the simulated network dropped, by reason, summed over trials.
    pub network_drops: BTreeMap<String, u64>,
    /// Frames put on simulated links (data and acknowledgements), summed over trials.
    pub network_frames: u64,
    /// Virtual time the trials took, summed, seconds.
    pub virtual_seconds: f64,
}

/// Router timing as reported.
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
pub struct TimingInfo {
    /// First retransmission timeout, ms.
    pub initial_rto_ms: f64,
    /// Floor, ms.
    pub min_rto_ms: f64,
    /// Ceiling, ms.
    pub max_rto_ms: f64,
    /// Growth per unanswered attempt.
    pub backoff: f64,
    /// Pause before retrying a transmission the transport refused, ms (doubles per attempt).
    pub link_retry_ms: f64,
}

impl From<Timing> for TimingInfo {
    fn from(t: Timing) -> Self {
        TimingInfo {
            initial_rto_ms: t.initial_rto.as_secs_f64() * 1e3,
            min_rto_ms: t.min_rto.as_secs_f64() * 1e3,
            max_rto_ms: t.max_rto.as_secs_f64() * 1e3,
            backoff: t.backoff,
            link_retry_ms: t.link_retry.as_secs_f64() * 1e3,
        }
    }
}

/// The thesis's published numbers (Tables 19 and 20), for comparison.
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
pub struct ThesisReference {
    /// Messages received.
    pub received: u64,
    /// Messages sent.
    pub total: u64,
    /// Percent.
    pub delivery_ratio_percent: f64,
    /// Table 19 and 20, rows Bravo, Charlie, Delta; per transport R then B.
    pub systems: Vec<SystemRow>,
}

impl ThesisReference {
    /// Tables 19–20 as published.
    pub fn published() -> ThesisReference {
        let row = |system: &str, r: [u64; 4], b: [u64; 4]| SystemRow {
            system: system.to_string(),
            per_transport: [("R", r), ("B", b)]
                .into_iter()
                .map(|(t, [a, s, rx, add])| TransportCounts {
                    transport: t.to_string(),
                    transmit_attempts: a,
                    transmit_successes: s,
                    receivals: rx,
                    additional_attempts: add,
                    unconfirmed: 0,
                    failed: a - s,
                })
                .collect(),
        };
        ThesisReference {
            received: THESIS_RECEIVED,
            total: THESIS_TOTAL,
            delivery_ratio_percent: round2(100.0 * THESIS_RECEIVED as f64 / THESIS_TOTAL as f64),
            systems: vec![
                row("Bravo", [65, 65, 60, 0], [75, 74, 69, 5]),
                row("Charlie", [69, 69, 60, 0], [71, 69, 82, 7]),
                row("Delta", [54, 54, 68, 0], [86, 82, 74, 13]),
            ],
        }
    }
}

/// A whole run: the settings and one report per mode.
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
pub struct ReliabilityReport {
    /// `reliability`.
    pub experiment: String,
    /// Trials per mode.
    pub trials: u32,
    /// Base seed.
    pub seed: u64,
    /// Attempt budget of the acknowledged mode.
    pub acknowledged_attempts: u32,
    /// The loss applied to the lossy transport.
    pub loss: LossModel,
    /// The same, in words.
    pub loss_description: String,
    /// Letter of the transport the loss applies to.
    pub lossy_transport: String,
    /// Messages per trial (all systems).
    pub messages_per_trial: u64,
    /// The thesis's numbers.
    pub thesis: ThesisReference,
    /// One report per mode, in the order run.
    pub modes: Vec<ModeReport>,
}

impl ReliabilityReport {
    /// The report of one mode, if it ran.
    pub fn mode(&self, mode: Mode) -> Option<&ModeReport> {
        self.modes.iter().find(|m| m.mode == mode)
    }
}

pub(crate) fn round2(x: f64) -> f64 {
    (x * 100.0).round() / 100.0
}

/// Checks the settings on their own.
pub fn validate(config: &ReliabilityConfig) -> Result<(), ExperimentError> {
    let bad = |m: String| Err(ExperimentError::Invalid(m));
    if config.trials == 0 {
        return bad("--trials must be at least 1".into());
    }
    if config.attempts == 0 {
        return bad("--attempts must be at least 1 (the first transmission counts)".into());
    }
    if config.point_to_point > u8::MAX as u32 {
        return bad(format!(
            "at most {} point-to-point messages per system per trial",
            u8::MAX
        ));
    }
    if config.modes.is_empty() {
        return bad("no mode to run".into());
    }
    if config.timing.initial_rto.is_zero() || config.timing.backoff < 1.0 {
        return bad(
            "the retransmission timing needs a positive initial RTO and backoff ≥ 1".into(),
        );
    }
    if config.timing.min_rto > config.timing.max_rto {
        return bad("the minimum RTO must not exceed the maximum".into());
    }
    match config.loss {
        LossModel::Profile => {}
        LossModel::Iid { percent } => {
            if !(0.0..=100.0).contains(&percent) {
                return bad(format!(
                    "--loss must be a percentage in 0–100, got {percent}"
                ));
            }
        }
        LossModel::Bursty {
            percent,
            burst_length,
        } => {
            if !(0.0..=100.0).contains(&percent) {
                return bad(format!(
                    "--burst-loss must be a percentage in 0–100, got {percent}"
                ));
            }
            if !(burst_length.is_finite() && burst_length >= 1.0) {
                return bad(format!(
                    "--burst-length must be a number of frames ≥ 1, got {burst_length}"
                ));
            }
            let max = 100.0 * burst_length / (1.0 + burst_length);
            if percent > max {
                return bad(format!(
                    "--burst-loss {percent}% cannot be reached with --burst-length \
                     {burst_length}: at most 100·L/(1+L) = {max:.2}% (longer bursts allow more loss)"
                ));
            }
        }
    }
    Ok(())
}

/// What runs a trial: the virtual-time simulator, or the real transports in real time.
enum Driver {
    Sim(SimFleet),
    Real {
        fleet: LocalFleet,
        start: std::time::Instant,
    },
}

impl Driver {
    fn system(&self, name: &str) -> Result<Comm, hetcomm::OpenError> {
        match self {
            Driver::Sim(sim) => sim.system(name),
            Driver::Real { fleet, .. } => fleet.system(name),
        }
    }

    fn systems(&self) -> &[Comm] {
        match self {
            Driver::Sim(sim) => sim.systems(),
            Driver::Real { fleet, .. } => fleet.systems(),
        }
    }

    /// Lets time pass up to `at` after the start of the trial.
    fn run_until(&self, at: Time) {
        match self {
            Driver::Sim(sim) => sim.run_until(at),
            Driver::Real { start, .. } => {
                let due = *start + at.saturating_since(Time::ZERO);
                std::thread::sleep(due.saturating_duration_since(std::time::Instant::now()));
            }
        }
    }

    /// The time to stamp a send with, on the clock receivers stamp arrivals with.
    fn now(&self) -> Time {
        match self {
            Driver::Sim(sim) => sim.now(),
            Driver::Real { .. } => Time::now_wall(),
        }
    }

    /// Runs until every send ended (or `limit` after the start), then returns the seconds
    /// the trial took on its own clock.
    fn finish(&self, limit: Duration, tickets: &[&Ticket]) -> f64 {
        match self {
            Driver::Sim(sim) => {
                sim.run_idle(Time::ZERO + limit);
                sim.now().as_secs_f64()
            }
            Driver::Real { start, .. } => {
                let deadline = *start + limit;
                for t in tickets {
                    let left = deadline.saturating_duration_since(std::time::Instant::now());
                    let _ = t.wait_timeout(left);
                }
                // Unacknowledged messages may still be on their way: a short grace period.
                std::thread::sleep(Duration::from_millis(200));
                start.elapsed().as_secs_f64()
            }
        }
    }

    fn net_stats(&self) -> SimNetStats {
        match self {
            Driver::Sim(sim) => sim.net_stats(),
            Driver::Real { .. } => SimNetStats::default(),
        }
    }
}

/// The fleet of one mode: delivery, budgets and loss set on a copy of `base`.
pub fn fleet_for_mode(
    base: &Fleet,
    mode: Mode,
    config: &ReliabilityConfig,
) -> Result<Fleet, ExperimentError> {
    let mut fleet = base.clone();
    let letter = config.lossy_letter;
    let mut found = config.loss == LossModel::Profile;
    for t in &mut fleet.transports {
        match mode {
            Mode::Thesis => t.delivery = DeliveryMode::Unacknowledged,
            Mode::Acknowledged => {
                t.delivery = DeliveryMode::Acknowledged;
                t.attempts = config.attempts;
                // Each sender's messages reach each receiver in the order sent.
                t.ordered = true;
            }
        }
        if config.loss == LossModel::Profile || t.tag != letter as u8 {
            continue;
        }
        let TransportSettings::Emulated(settings) = &mut t.settings else {
            return Err(ExperimentError::Invalid(format!(
                "the loss options apply to the transport of letter {letter}, but `{}` is a {} \
                 transport, not an emulated one",
                t.name, t.kind
            )));
        };
        let p = &mut settings.params;
        match config.loss {
            LossModel::Profile => {}
            LossModel::Iid { percent } => {
                p.insert("loss_percent".into(), percent);
                p.insert("burst_loss_percent".into(), 0.0);
            }
            LossModel::Bursty {
                percent,
                burst_length,
            } => {
                p.insert("loss_percent".into(), 0.0);
                p.insert("burst_loss_percent".into(), percent);
                p.insert("burst_length_mean".into(), burst_length);
            }
        }
        hetcomm::link::emulation::ModelParams::from_settings(settings).map_err(|e| {
            ExperimentError::Invalid(format!("transport `{}` with the loss options: {e}", t.name))
        })?;
        found = true;
    }
    if !found {
        return Err(ExperimentError::Invalid(format!(
            "the loss options apply to the transport of letter {letter}, but no transport of the \
             fleet has that letter"
        )));
    }
    Ok(fleet)
}

/// The systems that send (those with at least one route), by id, each with its destinations.
fn senders(fleet: &Fleet) -> Vec<(SystemId, Vec<SystemId>)> {
    fleet
        .systems
        .iter()
        .map(|s| {
            let dests: Vec<SystemId> = fleet
                .systems
                .iter()
                .filter(|d| d.id != s.id && fleet.route(s.id, d.id).is_some())
                .map(|d| d.id)
                .collect();
            (s.id, dests)
        })
        .filter(|(_, d)| !d.is_empty())
        .collect()
}

/// Point-to-point destinations: `[trial][sender index][k]`.
fn plan(
    senders: &[(SystemId, Vec<SystemId>)],
    config: &ReliabilityConfig,
) -> Vec<Vec<Vec<SystemId>>> {
    let mut rng = ChaCha8Rng::seed_from_u64(config.seed);
    (0..config.trials)
        .map(|_| {
            senders
                .iter()
                .map(|(_, dests)| {
                    (0..config.point_to_point)
                        .map(|_| dests[rng.gen_range(0..dests.len())])
                        .collect()
                })
                .collect()
        })
        .collect()
}

/// The module the experiment uses: `Plan` if the fleet has it, else its first module.
fn module_name(fleet: &Fleet) -> Result<String, ExperimentError> {
    fleet
        .module_by_name("Plan")
        .or(fleet.modules.first())
        .map(|m| m.name.clone())
        .ok_or_else(|| ExperimentError::Invalid("the fleet defines no modules".into()))
}

/// Transport indices the table uses, in fleet order.
fn used_transports(fleet: &Fleet) -> Vec<usize> {
    let used: HashSet<usize> = fleet.table.values().copied().collect();
    (0..fleet.transports.len())
        .filter(|i| used.contains(i))
        .collect()
}

fn letter_of(fleet: &Fleet, index: usize) -> String {
    let t = &fleet.transports[index];
    if t.tag.is_ascii_graphic() {
        (t.tag as char).to_string()
    } else {
        t.name.clone()
    }
}

fn transport_info(fleet: &Fleet, index: usize) -> TransportInfo {
    let t = &fleet.transports[index];
    let (profile, params) = match &t.settings {
        TransportSettings::Emulated(s) => (s.profile.clone(), s.params.clone()),
        _ => (None, BTreeMap::new()),
    };
    TransportInfo {
        letter: letter_of(fleet, index),
        name: t.name.clone(),
        kind: t.kind.to_string(),
        delivery: match t.delivery {
            DeliveryMode::Acknowledged => "acknowledged".into(),
            DeliveryMode::Unacknowledged => "unacknowledged".into(),
        },
        attempts: t.attempts,
        profile,
        params,
    }
}

/// One send of a trial.
struct SendRecord {
    from: SystemId,
    to: SystemId,
    /// 0 for the broadcast, 1… for the point-to-point messages.
    index: u8,
    at: Time,
    ticket: Ticket,
}

/// Runs the experiment on `fleet` (see the module docs).
pub fn run(
    fleet: &Fleet,
    config: &ReliabilityConfig,
) -> Result<ReliabilityReport, ExperimentError> {
    validate(config)?;
    let senders = senders(fleet);
    if senders.is_empty() {
        return Err(ExperimentError::Invalid(
            "the fleet's table has no traffic: no system can send".into(),
        ));
    }
    let plan = plan(&senders, config);
    let mut modes = Vec::with_capacity(config.modes.len());
    for &mode in &config.modes {
        let mode_fleet = fleet_for_mode(fleet, mode, config)?;
        modes.push(run_mode(&mode_fleet, mode, config, &senders, &plan)?);
    }
    let messages_per_trial = senders
        .iter()
        .map(|(_, d)| d.len() as u64 + config.point_to_point as u64)
        .sum();
    Ok(ReliabilityReport {
        experiment: "reliability".into(),
        trials: config.trials,
        seed: config.seed,
        acknowledged_attempts: config.attempts,
        loss: config.loss,
        loss_description: config.loss.describe(),
        lossy_transport: config.lossy_letter.to_string(),
        messages_per_trial,
        thesis: ThesisReference::published(),
        modes,
    })
}

fn run_mode(
    fleet: &Fleet,
    mode: Mode,
    config: &ReliabilityConfig,
    senders: &[(SystemId, Vec<SystemId>)],
    plan: &[Vec<Vec<SystemId>>],
) -> Result<ModeReport, ExperimentError> {
    let module = module_name(fleet)?;
    let columns = used_transports(fleet);
    let column_of: HashMap<usize, usize> =
        columns.iter().enumerate().map(|(c, &i)| (i, c)).collect();
    let col = |from: SystemId, to: SystemId| -> usize {
        fleet
            .table
            .get(&(from, to))
            .and_then(|i| column_of.get(i))
            .copied()
            .unwrap_or(0)
    };
    let name_of = |id: SystemId| -> String {
        fleet
            .system(id)
            .map(|s| s.name.clone())
            .unwrap_or_else(|| id.0.to_string())
    };
    // Rows: every system of the fleet (a system may only receive).
    let mut rows: Vec<SystemRow> = fleet
        .systems
        .iter()
        .map(|s| SystemRow {
            system: s.name.clone(),
            per_transport: columns
                .iter()
                .map(|&i| TransportCounts {
                    transport: letter_of(fleet, i),
                    ..Default::default()
                })
                .collect(),
        })
        .collect();
    let row_of: HashMap<SystemId, usize> = fleet
        .systems
        .iter()
        .enumerate()
        .map(|(r, s)| (s.id, r))
        .collect();
    let losses = match mode {
        Mode::Thesis => LossVisibility::Reported,
        Mode::Acknowledged => LossVisibility::Silent,
    };
    let timing = match mode {
        Mode::Thesis => None,
        Mode::Acknowledged => Some(config.timing),
    };

    let mut messages = 0u64;
    let mut received = 0u64;
    let mut duplicates_delivered = 0u64;
    let mut out_of_order = 0u64;
    let mut duplicates_suppressed = 0u64;
    let mut acc = Accounting::default();
    let mut failure_reasons = BTreeMap::new();
    let mut transmissions = 0u64;
    let mut max_attempts = 0u32;
    let mut attempts_sum = 0u64;
    let mut resolved = 0u64;
    let mut delays = Vec::new();
    let mut network_drops = BTreeMap::new();
    let mut network_frames = 0u64;
    let mut virtual_seconds = 0.0;

    for (trial, destinations) in plan.iter().enumerate() {
        let trial_no = trial as u32;
        let sim = if config.realtime {
            Driver::Real {
                fleet: LocalFleet::open(fleet.clone())?,
                start: std::time::Instant::now(),
            }
        } else {
            Driver::Sim(SimFleet::open(
                fleet.clone(),
                SimOptions {
                    seed: config.seed.wrapping_add(trial as u64),
                    losses,
                    timing,
                },
            )?)
        };
        let _scenario = match (&config.scenario, &sim) {
            (Some(sc), Driver::Sim(s)) => Some(s.apply_scenario(sc, config.seed)),
            (Some(sc), Driver::Real { fleet, .. }) => Some(fleet.apply_scenario(sc, config.seed)),
            (None, _) => None,
        }
        .transpose()
        .map_err(|e| ExperimentError::Invalid(e.to_string()))?;
        let modules = senders
            .iter()
            .map(|(id, _)| {
                sim.system(&name_of(*id))
                    .and_then(|c| c.module(&module))
                    .map_err(ExperimentError::from)
            })
            .collect::<Result<Vec<_>, _>>()?;
        let receivers = fleet
            .systems
            .iter()
            .map(|s| {
                sim.system(&s.name)
                    .and_then(|c| c.module(&module))
                    .map(|m| (s.id, m))
                    .map_err(ExperimentError::from)
            })
            .collect::<Result<Vec<_>, _>>()?;
        let refused = |from: SystemId, to: &str, e: hetcomm::SendError| ExperimentError::Send {
            from: name_of(from),
            to: to.to_string(),
            reason: e.to_string(),
        };
        let mut sends: Vec<SendRecord> = Vec::new();
        for step in 0..=config.point_to_point {
            let at = Time::ZERO + config.spacing * step;
            sim.run_until(at);
            for (s, ((from, _), m)) in senders.iter().zip(&modules).enumerate() {
                let now = sim.now();
                if step == 0 {
                    let msg = Message1 {
                        trial: trial_no,
                        sender: from.0,
                    };
                    let b = m
                        .broadcast(&module, &msg)
                        .map_err(|e| refused(*from, "All", e))?;
                    for t in b.tickets() {
                        let to = fleet
                            .system_by_name(t.destination())
                            .map(|d| d.id)
                            .unwrap_or(*from);
                        sends.push(SendRecord {
                            from: *from,
                            to,
                            index: 0,
                            at: now,
                            ticket: t.clone(),
                        });
                    }
                } else {
                    let to = destinations[s][step as usize - 1];
                    let to_name = name_of(to);
                    let msg = Message2 {
                        trial: trial_no,
                        sender: from.0,
                        index: step as u8,
                    };
                    let ticket = m
                        .send(&to_name, &module, &msg)
                        .map_err(|e| refused(*from, &to_name, e))?;
                    sends.push(SendRecord {
                        from: *from,
                        to,
                        index: step as u8,
                        at: now,
                        ticket,
                    });
                }
            }
        }
        let tickets: Vec<&Ticket> = sends.iter().map(|r| &r.ticket).collect();
        virtual_seconds += sim.finish(config.time_limit, &tickets);

        // Send side.
        for rec in &sends {
            messages += 1;
            let c = &mut rows[row_of[&rec.from]].per_transport[col(rec.from, rec.to)];
            c.transmit_attempts += 1;
            match rec.ticket.try_outcome() {
                None => acc.unresolved_tickets += 1,
                Some(outcome) => {
                    let attempts = outcome.attempts();
                    resolved += 1;
                    attempts_sum += attempts as u64;
                    max_attempts = max_attempts.max(attempts);
                    c.additional_attempts += attempts.saturating_sub(1) as u64;
                    match &outcome {
                        Outcome::Failed { reason, .. } => {
                            c.failed += 1;
                            *failure_reasons.entry(reason_name(reason)).or_insert(0) += 1;
                        }
                        Outcome::Unconfirmed { .. } => c.unconfirmed += 1,
                        Outcome::Delivered { .. } | Outcome::Sent { .. } => {
                            c.transmit_successes += 1
                        }
                    }
                }
            }
        }
        let sent_at: HashMap<(SystemId, SystemId, u8), Time> = sends
            .iter()
            .map(|rec| ((rec.from, rec.to, rec.index), rec.at))
            .collect();

        // Receive side.
        let mut seen: HashSet<(SystemId, SystemId, u8)> = HashSet::new();
        // Per (sender, receiver): the index of the last message received, to check order
        // (each sender sends index 0, the broadcast, then 1..=5).
        let mut last_index: HashMap<(SystemId, SystemId), u8> = HashMap::new();
        for (me, m) in &receivers {
            while let Some(raw) = m.try_recv_raw() {
                let from = raw.envelope.source().system;
                let index = if raw.envelope.message_type() == Message1::TYPE {
                    match hetcomm::payload::decode::<Message1>(&raw.payload) {
                        Ok(msg) if msg.trial == trial_no => 0u8,
                        _ => continue,
                    }
                } else if raw.envelope.message_type() == Message2::TYPE {
                    match hetcomm::payload::decode::<Message2>(&raw.payload) {
                        Ok(msg) if msg.trial == trial_no => msg.index,
                        _ => continue,
                    }
                } else {
                    continue;
                };
                let key = (from, *me, index);
                if !seen.insert(key) {
                    duplicates_delivered += 1;
                    continue;
                }
                received += 1;
                if let Some(last) = last_index.insert((from, *me), index) {
                    if index < last {
                        out_of_order += 1;
                    }
                }
                rows[row_of[me]].per_transport[col(from, *me)].receivals += 1;
                let sent = sent_at
                    .get(&key)
                    .copied()
                    .unwrap_or(raw.envelope.timestamp());
                delays.push(
                    raw.envelope
                        .received_at
                        .as_micros()
                        .saturating_sub(sent.as_micros()),
                );
            }
        }

        for comm in sim.systems() {
            let r = comm.stats().router;
            acc.accepted += r.sends;
            acc.delivered += r.delivered;
            acc.sent += r.sent;
            acc.unconfirmed += r.unconfirmed;
            acc.failed += r.failed;
            acc.in_flight += r.in_flight();
            duplicates_suppressed += r.duplicates;
            transmissions += r.transmissions;
        }
        let net = sim.net_stats();
        network_frames += net.frames_sent;
        for (k, v) in net.dropped {
            *network_drops.entry(k).or_insert(0) += v;
        }
    }
    let cells = || rows.iter().flat_map(|r| &r.per_transport);
    let outcome_failed: u64 = cells().map(|c| c.failed).sum();
    let outcome_unconfirmed: u64 = cells().map(|c| c.unconfirmed).sum();
    acc.balanced = acc.accepted
        == acc.delivered + acc.sent + acc.unconfirmed + acc.failed + acc.in_flight
        && acc.accepted == messages
        && acc.failed == outcome_failed
        && acc.unconfirmed == outcome_unconfirmed
        && acc.unresolved_tickets == acc.in_flight;
    let description = match mode {
        Mode::Thesis => format!(
            "unacknowledged delivery; the transport reports a failed transmission and the router \
             retries after a pause ({} ms, doubling) up to the transport's attempt budget; \
             success = the transport accepted the frame",
            timing.unwrap_or_default().link_retry.as_secs_f64() * 1e3
        ),
        Mode::Acknowledged => format!(
            "acknowledged delivery; losses are silent; the receiving router acknowledges and the \
             sender retransmits on an RTT-based timeout, up to {} attempts",
            config.attempts
        ),
    };
    Ok(ModeReport {
        mode,
        description,
        losses: match (config.realtime, losses) {
            (true, _) => "as the real links behave (real time)".into(),
            (false, LossVisibility::Silent) => "silent".into(),
            (false, LossVisibility::Reported) => "reported".into(),
        },
        transports: columns.iter().map(|&i| transport_info(fleet, i)).collect(),
        timing: TimingInfo::from(timing.unwrap_or_default()),
        systems: rows,
        messages,
        received,
        delivery_ratio_percent: if messages == 0 {
            0.0
        } else {
            100.0 * received as f64 / messages as f64
        },
        duplicates_delivered,
        out_of_order,
        duplicates_suppressed,
        accounting: acc,
        failure_reasons,
        transmissions,
        attempts_per_message: if resolved == 0 {
            0.0
        } else {
            attempts_sum as f64 / resolved as f64
        },
        max_attempts,
        delay: DelayStats::from_micros(delays),
        network_drops,
        network_frames,
        virtual_seconds,
    })
}

fn reason_name(reason: &FailReason) -> String {
    match reason {
        FailReason::NoAcknowledgement => "no-acknowledgement".into(),
        FailReason::Unreachable(_) => "unreachable".into(),
        FailReason::Congested(_) => "congested".into(),
        FailReason::InboxFull => "inbox-full".into(),
        FailReason::UnknownModule => "unknown-module".into(),
        FailReason::Link(_) => "link".into(),
        FailReason::Backpressure => "backpressure".into(),
        FailReason::Shutdown => "shutdown".into(),
        #[allow(unreachable_patterns)]
        _ => "other".into(),
    }
}

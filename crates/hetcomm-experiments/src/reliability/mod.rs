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
//!
//! Settings and fleets live here, the figures a run gives in `results`, running the trials in
//! `trial`.

mod results;
mod trial;

pub use results::*;
pub(crate) use trial::module_name;
pub use trial::{fleet_for_mode, run};

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
    ("fleet.toml", include_str!("../../data/fleet.toml")),
    (
        "table16-ids.txt",
        include_str!("../../data/table16-ids.txt"),
    ),
    (
        "table17-table.txt",
        include_str!("../../data/table17-table.txt"),
    ),
    (
        "table18-bluetooth.txt",
        include_str!("../../data/table18-bluetooth.txt"),
    ),
];

/// Writes the default fleet's files into `dir` (created if missing) and returns the path of
/// its `fleet.toml`.
pub fn write_default_fleet(dir: &Path) -> Result<std::path::PathBuf, ExperimentError> {
    write_fleet_files(dir, &DEFAULT_FLEET_FILES)
}

/// Writes a fleet's files, (name, contents), into `dir` (created if missing) and returns the
/// path of its `fleet.toml`.
pub(crate) fn write_fleet_files(
    dir: &Path,
    files: &[(&str, &str)],
) -> Result<std::path::PathBuf, ExperimentError> {
    std::fs::create_dir_all(dir)
        .map_err(ExperimentError::io(format!("creating {}", dir.display())))?;
    for (name, text) in files {
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

//! What a run of the reliability experiment gives: per mode, per system and transport.

// The parent's imports and types.
use super::*;

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

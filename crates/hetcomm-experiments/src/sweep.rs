//! The loss sweep: the reliability experiment at several loss rates on the lossy transport,
//! for independent and bursty loss, in every mode.

use std::fmt::Write as _;
use std::path::{Path, PathBuf};

use hetcomm::config::Fleet;
use serde::{Deserialize, Serialize};

use crate::reliability::{self, ExperimentError, LossModel, Mode, ReliabilityConfig};

/// The loss rates of the sweep, percent.
pub const DEFAULT_RATES: [f64; 7] = [0.0, 5.0, 10.0, 15.0, 20.0, 25.0, 30.0];

/// Mean burst length of the sweep's bursty loss, frames.
pub const DEFAULT_BURST_LENGTH: f64 = 3.0;

/// The sweep's settings.
#[derive(Clone, Debug)]
pub struct SweepConfig {
    /// Everything but the loss model (which the sweep sets).
    pub base: ReliabilityConfig,
    /// Loss rates, percent.
    pub rates: Vec<f64>,
    /// Mean burst length of the bursty runs.
    pub burst_length: f64,
}

impl Default for SweepConfig {
    fn default() -> Self {
        SweepConfig {
            base: ReliabilityConfig::default(),
            rates: DEFAULT_RATES.to_vec(),
            burst_length: DEFAULT_BURST_LENGTH,
        }
    }
}

/// One (mode, loss model, loss rate) point.
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
pub struct SweepPoint {
    /// The mode.
    pub mode: Mode,
    /// `iid` or `bursty`.
    pub loss_model: String,
    /// Long-run loss on the lossy transport, percent.
    pub loss_percent: f64,
    /// Messages sent.
    pub messages: u64,
    /// Unique messages received.
    pub received: u64,
    /// `received / messages`, percent.
    pub delivery_ratio_percent: f64,
    /// Messages delivered more than once.
    pub duplicates_delivered: u64,
    /// Sends that ended unconfirmed (may or may not have arrived).
    pub unconfirmed: u64,
    /// Sends that failed (certainly not delivered).
    pub failed: u64,
    /// Mean send-to-receipt delay, ms (virtual time).
    pub delay_mean_ms: f64,
    /// 99th percentile of the delay, ms.
    pub delay_p99_ms: f64,
    /// Transmissions per message.
    pub attempts_per_message: f64,
    /// Whether the accounting balanced.
    pub balanced: bool,
}

/// The whole sweep.
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
pub struct SweepReport {
    /// Trials per point.
    pub trials: u32,
    /// Base seed.
    pub seed: u64,
    /// Acknowledged-mode attempt budget.
    pub acknowledged_attempts: u32,
    /// Mean burst length of the bursty points.
    pub burst_length: f64,
    /// The points, by loss model, rate, then mode.
    pub points: Vec<SweepPoint>,
}

/// Runs the sweep.
pub fn run(fleet: &Fleet, config: &SweepConfig) -> Result<SweepReport, ExperimentError> {
    if config.rates.is_empty() {
        return Err(ExperimentError::Invalid(
            "the sweep has no loss rates".into(),
        ));
    }
    let mut points = Vec::new();
    for model in ["iid", "bursty"] {
        for &rate in &config.rates {
            let loss = match model {
                "iid" => LossModel::Iid { percent: rate },
                _ => LossModel::Bursty {
                    percent: rate,
                    burst_length: config.burst_length,
                },
            };
            let cfg = ReliabilityConfig {
                loss,
                ..config.base.clone()
            };
            let report = reliability::run(fleet, &cfg)?;
            for m in &report.modes {
                points.push(SweepPoint {
                    mode: m.mode,
                    loss_model: model.to_string(),
                    loss_percent: rate,
                    messages: m.messages,
                    received: m.received,
                    delivery_ratio_percent: m.delivery_ratio_percent,
                    duplicates_delivered: m.duplicates_delivered,
                    unconfirmed: m.accounting.unconfirmed,
                    failed: m.accounting.failed,
                    delay_mean_ms: m.delay.mean_ms,
                    delay_p99_ms: m.delay.p99_ms,
                    attempts_per_message: m.attempts_per_message,
                    balanced: m.accounting.balanced,
                });
            }
        }
    }
    Ok(SweepReport {
        trials: config.base.trials,
        seed: config.base.seed,
        acknowledged_attempts: config.base.attempts,
        burst_length: config.burst_length,
        points,
    })
}

/// The sweep as CSV, one row per point.
pub fn csv(report: &SweepReport) -> String {
    let mut out = String::from(
        "mode,loss_model,loss_percent,messages,received,delivery_ratio_percent,duplicates_delivered,\
         unconfirmed,failed,delay_mean_ms,delay_p99_ms,attempts_per_message,balanced\n",
    );
    for p in &report.points {
        let _ = writeln!(
            out,
            "{},{},{},{},{},{:.4},{},{},{},{:.4},{:.4},{:.4},{}",
            p.mode,
            p.loss_model,
            p.loss_percent,
            p.messages,
            p.received,
            p.delivery_ratio_percent,
            p.duplicates_delivered,
            p.unconfirmed,
            p.failed,
            p.delay_mean_ms,
            p.delay_p99_ms,
            p.attempts_per_message,
            p.balanced
        );
    }
    out
}

/// The sweep as a text table.
pub fn text(report: &SweepReport) -> String {
    let mut out = String::new();
    let _ = writeln!(
        out,
        "Loss sweep on B: {} trials per point, seed {}, acknowledged budget {} attempts, bursty = \
         Gilbert–Elliott with mean burst {} frames",
        report.trials, report.seed, report.acknowledged_attempts, report.burst_length
    );
    let _ = writeln!(
        out,
        "{:<13} {:<7} {:>6} {:>9} {:>9} {:>5} {:>6} {:>6} {:>10} {:>10} {:>9}",
        "mode",
        "loss",
        "rate%",
        "received",
        "ratio%",
        "dups",
        "unconf",
        "failed",
        "mean ms",
        "p99 ms",
        "att/msg"
    );
    for p in &report.points {
        let _ = writeln!(
            out,
            "{:<13} {:<7} {:>6} {:>9} {:>9.2} {:>5} {:>6} {:>6} {:>10.3} {:>10.3} {:>9.3}",
            p.mode.name(),
            p.loss_model,
            p.loss_percent,
            format!("{}/{}", p.received, p.messages),
            p.delivery_ratio_percent,
            p.duplicates_delivered,
            p.unconfirmed,
            p.failed,
            p.delay_mean_ms,
            p.delay_p99_ms,
            p.attempts_per_message
        );
    }
    out
}

/// Writes `sweep.csv`, `sweep.json` and `sweep.png` into `dir` and returns their paths.
pub fn write_files(report: &SweepReport, dir: &Path) -> Result<Vec<PathBuf>, ExperimentError> {
    std::fs::create_dir_all(dir)
        .map_err(ExperimentError::io(format!("creating {}", dir.display())))?;
    let csv_path = dir.join("sweep.csv");
    std::fs::write(&csv_path, csv(report)).map_err(ExperimentError::io(format!(
        "writing {}",
        csv_path.display()
    )))?;
    let json_path = dir.join("sweep.json");
    let json = serde_json::to_string_pretty(report)
        .map_err(|e| ExperimentError::Invalid(format!("serializing the sweep: {e}")))?;
    std::fs::write(&json_path, json + "\n").map_err(ExperimentError::io(format!(
        "writing {}",
        json_path.display()
    )))?;
    let png_path = dir.join("sweep.png");
    crate::plot::sweep_png(report, &png_path)?;
    Ok(vec![csv_path, json_path, png_path])
}

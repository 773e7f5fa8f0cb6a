//! Model parameters: the keys of an `emulated` transport, the built-in profiles, parsing
//! ("profile, then overrides key by key") and validation.
//!
//! Every key, its unit, default and meaning is listed in `docs/emulation.md`; [`KEYS`] is the
//! authoritative list that the parser accepts.

use std::collections::BTreeMap;

use super::settings::EmulatedSettings;

/// Names of the built-in profiles, in documentation order.
pub const PROFILES: [&str; 3] = ["wired", "wifi", "bluetooth-classic"];

/// Every parameter key the emulation understands. Any other key is an error (it is most likely
/// a typo, and silently ignoring it would make a run lie about its conditions).
pub const KEYS: [&str; 24] = [
    "loss_percent",
    "burst_loss_percent",
    "burst_length_mean",
    "latency_ms",
    "jitter_ms",
    "delay_tail_ms",
    "preserve_order",
    "bandwidth_kbps",
    "queue_frames",
    "mtu_bytes",
    "duplicate_percent",
    "reorder_percent",
    "reorder_delay_ms",
    "corrupt_percent",
    "outage_start_ms",
    "outage_duration_ms",
    "outage_period_ms",
    "range_m",
    "tx_power_dbm",
    "reference_loss_db",
    "reference_distance_m",
    "path_loss_exponent",
    "sensitivity_dbm",
    "margin_slope_db",
];

/// The key/value pairs of a built-in profile (`wired`, `wifi`, `bluetooth-classic`), or
/// `None` if there is no profile of that name. The one copy: the `emulated` kind's spec checks
/// a transport's parameters against them when the fleet is loaded, and the model is built
/// from them when it is opened.
pub fn profile(name: &str) -> Option<&'static [(&'static str, f64)]> {
    /// `wired`: switched gigabit Ethernet. No loss; 0.1 ms one way; 1 Gbit/s line rate.
    const WIRED: &[(&str, f64)] = &[("latency_ms", 0.1), ("bandwidth_kbps", 1_000_000.0)];
    /// `wifi`: one 802.11 hop. The delay distribution is fitted to Sui et al. (INFOCOM
    /// 2016): more than half of the packets see over 20 ms and about 10% over 100 ms on the
    /// Wi-Fi hop. With delay = 5 ms ± 3 ms (uniform) + an exponential tail of mean 41 ms,
    /// P(delay > 20 ms) ≈ e^(−15/41) ≈ 0.69 and P(delay > 100 ms) ≈ e^(−95/41) ≈ 0.099.
    const WIFI: &[(&str, f64)] = &[
        ("latency_ms", 5.0),
        ("jitter_ms", 3.0),
        ("delay_tail_ms", 41.0),
        ("loss_percent", 1.0),
        ("bandwidth_kbps", 20_000.0),
        ("queue_frames", 100.0),
        ("tx_power_dbm", 20.0),
        ("reference_loss_db", 40.0),
        ("reference_distance_m", 1.0),
        ("path_loss_exponent", 3.0),
        ("sensitivity_dbm", -80.0),
        ("margin_slope_db", 2.0),
    ];
    /// `bluetooth-classic`: RFCOMM over BR/EDR 2 Mbit/s. Rate 1448 kbit/s (EDR 2M
    /// asymmetric); latency ≥ two 625 µs slots; bursty loss fitted to the thesis's Tables
    /// 19–20 (see docs/emulation.md).
    const BLUETOOTH_CLASSIC: &[(&str, f64)] = &[
        ("latency_ms", 2.5),
        ("jitter_ms", 1.25),
        ("preserve_order", 1.0),
        ("burst_loss_percent", 7.0),
        ("burst_length_mean", 3.0),
        ("bandwidth_kbps", 1448.0),
        ("tx_power_dbm", 4.0),
        ("reference_loss_db", 40.0),
        ("reference_distance_m", 1.0),
        ("path_loss_exponent", 3.0),
        ("sensitivity_dbm", -70.0),
        ("margin_slope_db", 2.0),
    ];
    match name {
        "wired" => Some(WIRED),
        "wifi" => Some(WIFI),
        "bluetooth-classic" => Some(BLUETOOTH_CLASSIC),
        _ => None,
    }
}

/// Why emulation parameters (or an emulated link) could not be set up.
#[derive(Debug, thiserror::Error)]
#[non_exhaustive]
pub enum EmulationError {
    /// The profile name is not one of [`PROFILES`].
    #[error("unknown emulation profile {name:?}; valid profiles: {valid}")]
    UnknownProfile {
        /// The name given.
        name: String,
        /// The valid names, comma-separated.
        valid: String,
    },
    /// A parameter key is not one of [`KEYS`].
    #[error("unknown emulation parameter {key:?}; valid parameters: {valid}")]
    UnknownKey {
        /// The key given.
        key: String,
        /// The valid keys, comma-separated.
        valid: String,
    },
    /// A parameter's value is outside its allowed range.
    #[error("emulation parameter {key} = {value} is invalid: expected {expected}")]
    InvalidValue {
        /// The key.
        key: &'static str,
        /// The value given (after the profile was applied).
        value: f64,
        /// What is allowed, e.g. "a percentage in 0..=100".
        expected: &'static str,
    },
    /// Parameters that are each valid do not fit together.
    #[error("inconsistent emulation parameters: {reason}")]
    Inconsistent {
        /// What does not fit, naming the keys.
        reason: String,
    },
    /// The emulated link could not start its delay thread.
    #[error("could not start the emulated link's delay thread: {0}")]
    Thread(#[from] std::io::Error),
}

/// A repeating (or one-off) window during which every frame is dropped.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct Outage {
    /// When the first outage begins, ms after the clock's origin (`outage_start_ms`).
    pub start_ms: f64,
    /// How long each outage lasts, ms (`outage_duration_ms`).
    pub duration_ms: f64,
    /// Time from one outage's start to the next one's, ms (`outage_period_ms`); `None`: once.
    pub period_ms: Option<f64>,
}

impl Outage {
    /// Whether time `now_us` (µs on the model's clock) lies inside an outage window. Windows
    /// are half-open: `[start + k·period, start + k·period + duration)`.
    pub fn contains(&self, now_us: u64) -> bool {
        let t_ms = now_us as f64 / 1000.0;
        if t_ms < self.start_ms {
            return false;
        }
        let mut offset = t_ms - self.start_ms;
        if let Some(period) = self.period_ms {
            offset %= period;
        }
        offset < self.duration_ms
    }
}

/// Log-distance path loss and the loss probability derived from the link margin.
///
/// Received power at distance `d` (metres, clamped to at least `reference_distance_m`):
/// `Pr(d) = tx_power_dbm − reference_loss_db − 10·path_loss_exponent·log10(d / reference_distance_m)`.
/// Margin `m = Pr(d) − sensitivity_dbm`. Loss probability is logistic in the margin,
/// `p = 1 / (1 + exp(m / margin_slope_db))` (so 50% at zero margin, ≈1% at `+4.6·slope`), or a
/// hard threshold (`p = 1` if `m < 0`, else 0) when `margin_slope_db` is 0.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct PathLoss {
    /// Transmit power, dBm.
    pub tx_power_dbm: f64,
    /// Path loss at the reference distance, dB (≈40 dB at 1 m for 2.4 GHz in free space).
    pub reference_loss_db: f64,
    /// The reference distance d0, metres (> 0).
    pub reference_distance_m: f64,
    /// The path-loss exponent n (2 in free space, ~2.7–3.5 indoors or among obstacles).
    pub path_loss_exponent: f64,
    /// Receiver sensitivity, dBm: the power at which half of the frames are lost.
    pub sensitivity_dbm: f64,
    /// Width of the logistic transition, dB; 0 for a hard threshold.
    pub margin_slope_db: f64,
}

impl PathLoss {
    /// Received power in dBm at `distance_m` (clamped to the reference distance from below).
    pub fn received_power_dbm(&self, distance_m: f64) -> f64 {
        let d = sanitize_distance(Some(distance_m)).max(self.reference_distance_m);
        self.tx_power_dbm
            - self.reference_loss_db
            - 10.0 * self.path_loss_exponent * (d / self.reference_distance_m).log10()
    }

    /// Probability in `0..=1` that a frame sent over `distance_m` is lost to a weak signal.
    /// Non-decreasing in the distance.
    pub fn loss_probability(&self, distance_m: f64) -> f64 {
        let margin = self.received_power_dbm(distance_m) - self.sensitivity_dbm;
        if self.margin_slope_db == 0.0 {
            return if margin < 0.0 { 1.0 } else { 0.0 };
        }
        1.0 / (1.0 + (margin / self.margin_slope_db).exp())
    }
}

/// Turns an optional, possibly nonsensical distance into metres: unknown (`None`), negative or
/// NaN distances count as 0 (the systems are treated as co-located).
pub(crate) fn sanitize_distance(distance_m: Option<f64>) -> f64 {
    match distance_m {
        Some(d) if d.is_finite() && d > 0.0 => d,
        Some(d) if d == f64::INFINITY => d,
        _ => 0.0,
    }
}

/// The validated, typed parameters of one emulated transport. Build it with
/// [`ModelParams::from_keys`] or [`ModelParams::from_settings`]; if you fill the fields
/// yourself, [`ModelParams::validate`] checks them (and [`super::LinkModel::new`] calls it).
#[derive(Clone, Debug, PartialEq)]
pub struct ModelParams {
    /// Independent per-frame loss, percent (`loss_percent`).
    pub loss_percent: f64,
    /// Gilbert–Elliott long-run loss, percent (`burst_loss_percent`); 0 disables the model.
    pub burst_loss_percent: f64,
    /// Gilbert–Elliott mean burst length, frames (`burst_length_mean`, ≥ 1).
    pub burst_length_mean: f64,
    /// Base one-way delay, ms (`latency_ms`).
    pub latency_ms: f64,
    /// Uniform jitter half-width, ms (`jitter_ms`): delay ∈ [latency − jitter, latency + jitter],
    /// clamped at 0.
    pub jitter_ms: f64,
    /// Mean of an exponential extra delay, ms (`delay_tail_ms`); 0 disables it.
    pub delay_tail_ms: f64,
    /// Jitter never lets a frame overtake an earlier one of the same direction
    /// (`preserve_order` = 1), as on a stream transport such as RFCOMM.
    pub preserve_order: bool,
    /// Transmit rate, kbit/s (1 kbit = 1000 bit) (`bandwidth_kbps`); `None`: unlimited.
    pub bandwidth_kbps: Option<f64>,
    /// Most frames waiting or in transmission per direction (`queue_frames`); `None`: unbounded.
    pub queue_frames: Option<usize>,
    /// Largest frame carried, bytes (`mtu_bytes`); `None`: no limit of its own.
    pub mtu_bytes: Option<usize>,
    /// Probability a delivered frame arrives twice, percent (`duplicate_percent`).
    pub duplicate_percent: f64,
    /// Probability a delivered frame is held back, percent (`reorder_percent`).
    pub reorder_percent: f64,
    /// Extra delay of a held-back frame, ms (`reorder_delay_ms`, default 10).
    pub reorder_delay_ms: f64,
    /// Probability a delivered copy has one bit flipped, percent (`corrupt_percent`).
    pub corrupt_percent: f64,
    /// Outage windows (`outage_start_ms`, `outage_duration_ms`, `outage_period_ms`).
    pub outage: Option<Outage>,
    /// Hard range cut-off, metres (`range_m`): frames between systems further apart are dropped.
    pub range_m: Option<f64>,
    /// Log-distance path loss (present when `sensitivity_dbm` is given).
    pub path_loss: Option<PathLoss>,
}

impl Default for ModelParams {
    /// The transparent model: no impairment at all.
    fn default() -> Self {
        ModelParams {
            loss_percent: 0.0,
            burst_loss_percent: 0.0,
            burst_length_mean: 1.0,
            latency_ms: 0.0,
            jitter_ms: 0.0,
            delay_tail_ms: 0.0,
            preserve_order: false,
            bandwidth_kbps: None,
            queue_frames: None,
            mtu_bytes: None,
            duplicate_percent: 0.0,
            reorder_percent: 0.0,
            reorder_delay_ms: DEFAULT_REORDER_DELAY_MS,
            corrupt_percent: 0.0,
            outage: None,
            range_m: None,
            path_loss: None,
        }
    }
}

const DEFAULT_REORDER_DELAY_MS: f64 = 10.0;

const PATH_LOSS_KEYS: [&str; 5] = [
    "tx_power_dbm",
    "reference_loss_db",
    "reference_distance_m",
    "path_loss_exponent",
    "margin_slope_db",
];

impl ModelParams {
    /// Parameters of an `emulated` transport from the fleet file.
    pub fn from_settings(settings: &EmulatedSettings) -> Result<ModelParams, EmulationError> {
        Self::from_keys(settings.profile.as_deref(), &settings.params)
    }

    /// Starts from the named profile's values (or from nothing), replaces them key by key with
    /// `overrides`, parses and validates the result.
    pub fn from_keys(
        profile_name: Option<&str>,
        overrides: &BTreeMap<String, f64>,
    ) -> Result<ModelParams, EmulationError> {
        let mut merged: BTreeMap<&str, f64> = BTreeMap::new();
        if let Some(name) = profile_name {
            let values = profile(name).ok_or_else(|| EmulationError::UnknownProfile {
                name: name.to_string(),
                valid: PROFILES.join(", "),
            })?;
            merged.extend(values.iter().copied());
        }
        for (key, &value) in overrides {
            let key = KEYS.iter().copied().find(|k| k == key).ok_or_else(|| {
                EmulationError::UnknownKey {
                    key: key.clone(),
                    valid: KEYS.join(", "),
                }
            })?;
            merged.insert(key, value);
        }
        for (&key, &value) in &merged {
            if !value.is_finite() {
                return Err(EmulationError::InvalidValue {
                    key,
                    value,
                    expected: "a finite number",
                });
            }
        }
        let get = |k: &str| merged.get(k).copied();
        let mut p = ModelParams {
            loss_percent: get("loss_percent").unwrap_or(0.0),
            burst_loss_percent: get("burst_loss_percent").unwrap_or(0.0),
            burst_length_mean: get("burst_length_mean").unwrap_or(1.0),
            latency_ms: get("latency_ms").unwrap_or(0.0),
            jitter_ms: get("jitter_ms").unwrap_or(0.0),
            delay_tail_ms: get("delay_tail_ms").unwrap_or(0.0),
            preserve_order: match get("preserve_order") {
                None => false,
                Some(0.0) => false,
                Some(1.0) => true,
                Some(value) => {
                    return Err(EmulationError::InvalidValue {
                        key: "preserve_order",
                        value,
                        expected: "0 or 1",
                    })
                }
            },
            bandwidth_kbps: get("bandwidth_kbps"),
            queue_frames: whole(&merged, "queue_frames")?,
            mtu_bytes: whole(&merged, "mtu_bytes")?,
            duplicate_percent: get("duplicate_percent").unwrap_or(0.0),
            reorder_percent: get("reorder_percent").unwrap_or(0.0),
            reorder_delay_ms: get("reorder_delay_ms").unwrap_or(DEFAULT_REORDER_DELAY_MS),
            corrupt_percent: get("corrupt_percent").unwrap_or(0.0),
            outage: None,
            range_m: get("range_m"),
            path_loss: None,
        };
        if p.burst_loss_percent > 0.0 && get("burst_length_mean").is_none() {
            return Err(EmulationError::Inconsistent {
                reason: "burst_loss_percent needs burst_length_mean (mean burst length in frames)"
                    .into(),
            });
        }
        match get("outage_duration_ms") {
            Some(duration_ms) => {
                p.outage = Some(Outage {
                    start_ms: get("outage_start_ms").unwrap_or(0.0),
                    duration_ms,
                    period_ms: get("outage_period_ms"),
                })
            }
            None => {
                if let Some(k) = ["outage_start_ms", "outage_period_ms"]
                    .into_iter()
                    .find(|k| merged.contains_key(k))
                {
                    return Err(EmulationError::Inconsistent {
                        reason: format!("{k} needs outage_duration_ms"),
                    });
                }
            }
        }
        match get("sensitivity_dbm") {
            Some(sensitivity_dbm) => {
                p.path_loss = Some(PathLoss {
                    tx_power_dbm: get("tx_power_dbm").unwrap_or(0.0),
                    reference_loss_db: get("reference_loss_db").unwrap_or(40.0),
                    reference_distance_m: get("reference_distance_m").unwrap_or(1.0),
                    path_loss_exponent: get("path_loss_exponent").unwrap_or(2.0),
                    sensitivity_dbm,
                    margin_slope_db: get("margin_slope_db").unwrap_or(2.0),
                })
            }
            None => {
                if let Some(k) = PATH_LOSS_KEYS.into_iter().find(|k| merged.contains_key(k)) {
                    return Err(EmulationError::Inconsistent {
                        reason: format!("{k} needs sensitivity_dbm (it enables path loss)"),
                    });
                }
            }
        }
        p.validate()?;
        Ok(p)
    }

    /// Checks every field's range and that the fields fit together.
    pub fn validate(&self) -> Result<(), EmulationError> {
        let invalid = |key, value, expected| {
            Err(EmulationError::InvalidValue {
                key,
                value,
                expected,
            })
        };
        for (key, value) in [
            ("loss_percent", self.loss_percent),
            ("burst_loss_percent", self.burst_loss_percent),
            ("duplicate_percent", self.duplicate_percent),
            ("reorder_percent", self.reorder_percent),
            ("corrupt_percent", self.corrupt_percent),
        ] {
            if !(0.0..=100.0).contains(&value) {
                return invalid(key, value, "a percentage in 0..=100");
            }
        }
        let mut non_negative = vec![
            ("latency_ms", self.latency_ms),
            ("jitter_ms", self.jitter_ms),
            ("delay_tail_ms", self.delay_tail_ms),
            ("reorder_delay_ms", self.reorder_delay_ms),
        ];
        if let Some(o) = self.outage {
            non_negative.push(("outage_start_ms", o.start_ms));
            non_negative.push(("outage_duration_ms", o.duration_ms));
        }
        if let Some(r) = self.range_m {
            non_negative.push(("range_m", r));
        }
        if let Some(pl) = self.path_loss {
            non_negative.push(("path_loss_exponent", pl.path_loss_exponent));
            non_negative.push(("margin_slope_db", pl.margin_slope_db));
        }
        for (key, value) in non_negative {
            if !(value >= 0.0 && value.is_finite()) {
                return invalid(key, value, "a finite number ≥ 0");
            }
        }
        if self.burst_loss_percent > 0.0 {
            let l = self.burst_length_mean;
            if !(l >= 1.0 && l.is_finite()) {
                return invalid("burst_length_mean", l, "a finite number of frames ≥ 1");
            }
            let max = 100.0 * l / (1.0 + l);
            if self.burst_loss_percent > max {
                return Err(EmulationError::Inconsistent {
                    reason: format!(
                        "burst_loss_percent = {} cannot be reached with burst_length_mean = {l}: \
                         at most 100·L/(1+L) = {max:.3} (longer bursts allow more loss)",
                        self.burst_loss_percent
                    ),
                });
            }
        }
        if let Some(b) = self.bandwidth_kbps {
            if !(b > 0.0 && b.is_finite()) {
                return invalid("bandwidth_kbps", b, "a finite rate > 0");
            }
        }
        if let Some(q) = self.queue_frames {
            if q == 0 {
                return invalid("queue_frames", 0.0, "a whole number of frames ≥ 1");
            }
            if self.bandwidth_kbps.is_none() {
                return Err(EmulationError::Inconsistent {
                    reason: "queue_frames needs bandwidth_kbps (without a rate nothing queues)"
                        .into(),
                });
            }
        }
        if self.mtu_bytes == Some(0) {
            return invalid("mtu_bytes", 0.0, "a whole number of bytes ≥ 1");
        }
        if let Some(o) = self.outage {
            if let Some(period) = o.period_ms {
                if !(period > 0.0 && period.is_finite() && period >= o.duration_ms) {
                    return invalid(
                        "outage_period_ms",
                        period,
                        "a finite period > 0 and ≥ outage_duration_ms",
                    );
                }
            }
        }
        if let Some(pl) = self.path_loss {
            if !(pl.reference_distance_m > 0.0 && pl.reference_distance_m.is_finite()) {
                return invalid(
                    "reference_distance_m",
                    pl.reference_distance_m,
                    "a finite distance > 0",
                );
            }
            for (key, value) in [
                ("tx_power_dbm", pl.tx_power_dbm),
                ("reference_loss_db", pl.reference_loss_db),
                ("sensitivity_dbm", pl.sensitivity_dbm),
            ] {
                if !value.is_finite() {
                    return invalid(key, value, "a finite number");
                }
            }
        }
        if self.preserve_order && self.reorder_percent > 0.0 {
            return Err(EmulationError::Inconsistent {
                reason: "preserve_order = 1 contradicts reorder_percent > 0".into(),
            });
        }
        Ok(())
    }

    /// The Gilbert–Elliott transition probabilities `(p_good_to_bad, p_bad_to_good)` per frame,
    /// or `None` when burst loss is off. With loss only in the bad state, the long-run loss is
    /// `π_B = p/(p + r)` and the mean burst length is `1/r`, so `r = 1/L` and
    /// `p = π_B·r/(1 − π_B)`.
    pub fn gilbert_elliott(&self) -> Option<(f64, f64)> {
        if self.burst_loss_percent <= 0.0 {
            return None;
        }
        let pi = self.burst_loss_percent / 100.0;
        let r = 1.0 / self.burst_length_mean;
        let p = (pi * r / (1.0 - pi)).min(1.0);
        Some((p, r))
    }

    /// Whether the model can lose a frame (or damage it) after `send` accepted it: loss, burst
    /// loss, corruption, range, path loss, outages or a bounded queue.
    pub fn is_lossy(&self) -> bool {
        self.loss_percent > 0.0
            || self.burst_loss_percent > 0.0
            || self.corrupt_percent > 0.0
            || self.range_m.is_some()
            || self.path_loss.is_some()
            || self.outage.is_some()
            || self.queue_frames.is_some()
    }

    /// Whether frames of one direction can arrive out of order: reordering, or jitter / a
    /// delay tail without `preserve_order`.
    pub fn may_reorder(&self) -> bool {
        self.reorder_percent > 0.0
            || (!self.preserve_order && (self.jitter_ms > 0.0 || self.delay_tail_ms > 0.0))
    }

    /// Whether the model can ever deliver a frame later than it was sent.
    pub fn may_delay(&self) -> bool {
        self.latency_ms > 0.0
            || self.jitter_ms > 0.0
            || self.delay_tail_ms > 0.0
            || self.bandwidth_kbps.is_some()
            || self.reorder_percent > 0.0
    }

    /// Whether the model looks at the distance between the systems.
    pub fn uses_distance(&self) -> bool {
        self.range_m.is_some() || self.path_loss.is_some()
    }
}

/// Reads an optional key that must be a whole non-negative number.
fn whole(merged: &BTreeMap<&str, f64>, key: &'static str) -> Result<Option<usize>, EmulationError> {
    match merged.get(key) {
        None => Ok(None),
        Some(&v) if v >= 0.0 && v.fract() == 0.0 && v <= usize::MAX as f64 => Ok(Some(v as usize)),
        Some(&value) => Err(EmulationError::InvalidValue {
            key,
            value,
            expected: "a whole number ≥ 0",
        }),
    }
}

#[cfg(test)]
#[path = "params_tests.rs"]
mod tests;

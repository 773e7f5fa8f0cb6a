//! The settings half of the `emulated` kind ([`KindSpec`]): a built-in profile, the transport it
//! is layered over, a seed and the model's parameters, read from a fleet file's transport table
//! and checked against what [`ModelParams`] can be built with, at the key that breaks it.

use std::collections::{BTreeMap, BTreeSet};

use hetcomm_config::kinds::{KindSpec, SettingsReader};
use hetcomm_config::{RegisteredSettings, TransportKind};

use super::params::{profile, KEYS, PROFILES};

/// Settings of an `emulated` transport: a built-in profile, overridden key by key. The model
/// keys (`loss_percent`, `latency_ms`, …) are kept as given; [`ModelParams::from_settings`]
/// interprets them.
///
/// [`ModelParams::from_settings`]: super::ModelParams::from_settings
#[derive(Clone, Debug, PartialEq)]
///
/// The transport it is layered over (`over`) is not kept here: the loader keeps it, for every
/// kind alike, as [`TransportDef::over`](hetcomm_config::TransportDef::over).
pub struct EmulatedSettings {
    /// Built-in profile name (`wired`, `wifi`, `bluetooth-classic`), if any.
    pub profile: Option<String>,
    /// Seed for the emulation's random choices.
    pub seed: u64,
    /// Model parameters, by key, as numbers.
    pub params: BTreeMap<String, f64>,
}

/// Keys of `emulated` transports that are not model parameters.
const OWN_KEYS: [&str; 3] = ["profile", "over", "seed"];

/// Every key of an `emulated` transport besides the ones every transport has: its own and the
/// model's parameters ([`KEYS`], which docs/emulation.md explains).
const ALL_KEYS: [&str; OWN_KEYS.len() + KEYS.len()] = {
    let mut all = [""; OWN_KEYS.len() + KEYS.len()];
    let mut i = 0;
    while i < OWN_KEYS.len() {
        all[i] = OWN_KEYS[i];
        i += 1;
    }
    while i < all.len() {
        all[i] = KEYS[i - OWN_KEYS.len()];
        i += 1;
    }
    all
};

/// The `emulated` kind's settings spec.
pub(crate) struct EmulatedSpec;

impl KindSpec for EmulatedSpec {
    fn kind(&self) -> TransportKind {
        TransportKind::Emulated
    }

    fn keys(&self) -> &[&'static str] {
        &ALL_KEYS
    }

    /// Without `over`, its link is a private in-process hub.
    fn in_process(&self) -> bool {
        true
    }

    fn parse(&self, s: &mut SettingsReader<'_, '_>) -> Option<RegisteredSettings> {
        let profile = s
            .choice("profile", ("profile", "profiles"), &PROFILES)
            .map(|i| PROFILES[i].to_string());
        // Kept by the loader as the transport's `TransportDef::over`.
        s.layered_over("over", "write the wrapped transport's name in quotes");
        let seed = s
            .int_in("seed", 0, i64::MAX, "a whole number, e.g. 1")
            .map_or(0, i64::unsigned_abs);
        let mut params = BTreeMap::new();
        for k in KEYS {
            let Some(n) = s.number(k, "write a number without quotes, e.g. 5.0") else {
                continue;
            };
            // Percentages are bounded; decibel-milliwatt levels may be negative; everything
            // else (times, sizes, distances, rates) may not.
            let ok = n.is_finite()
                && if k.ends_with("_percent") {
                    (0.0..=100.0).contains(&n)
                } else if k.ends_with("_dbm") {
                    true
                } else {
                    n >= 0.0
                };
            if !ok {
                let want = if k.ends_with("_percent") {
                    "from 0 to 100"
                } else if k.ends_with("_dbm") {
                    "a finite number"
                } else {
                    "0 or more"
                };
                let written = s.written(k).unwrap_or_default();
                s.error(
                    k,
                    format!("`{}` must be {want}, found {written}", s.key_path(k)),
                    "see docs/config.md for each parameter's unit",
                );
                continue;
            }
            params.insert(k.to_string(), n);
        }
        fits(s, profile.as_deref(), &params);
        Some(RegisteredSettings::new(EmulatedSettings {
            profile,
            seed,
            params,
        }))
    }
}

/// Checks that the parameters, after the profile, can build the emulation model: the
/// constraints between keys that [`ModelParams::from_keys`](super::ModelParams::from_keys)
/// and `validate` enforce when the fleet is opened, reported when it is loaded instead, at
/// the key that breaks them (`the_fleet_loader_rejects_what_the_model_cannot_build` checks
/// that both agree).
fn fits(s: &mut SettingsReader<'_, '_>, profile_name: Option<&str>, given: &BTreeMap<String, f64>) {
    let mut merged: BTreeMap<&str, f64> = profile_name
        .and_then(profile)
        .unwrap_or(&[])
        .iter()
        .copied()
        .collect();
    merged.extend(given.iter().map(|(k, v)| (k.as_str(), *v)));
    let own: BTreeSet<&str> = given.keys().map(String::as_str).collect();
    let get = |k: &str| merged.get(k).copied();
    // Where to point for a key: its own line when the file gives it, else the profile.
    let at = |k: &'static str| if own.contains(k) { k } else { "profile" };
    let shown = |k: &str| match own.contains(k) {
        true => format!("`{}`", s.key_path(k)),
        false => format!("`{k}` (from profile `{}`)", profile_name.unwrap_or("")),
    };
    let mut problems: Vec<(&'static str, String, String)> = Vec::new();

    if let Some(v) = get("preserve_order").filter(|v| *v != 0.0 && *v != 1.0) {
        problems.push((
            at("preserve_order"),
            format!("{} must be 0 or 1, found {v}", shown("preserve_order")),
            "write 1 to keep each direction in order, 0 (the default) to let jitter reorder".into(),
        ));
    }
    for k in ["queue_frames", "mtu_bytes"] {
        if let Some(v) = get(k).filter(|v| v.fract() != 0.0) {
            problems.push((
                at(k),
                format!("{} must be a whole number, found {v}", shown(k)),
                "write a whole number, e.g. 100".into(),
            ));
        }
    }
    let burst = get("burst_loss_percent").unwrap_or(0.0);
    if burst > 0.0 {
        match get("burst_length_mean") {
            None => problems.push((
                at("burst_loss_percent"),
                format!(
                    "{} needs `burst_length_mean`, the mean burst length in frames",
                    shown("burst_loss_percent")
                ),
                "add `burst_length_mean = 3` (or another length ≥ 1)".into(),
            )),
            Some(l) if l < 1.0 => problems.push((
                at("burst_length_mean"),
                format!(
                    "{} must be at least 1 frame, found {l}",
                    shown("burst_length_mean")
                ),
                "a burst is at least one lost frame".into(),
            )),
            Some(l) => {
                // Gilbert–Elliott with loss only in the bad state: long-run loss
                // π = p/(p + r) with r = 1/L, and p ≤ 1, so π ≤ L/(1 + L).
                let max = 100.0 * l / (1.0 + l);
                if burst > max {
                    let key = if own.contains("burst_loss_percent") {
                        "burst_loss_percent"
                    } else {
                        at("burst_length_mean")
                    };
                    let help = if burst < 100.0 {
                        format!(
                            "lower `burst_loss_percent` to at most {}, or raise \
                             `burst_length_mean` to at least {} (L ≥ p/(100 − p))",
                            trim(max),
                            trim(burst / (100.0 - burst))
                        )
                    } else {
                        "no burst length loses every frame; use `loss_percent = 100`".to_string()
                    };
                    problems.push((
                        key,
                        format!(
                            "{} = {} cannot be reached with {} = {}: with mean bursts of \
                             L frames, burst loss is at most 100·L/(1+L) = {}%",
                            shown("burst_loss_percent"),
                            trim(burst),
                            shown("burst_length_mean"),
                            trim(l),
                            trim(max)
                        ),
                        help,
                    ));
                }
            }
        }
    }
    if get("outage_duration_ms").is_none() {
        for k in ["outage_start_ms", "outage_period_ms"] {
            if merged.contains_key(k) {
                problems.push((
                    at(k),
                    format!("{} needs `outage_duration_ms`", shown(k)),
                    "add `outage_duration_ms`, how long each outage lasts".into(),
                ));
            }
        }
    } else if let (Some(period), Some(duration)) =
        (get("outage_period_ms"), get("outage_duration_ms"))
    {
        if period <= 0.0 || period < duration {
            problems.push((
                at("outage_period_ms"),
                format!(
                    "{} must be more than 0 and at least `outage_duration_ms` ({}), found {}",
                    shown("outage_period_ms"),
                    trim(duration),
                    trim(period)
                ),
                "the period runs from one outage's start to the next one's".into(),
            ));
        }
    }
    if get("sensitivity_dbm").is_none() {
        for k in [
            "tx_power_dbm",
            "reference_loss_db",
            "reference_distance_m",
            "path_loss_exponent",
            "margin_slope_db",
        ] {
            if merged.contains_key(k) {
                problems.push((
                    at(k),
                    format!(
                        "{} needs `sensitivity_dbm`, which turns path loss on",
                        shown(k)
                    ),
                    "add `sensitivity_dbm` (e.g. -80), or remove this key".into(),
                ));
            }
        }
    } else if get("reference_distance_m") == Some(0.0) {
        problems.push((
            at("reference_distance_m"),
            format!("{} must be more than 0", shown("reference_distance_m")),
            "the distance of `reference_loss_db`, e.g. 1".into(),
        ));
    }
    if get("bandwidth_kbps") == Some(0.0) {
        problems.push((
            at("bandwidth_kbps"),
            format!("{} must be more than 0", shown("bandwidth_kbps")),
            "leave it out for an unlimited rate".into(),
        ));
    }
    match get("queue_frames") {
        Some(0.0) => problems.push((
            at("queue_frames"),
            format!("{} must be at least 1", shown("queue_frames")),
            "leave it out for an unbounded queue".into(),
        )),
        Some(_) if get("bandwidth_kbps").is_none() => problems.push((
            at("queue_frames"),
            format!(
                "{} needs `bandwidth_kbps`: without a rate nothing queues",
                shown("queue_frames")
            ),
            "add `bandwidth_kbps`, or remove `queue_frames`".into(),
        )),
        _ => {}
    }
    if get("mtu_bytes") == Some(0.0) {
        problems.push((
            at("mtu_bytes"),
            format!("{} must be at least 1", shown("mtu_bytes")),
            "leave it out for no limit of the link's own".into(),
        ));
    }
    if get("preserve_order") == Some(1.0) && get("reorder_percent").unwrap_or(0.0) > 0.0 {
        let key = if own.contains("reorder_percent") {
            "reorder_percent"
        } else {
            at("preserve_order")
        };
        problems.push((
            key,
            "`preserve_order = 1` contradicts `reorder_percent` above 0".to_string(),
            "keep one of them".into(),
        ));
    }
    for (key, message, help) in problems {
        s.error(key, message, help);
    }
}

/// A number as short as it can be written: `50`, `0.5`, `66.667`.
fn trim(v: f64) -> String {
    let s = format!("{v:.3}");
    let s = s.trim_end_matches('0').trim_end_matches('.');
    s.to_string()
}

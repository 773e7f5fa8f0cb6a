//! `emulated` transports: profile, wrapped transport, seed and model parameters.

use super::*;

impl P<'_> {
    pub(super) fn emulated(
        &mut self,
        t: &dyn TableLike,
        path: &str,
        tloc: &Loc,
        spec: &mut TransportSpec,
    ) -> TransportSettings {
        let mut profile_loc = tloc.clone();
        let profile = t.get("profile").and_then(|v| {
            let vl = self.vloc(v, tloc);
            profile_loc = vl.clone();
            self.choice(
                v,
                &format!("{path}.profile"),
                &vl,
                ("profile", "profiles"),
                &PROFILES,
            )
            .map(|i| PROFILES[i].to_string())
        });
        spec.over = t.get("over").and_then(|v| {
            let vl = self.vloc(v, tloc);
            self.string(
                v,
                &format!("{path}.over"),
                &vl,
                "write the wrapped transport's name in quotes",
            )
            .map(|s| (crate::names::nfc(s).into_owned(), vl))
        });
        let seed = t.get("seed").map_or(0, |v| {
            let vl = self.vloc(v, tloc);
            self.int_in(
                v,
                &format!("{path}.seed"),
                &vl,
                0,
                i64::MAX,
                "a whole number, e.g. 1",
            )
            .map_or(0, i64::unsigned_abs)
        });
        let mut params = BTreeMap::new();
        let mut locs: BTreeMap<&'static str, Loc> = BTreeMap::new();
        for (k, v) in t.iter() {
            if !EMULATED_PARAMS.contains(&k) {
                continue;
            }
            let vl = self.vloc(v, tloc);
            let kpath = format!("{path}.{k}");
            let n = match v.as_value() {
                Some(Value::Integer(i)) => *i.value() as f64,
                Some(Value::Float(f)) => *f.value(),
                _ => {
                    self.wrong_type(
                        &vl,
                        &kpath,
                        "a number",
                        v,
                        "write a number without quotes, e.g. 5.0",
                    );
                    continue;
                }
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
                self.diag.err_help(
                    &vl,
                    format!("`{kpath}` must be {want}, found {}", self.raw(v)),
                    "see docs/config.md for each parameter's unit",
                );
                continue;
            }
            params.insert(k.to_string(), n);
            if let Some(key) = EMULATED_PARAMS.iter().find(|p| **p == k) {
                locs.insert(key, vl);
            }
        }
        self.emulation_fits(path, profile.as_deref(), &profile_loc, &params, &locs);
        TransportSettings::Emulated(EmulatedSettings {
            over: spec.over.as_ref().map(|(s, _)| s.clone()),
            profile,
            seed,
            params,
        })
    }

    /// Checks that the parameters, after the profile, can build the emulation model: the
    /// constraints between keys that the emulation layer (`hetcomm-link`'s
    /// `ModelParams::from_keys` and `validate`) enforces when the fleet is opened, reported
    /// here instead, at the key that breaks them. A test in that crate checks that both
    /// agree.
    fn emulation_fits(
        &mut self,
        path: &str,
        profile: Option<&str>,
        profile_loc: &Loc,
        params: &BTreeMap<String, f64>,
        locs: &BTreeMap<&'static str, Loc>,
    ) {
        let mut merged: BTreeMap<&str, f64> = profile
            .and_then(emulated_profile)
            .unwrap_or(&[])
            .iter()
            .copied()
            .collect();
        merged.extend(params.iter().map(|(k, v)| (k.as_str(), *v)));
        let get = |k: &str| merged.get(k).copied();
        // Where to point for a key: its own line when the file gives it, else the profile.
        let at = |k: &str| locs.get(k).unwrap_or(profile_loc).clone();
        let shown = |k: &str| match locs.contains_key(k) {
            true => format!("`{path}.{k}`"),
            false => format!("`{k}` (from profile `{}`)", profile.unwrap_or("")),
        };
        let mut problems: Vec<(Loc, String, String)> = Vec::new();

        if let Some(v) = get("preserve_order").filter(|v| *v != 0.0 && *v != 1.0) {
            problems.push((
                at("preserve_order"),
                format!("{} must be 0 or 1, found {v}", shown("preserve_order")),
                "write 1 to keep each direction in order, 0 (the default) to let jitter reorder"
                    .into(),
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
                        let key = if locs.contains_key("burst_loss_percent") {
                            "burst_loss_percent"
                        } else {
                            "burst_length_mean"
                        };
                        let help = if burst < 100.0 {
                            format!(
                                "lower `burst_loss_percent` to at most {}, or raise \
                                 `burst_length_mean` to at least {} (L ≥ p/(100 − p))",
                                trim(max),
                                trim(burst / (100.0 - burst))
                            )
                        } else {
                            "no burst length loses every frame; use `loss_percent = 100`"
                                .to_string()
                        };
                        problems.push((
                            at(key),
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
            let key = if locs.contains_key("reorder_percent") {
                "reorder_percent"
            } else {
                "preserve_order"
            };
            problems.push((
                at(key),
                "`preserve_order = 1` contradicts `reorder_percent` above 0".to_string(),
                "keep one of them".into(),
            ));
        }
        for (loc, message, help) in problems {
            self.diag.err_help(&loc, message, help);
        }
    }
}

/// A number as short as it can be written: `50`, `0.5`, `66.667`.
fn trim(v: f64) -> String {
    let s = format!("{v:.3}");
    let s = s.trim_end_matches('0').trim_end_matches('.');
    s.to_string()
}

/// The parameter values of a built-in emulation profile (`wired`, `wifi`,
/// `bluetooth-classic`); None for another name. The one copy: the fleet loader checks an
/// `emulated` transport's parameters against them, and the emulation layer
/// (`hetcomm-link`'s `emulation::params::profile`) builds its model from them.
pub fn emulated_profile(name: &str) -> Option<&'static [(&'static str, f64)]> {
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

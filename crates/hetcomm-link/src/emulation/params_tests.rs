//! Tests of `params.rs`: profiles, keys, validation, and agreement with the fleet loader.

use super::*;

/// The kinds this crate registers, as a program's loader knows them.
fn kinds() -> &'static hetcomm_config::Kinds {
    static REGISTRY: std::sync::OnceLock<crate::registry::Registry> = std::sync::OnceLock::new();
    REGISTRY
        .get_or_init(|| {
            let mut registry = crate::registry::Registry::new();
            crate::register_transports(&mut registry);
            registry
        })
        .kinds()
}

fn keys(pairs: &[(&str, f64)]) -> BTreeMap<String, f64> {
    pairs.iter().map(|&(k, v)| (k.to_string(), v)).collect()
}

#[test]
fn every_profile_parses_and_uses_known_keys() {
    for name in PROFILES {
        let p = ModelParams::from_keys(Some(name), &BTreeMap::new())
            .unwrap_or_else(|e| panic!("profile {name}: {e}"));
        p.validate().unwrap();
        for (k, _) in profile(name).unwrap() {
            assert!(KEYS.contains(k), "profile {name} uses unknown key {k}");
        }
    }
    assert_eq!(
        ModelParams::from_keys(None, &BTreeMap::new()).unwrap(),
        ModelParams::default()
    );
}

/// `hetcomm validate` must reject exactly the parameters this model cannot be built with,
/// so that a fleet that validates also opens.
#[test]
fn the_fleet_loader_rejects_what_the_model_cannot_build() {
    let sets: &[&[(&str, f64)]] = &[
        &[],
        &[("burst_loss_percent", 90.0), ("burst_length_mean", 1.0)],
        &[("burst_loss_percent", 50.0), ("burst_length_mean", 1.0)],
        &[("burst_loss_percent", 50.5), ("burst_length_mean", 1.0)],
        &[("burst_loss_percent", 10.0)],
        &[("burst_loss_percent", 10.0), ("burst_length_mean", 0.5)],
        &[("burst_loss_percent", 74.0)],
        &[("burst_loss_percent", 76.0)],
        &[("burst_loss_percent", 100.0), ("burst_length_mean", 1000.0)],
        &[("burst_length_mean", 0.5)],
        &[("preserve_order", 2.0)],
        &[("preserve_order", 1.0), ("reorder_percent", 1.0)],
        &[("reorder_percent", 1.0)],
        &[("preserve_order", 0.0)],
        &[("queue_frames", 2.5), ("bandwidth_kbps", 1.0)],
        &[("queue_frames", 4.0)],
        &[("queue_frames", 0.0), ("bandwidth_kbps", 1.0)],
        &[("queue_frames", 4.0), ("bandwidth_kbps", 1.0)],
        &[("mtu_bytes", 0.0)],
        &[("mtu_bytes", 1.5)],
        &[("mtu_bytes", 1500.0)],
        &[("bandwidth_kbps", 0.0)],
        &[("outage_start_ms", 5.0)],
        &[("outage_period_ms", 10.0)],
        &[("outage_duration_ms", 50.0), ("outage_period_ms", 10.0)],
        &[("outage_duration_ms", 50.0), ("outage_period_ms", 50.0)],
        &[("outage_duration_ms", 0.0), ("outage_period_ms", 0.0)],
        &[("outage_duration_ms", 20.0)],
        &[("tx_power_dbm", 5.0)],
        &[("margin_slope_db", 0.0)],
        &[("sensitivity_dbm", -80.0)],
        &[("sensitivity_dbm", -80.0), ("reference_distance_m", 0.0)],
        &[("sensitivity_dbm", -80.0), ("tx_power_dbm", -5.0)],
        &[("latency_ms", 5.0), ("jitter_ms", 1.0), ("range_m", 0.0)],
    ];
    for prof in [None, Some("wired"), Some("wifi"), Some("bluetooth-classic")] {
        for set in sets {
            let mut text = String::from("[systems]\nA = 0\n[transports.e]\nkind = \"emulated\"\n");
            if let Some(p) = prof {
                text.push_str(&format!("profile = \"{p}\"\n"));
            }
            for (k, v) in *set {
                text.push_str(&format!("{k} = {v:?}\n"));
            }
            let loader = hetcomm_config::parse_str_with(&text, "e.toml", None, kinds());
            let model = ModelParams::from_keys(prof, &keys(set));
            assert_eq!(
                loader.is_ok(),
                model.is_ok(),
                "profile {prof:?}, {set:?}: the loader says {:?}, the model {:?}",
                loader.err().map(|e| e.to_string()),
                model.err().map(|e| e.to_string()),
            );
        }
    }
}

#[test]
fn unknown_profile_lists_the_valid_ones() {
    let e = ModelParams::from_keys(Some("lora"), &BTreeMap::new()).unwrap_err();
    let msg = e.to_string();
    assert!(msg.contains("\"lora\""), "{msg}");
    for name in PROFILES {
        assert!(msg.contains(name), "{msg}");
    }
}

#[test]
fn unknown_key_is_named() {
    let e = ModelParams::from_keys(None, &keys(&[("los_percent", 1.0)])).unwrap_err();
    assert!(matches!(e, EmulationError::UnknownKey { ref key, .. } if key == "los_percent"));
    assert!(e.to_string().contains("loss_percent"));
}

#[test]
fn overrides_replace_profile_values_key_by_key() {
    let p = ModelParams::from_keys(
        Some("wifi"),
        &keys(&[("loss_percent", 0.0), ("latency_ms", 7.0)]),
    )
    .unwrap();
    assert_eq!(p.loss_percent, 0.0);
    assert_eq!(p.latency_ms, 7.0);
    assert_eq!(p.jitter_ms, 3.0, "untouched profile value kept");
    assert_eq!(p.queue_frames, Some(100));
}

#[test]
fn bad_values_are_errors_naming_the_key() {
    let cases: &[(&[(&str, f64)], &str)] = &[
        (&[("loss_percent", 101.0)], "loss_percent"),
        (&[("loss_percent", -1.0)], "loss_percent"),
        (&[("corrupt_percent", f64::NAN)], "corrupt_percent"),
        (&[("latency_ms", -0.5)], "latency_ms"),
        (&[("jitter_ms", -1.0)], "jitter_ms"),
        (&[("bandwidth_kbps", 0.0)], "bandwidth_kbps"),
        (
            &[("queue_frames", 2.5), ("bandwidth_kbps", 1.0)],
            "queue_frames",
        ),
        (&[("queue_frames", 4.0)], "queue_frames"),
        (&[("mtu_bytes", 0.0)], "mtu_bytes"),
        (&[("burst_loss_percent", 10.0)], "burst_length_mean"),
        (
            &[("burst_loss_percent", 60.0), ("burst_length_mean", 1.0)],
            "burst_loss_percent",
        ),
        (
            &[("burst_loss_percent", 5.0), ("burst_length_mean", 0.5)],
            "burst_length_mean",
        ),
        (&[("outage_start_ms", 5.0)], "outage_duration_ms"),
        (
            &[("outage_duration_ms", 50.0), ("outage_period_ms", 10.0)],
            "outage_period_ms",
        ),
        (&[("tx_power_dbm", 5.0)], "sensitivity_dbm"),
        (
            &[("sensitivity_dbm", -80.0), ("reference_distance_m", 0.0)],
            "reference_distance_m",
        ),
        (&[("range_m", -3.0)], "range_m"),
        (&[("preserve_order", 2.0)], "preserve_order"),
        (
            &[("preserve_order", 1.0), ("reorder_percent", 1.0)],
            "reorder_percent",
        ),
    ];
    for (pairs, key) in cases {
        let e = ModelParams::from_keys(None, &keys(pairs))
            .expect_err(&format!("{pairs:?} should be rejected"));
        assert!(e.to_string().contains(key), "{pairs:?}: {e}");
    }
}

#[test]
fn gilbert_elliott_transitions_follow_the_formulas() {
    let p = ModelParams::from_keys(
        None,
        &keys(&[("burst_loss_percent", 10.0), ("burst_length_mean", 4.0)]),
    )
    .unwrap();
    let (gb, bg) = p.gilbert_elliott().unwrap();
    assert!((bg - 0.25).abs() < 1e-12);
    assert!((gb - 0.1 * 0.25 / 0.9).abs() < 1e-12);
    assert!((gb / (gb + bg) - 0.1).abs() < 1e-12, "stationary loss");
}

#[test]
fn path_loss_is_monotone_and_centred_on_sensitivity() {
    let pl = PathLoss {
        tx_power_dbm: 20.0,
        reference_loss_db: 40.0,
        reference_distance_m: 1.0,
        path_loss_exponent: 3.0,
        sensitivity_dbm: -80.0,
        margin_slope_db: 2.0,
    };
    // Pr(100 m) = 20 − 40 − 30·2 = −80 dBm: exactly the sensitivity.
    assert!((pl.received_power_dbm(100.0) + 80.0).abs() < 1e-9);
    assert!((pl.loss_probability(100.0) - 0.5).abs() < 1e-9);
    assert_eq!(pl.received_power_dbm(0.0), pl.received_power_dbm(1.0));
    let mut last = -1.0;
    for i in 0..=2000 {
        let p = pl.loss_probability(i as f64 * 0.5);
        assert!(p >= last, "loss probability fell at {} m", i as f64 * 0.5);
        assert!((0.0..=1.0).contains(&p));
        last = p;
    }
    let hard = PathLoss {
        margin_slope_db: 0.0,
        ..pl
    };
    assert_eq!(hard.loss_probability(99.0), 0.0);
    assert_eq!(hard.loss_probability(101.0), 1.0);
}

#[test]
fn outage_windows_are_half_open_and_repeat() {
    let o = Outage {
        start_ms: 1000.0,
        duration_ms: 200.0,
        period_ms: Some(1000.0),
    };
    assert!(!o.contains(999_999));
    assert!(o.contains(1_000_000));
    assert!(o.contains(1_199_999));
    assert!(!o.contains(1_200_000));
    assert!(o.contains(2_100_000));
    assert!(!o.contains(2_500_000));
    let once = Outage {
        period_ms: None,
        ..o
    };
    assert!(!once.contains(2_100_000));
}

//! Tests of the link model: rates, bounds and profiles against their figures, seeded.

use std::collections::hash_map::DefaultHasher;
use std::hash::{Hash, Hasher};

use super::*;

const A: SystemId = SystemId(1);
const B: SystemId = SystemId(2);
const C: SystemId = SystemId(3);

fn model(pairs: &[(&str, f64)], seed: u64) -> LinkModel {
    let keys = pairs.iter().map(|&(k, v)| (k.to_string(), v)).collect();
    LinkModel::new(ModelParams::from_keys(None, &keys).unwrap(), seed).unwrap()
}

fn profile_model(name: &str, seed: u64) -> LinkModel {
    LinkModel::new(
        ModelParams::from_keys(Some(name), &BTreeMap::new()).unwrap(),
        seed,
    )
    .unwrap()
}

/// `n` frames A → B, `gap_us` apart; returns the verdicts.
fn run(m: &mut LinkModel, n: usize, gap_us: u64, len: usize) -> Vec<Verdict> {
    (0..n)
        .map(|i| m.on_frame(Time(i as u64 * gap_us), A, B, len, None))
        .collect()
}

fn first(v: &Verdict) -> Arrival {
    v.deliveries().next().expect("delivered")
}

#[test]
fn iid_loss_rate_is_within_half_a_percent() {
    let seed = 0x1d_105;
    let mut m = model(&[("loss_percent", 10.0)], seed);
    let v = run(&mut m, 100_000, 1000, 100);
    let lost = v
        .iter()
        .filter(|v| v.drop_reason() == Some(DropReason::Loss))
        .count();
    let rate = lost as f64 / v.len() as f64;
    assert!((rate - 0.10).abs() < 0.005, "seed {seed}: loss {rate}");
    assert!(v
        .iter()
        .all(|v| matches!(v.drop_reason(), None | Some(DropReason::Loss))));
}

#[test]
fn gilbert_elliott_mean_loss_and_burst_length() {
    let seed = 77;
    let mut m = model(
        &[("burst_loss_percent", 10.0), ("burst_length_mean", 4.0)],
        seed,
    );
    let v = run(&mut m, 200_000, 1000, 100);
    let lost: Vec<bool> = v.iter().map(|v| v.drop_reason().is_some()).collect();
    let rate = lost.iter().filter(|&&l| l).count() as f64 / lost.len() as f64;
    let mut bursts = Vec::new();
    let mut run_len = 0;
    for &l in &lost {
        if l {
            run_len += 1;
        } else if run_len > 0 {
            bursts.push(run_len);
            run_len = 0;
        }
    }
    let mean_burst = bursts.iter().sum::<usize>() as f64 / bursts.len() as f64;
    assert!((rate - 0.10).abs() < 0.01, "seed {seed}: GE loss {rate}");
    assert!(
        (mean_burst - 4.0).abs() < 0.3,
        "seed {seed}: mean burst {mean_burst}"
    );
    // Bursty, unlike iid loss at 10% whose mean run is 1/0.9 ≈ 1.11.
    assert!(v
        .iter()
        .all(|v| matches!(v.drop_reason(), None | Some(DropReason::BurstLoss))));
}

#[test]
fn latency_and_jitter_bounds_and_mean() {
    let seed = 5;
    let mut m = model(&[("latency_ms", 20.0), ("jitter_ms", 5.0)], seed);
    let gap = 1000;
    let delays: Vec<f64> = run(&mut m, 50_000, gap, 100)
        .iter()
        .enumerate()
        .map(|(i, v)| (first(v).at.as_micros() - i as u64 * gap) as f64 / 1000.0)
        .collect();
    let min = delays.iter().cloned().fold(f64::MAX, f64::min);
    let max = delays.iter().cloned().fold(f64::MIN, f64::max);
    let mean = delays.iter().sum::<f64>() / delays.len() as f64;
    assert!(
        min >= 15.0 - 0.001 && max <= 25.0 + 0.001,
        "seed {seed}: [{min}, {max}]"
    );
    assert!((mean - 20.0).abs() < 0.2, "seed {seed}: mean {mean}");
    assert!(
        min < 15.2 && max > 24.8,
        "seed {seed}: jitter spans its range"
    );

    // Jitter larger than the latency: never before the send.
    let mut m = model(&[("latency_ms", 1.0), ("jitter_ms", 5.0)], seed);
    for (i, v) in run(&mut m, 10_000, gap, 100).iter().enumerate() {
        assert!(
            first(v).at.as_micros() >= i as u64 * gap,
            "seed {seed}: frame {i} early"
        );
    }
}

#[test]
fn wifi_profile_matches_sui_et_al_delay_figures() {
    let seed = 2016;
    let mut m = profile_model("wifi", seed);
    let gap = 1_000_000; // 1 s apart: the queue is always empty.
    let delays: Vec<f64> = (0..50_000u64)
        .filter_map(|i| {
            let v = m.on_frame(Time(i * gap), A, B, 64, None);
            v.deliveries()
                .next()
                .map(|d| (d.at.as_micros() - i * gap) as f64 / 1000.0)
        })
        .collect();
    let over = |ms: f64| delays.iter().filter(|&&d| d > ms).count() as f64 / delays.len() as f64;
    assert!(over(20.0) > 0.5, "seed {seed}: P(>20 ms) = {}", over(20.0));
    assert!(
        (over(100.0) - 0.10).abs() < 0.01,
        "seed {seed}: P(>100 ms) = {}",
        over(100.0)
    );
    assert!(
        delays.iter().all(|&d| d >= 2.0 - 0.001),
        "seed {seed}: below latency − jitter"
    );
}

#[test]
fn bluetooth_profile_reproduces_the_thesis_retry_counts() {
    // The thesis (Tables 19–20): 232 Bluetooth sends, up to 3 attempts each, 25 additional
    // attempts, 7 sends failing all three. If a send's first attempt meets the chain in its
    // stationary state, the GE fit predicts per send E[additional] = π(2 − r) and
    // P(all fail) = π(1 − r)²: 27.1 and 7.2 over 232 sends.
    let p = ModelParams::from_keys(Some("bluetooth-classic"), &BTreeMap::new()).unwrap();
    let (pi, r) = (p.burst_loss_percent / 100.0, 1.0 / p.burst_length_mean);
    let (want_extra, want_fail) = (pi * (2.0 - r), pi * (1.0 - r).powi(2));
    assert!(
        (want_extra * 232.0 - 25.0).abs() < 3.0,
        "fit: {}",
        want_extra * 232.0
    );
    assert!(
        (want_fail * 232.0 - 7.0).abs() < 1.0,
        "fit: {}",
        want_fail * 232.0
    );

    // The chain advances per frame, so other traffic (10 frames) runs between sends to let
    // it mix, as the rovers' other messages did.
    let seed = 2019;
    let mut m = LinkModel::new(p, seed).unwrap();
    let (mut extra, mut failed, sends) = (0u32, 0u32, 20_000u64);
    let mut t = 0;
    let mut next = |m: &mut LinkModel| {
        t += 10_000;
        m.on_frame(Time(t), A, B, 64, None).drop_reason().is_none()
    };
    for _ in 0..sends {
        for _ in 0..10 {
            next(&mut m);
        }
        let mut ok = false;
        for attempt in 0..3 {
            if attempt > 0 {
                extra += 1;
            }
            if next(&mut m) {
                ok = true;
                break;
            }
        }
        failed += u32::from(!ok);
    }
    let extra_rate = extra as f64 / sends as f64;
    let fail_rate = failed as f64 / sends as f64;
    assert!(
        (extra_rate - want_extra).abs() < 0.012,
        "seed {seed}: extra {extra_rate}"
    );
    assert!(
        (fail_rate - want_fail).abs() < 0.006,
        "seed {seed}: failed {fail_rate}"
    );
}

#[test]
fn rate_limit_serializes_back_to_back_frames() {
    let mut m = model(&[("bandwidth_kbps", 1000.0)], 1);
    let (n, size) = (1000u64, 1000usize);
    let v: Vec<Verdict> = (0..n)
        .map(|_| m.on_frame(Time(0), A, B, size, None))
        .collect();
    // 1000 bytes at 1000 kbit/s = 8 ms each; all 1000 take 8 s.
    for (i, v) in v.iter().enumerate() {
        assert_eq!(first(v).at.as_micros(), (i as u64 + 1) * 8000, "frame {i}");
    }
    let total = first(v.last().unwrap()).at.as_micros();
    assert_eq!(total, n * size as u64 * 8 * 1000 / 1000);
    // An idle link sends a new frame at once (after its own serialization).
    let v = m.on_frame(Time(20_000_000), A, B, 125, None);
    assert_eq!(first(&v).at.as_micros(), 20_001_000);
}

#[test]
fn queue_bound_drops_exactly_the_excess() {
    let mut m = model(&[("bandwidth_kbps", 1000.0), ("queue_frames", 10.0)], 1);
    let v: Vec<Verdict> = (0..25)
        .map(|_| m.on_frame(Time(0), A, B, 1000, None))
        .collect();
    let full = v
        .iter()
        .filter(|v| v.drop_reason() == Some(DropReason::QueueFull))
        .count();
    assert_eq!(full, 15);
    assert!(v[..10].iter().all(|v| v.drop_reason().is_none()));
    // One frame leaves every 8 ms: at 8 ms there is room for exactly one more.
    assert!(m
        .on_frame(Time(8_000), A, B, 1000, None)
        .drop_reason()
        .is_none());
    assert_eq!(
        m.on_frame(Time(8_000), A, B, 1000, None).drop_reason(),
        Some(DropReason::QueueFull)
    );
    // Another direction has its own queue.
    assert!(m
        .on_frame(Time(0), B, A, 1000, None)
        .drop_reason()
        .is_none());
}

#[test]
fn duplicate_corrupt_and_reorder_rates() {
    let seed = 99;
    let mut m = model(
        &[
            ("duplicate_percent", 5.0),
            ("corrupt_percent", 5.0),
            ("reorder_percent", 5.0),
            ("reorder_delay_ms", 7.0),
            ("latency_ms", 1.0),
        ],
        seed,
    );
    let n = 100_000;
    let gap = 1000;
    let v = run(&mut m, n, gap, 50);
    let copies: Vec<(usize, Arrival)> = v
        .iter()
        .enumerate()
        .flat_map(|(i, v)| v.deliveries().map(move |d| (i, d)))
        .collect();
    let dup = v
        .iter()
        .filter(|v| {
            matches!(
                v,
                Verdict::Deliver {
                    duplicate: Some(_),
                    ..
                }
            )
        })
        .count();
    let corrupt = copies.iter().filter(|(_, d)| d.corrupt.is_some()).count();
    let reordered = copies.iter().filter(|(_, d)| d.reordered).count();
    let frac = |k: usize, of: usize| k as f64 / of as f64;
    assert!(
        (frac(dup, n) - 0.05).abs() < 0.005,
        "seed {seed}: dup {}",
        frac(dup, n)
    );
    let nc = copies.len();
    assert!(
        (frac(corrupt, nc) - 0.05).abs() < 0.005,
        "seed {seed}: corrupt {}",
        frac(corrupt, nc)
    );
    assert!(
        (frac(reordered, nc) - 0.05).abs() < 0.005,
        "seed {seed}: reorder {}",
        frac(reordered, nc)
    );
    for (i, d) in &copies {
        let delay = d.at.as_micros() - *i as u64 * gap;
        assert_eq!(
            delay,
            if d.reordered { 8000 } else { 1000 },
            "seed {seed}: frame {i}"
        );
        if let Some(f) = d.corrupt {
            assert!(
                f.byte < 50 && f.mask.count_ones() == 1,
                "seed {seed}: {f:?}"
            );
        }
    }
    // A held-back frame is overtaken: arrivals are not in send order.
    let arrivals: Vec<Time> = copies.iter().map(|(_, d)| d.at).collect();
    assert!(
        arrivals.windows(2).any(|w| w[1] < w[0]),
        "seed {seed}: nothing reordered"
    );
}

#[test]
fn preserve_order_keeps_jittered_frames_in_order() {
    let seed = 3;
    let mut m = profile_model("bluetooth-classic", seed);
    let mut last = Time::ZERO;
    for i in 0..20_000u64 {
        for d in m.on_frame(Time(i * 100), A, B, 10, None).deliveries() {
            assert!(d.at >= last, "seed {seed}: frame {i} overtook");
            last = d.at;
        }
    }
}

#[test]
fn outage_drops_inside_the_window_and_nothing_outside() {
    let mut m = model(
        &[
            ("outage_start_ms", 1000.0),
            ("outage_duration_ms", 500.0),
            ("outage_period_ms", 2000.0),
        ],
        1,
    );
    for i in 0..10_000u64 {
        let t_ms = i; // one frame per ms for 10 s
        let inside = t_ms >= 1000 && (t_ms - 1000) % 2000 < 500;
        let v = m.on_frame(Time(t_ms * 1000), A, B, 10, None);
        let want = inside.then_some(DropReason::Outage);
        assert_eq!(v.drop_reason(), want, "at {t_ms} ms");
    }
}

#[test]
fn range_cut_off_and_unknown_distance() {
    let mut m = model(&[("range_m", 50.0)], 1);
    assert!(m
        .on_frame(Time(0), A, B, 10, Some(49.9))
        .drop_reason()
        .is_none());
    assert!(m
        .on_frame(Time(0), A, B, 10, Some(50.0))
        .drop_reason()
        .is_none());
    assert_eq!(
        m.on_frame(Time(0), A, B, 10, Some(50.1)).drop_reason(),
        Some(DropReason::OutOfRange)
    );
    assert!(m.on_frame(Time(0), A, B, 10, None).drop_reason().is_none());
    assert!(m
        .on_frame(Time(0), A, B, 10, Some(f64::NAN))
        .drop_reason()
        .is_none());
    assert_eq!(
        m.on_frame(Time(0), A, B, 10, Some(f64::INFINITY))
            .drop_reason(),
        Some(DropReason::OutOfRange)
    );
}

#[test]
fn path_loss_drop_rate_grows_with_distance() {
    let seed = 11;
    let mut m = profile_model("wifi", seed);
    let params = m.params().clone();
    let pl = params.path_loss.unwrap();
    let mut last = -1.0;
    let mut t = 0;
    for d in [1.0, 60.0, 100.0, 130.0, 300.0] {
        let n = 20_000u64;
        let dropped = (0..n)
            .filter(|_| {
                t += 1_000_000; // time never goes back; 1 s apart keeps the queue empty
                m.on_frame(Time(t), A, B, 64, Some(d)).drop_reason() == Some(DropReason::PathLoss)
            })
            .count() as f64
            / n as f64;
        let expect = pl.loss_probability(d);
        assert!(
            (dropped - expect).abs() < 0.015,
            "seed {seed}: {d} m: {dropped} vs {expect}"
        );
        assert!(dropped >= last, "seed {seed}: drop rate fell at {d} m");
        last = dropped;
    }
}

#[test]
fn mtu_drops_large_frames_without_drawing() {
    let mut m = model(&[("mtu_bytes", 100.0), ("loss_percent", 50.0)], 8);
    let mut reference = m.clone();
    assert_eq!(
        m.on_frame(Time(0), A, B, 101, None).drop_reason(),
        Some(DropReason::Mtu)
    );
    // The refused frame consumed no random number.
    assert_eq!(
        m.on_frame(Time(1), A, B, 100, None),
        reference.on_frame(Time(1), A, B, 100, None)
    );
}

fn fingerprint(name: &str, seed: u64) -> u64 {
    let mut keys = BTreeMap::new();
    keys.insert("duplicate_percent".to_string(), 3.0);
    keys.insert("corrupt_percent".to_string(), 3.0);
    let mut m = LinkModel::new(ModelParams::from_keys(Some(name), &keys).unwrap(), seed).unwrap();
    let mut h = DefaultHasher::new();
    for i in 0..5_000u64 {
        let (src, dst) = if i % 3 == 0 { (B, A) } else { (A, B) };
        m.on_frame(
            Time(i * 700),
            src,
            dst,
            200 + (i as usize % 900),
            Some((i % 150) as f64),
        )
        .hash(&mut h);
    }
    h.finish()
}

#[test]
fn same_seed_same_verdicts_different_seed_different() {
    for name in ["wifi", "bluetooth-classic"] {
        assert_eq!(fingerprint(name, 1234), fingerprint(name, 1234), "{name}");
        assert_ne!(fingerprint(name, 1234), fingerprint(name, 1235), "{name}");
    }
}

#[test]
fn traffic_on_one_pair_does_not_change_another() {
    let seed = 4321;
    let mut alone = profile_model("wifi", seed);
    let mut mixed = profile_model("wifi", seed);
    for i in 0..5_000u64 {
        let t = Time(i * 10_000);
        let expected = alone.on_frame(t, A, B, 300, Some(90.0));
        mixed.on_frame(t, A, C, 300, Some(90.0));
        mixed.on_frame(t, C, B, 300, Some(90.0));
        assert_eq!(
            mixed.on_frame(t, A, B, 300, Some(90.0)),
            expected,
            "seed {seed}: frame {i}"
        );
    }
}

#[test]
fn transparent_model_delivers_everything_at_once() {
    let mut m = LinkModel::new(ModelParams::default(), 0).unwrap();
    for i in 0..1000u64 {
        let v = m.on_frame(Time(i), A, B, 1 << 20, Some(1e9));
        assert_eq!(
            v,
            Verdict::Deliver {
                first: Arrival {
                    at: Time(i),
                    corrupt: None,
                    reordered: false
                },
                duplicate: None
            }
        );
    }
}

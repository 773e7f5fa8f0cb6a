//! The outcome oracle: sans-IO routers driven through long random schedules — loss,
//! duplication, reordering, delay, acknowledgement loss, link and inbox refusals, unknown
//! modules, bursts past the duplicate window, restarts, ordered and unordered delivery,
//! native broadcasts, the senders' wall clocks stepped by ± hours, routes with a second path
//! and outages of the first (failover, probes, return) — while the world keeps the ground
//! truth of what entered which inbox.
//! For every send it asserts: exactly one outcome; *delivered* ⇒ in the destination inbox;
//! *failed* ⇒ never in it; *sent* only on unacknowledged routes; *unconfirmed* only where a
//! data frame left; a confirmed outcome names a path a data frame of it left on; nothing
//! enters one inbox twice; the counters balance.
//!
//! A failing schedule prints its parameters (seed included) and the smallest schedule the
//! shrinker found that still fails. Run more of them with
//!
//! ```sh
//! HETCOMM_ORACLE_SCHEDULES=20000 HETCOMM_ORACLE_SENDS=2000 HETCOMM_ORACLE_FIRST_SEED=0 \
//!   cargo test --release -p hetcomm-router --test oracle -- --ignored --nocapture soak
//! ```

mod world;

use world::{Params, World};

/// Runs one schedule: its falsehoods and the router calls it made.
fn judge(params: &Params) -> (Vec<String>, u64) {
    let mut world = World::new(params.clone());
    world.run();
    (world.falsehoods(), world.events)
}

/// Smaller schedules that still fail, tried one change at a time until none helps: fewer
/// sends, fewer systems, each kind of trouble switched off.
fn shrink(mut failing: Params) -> Params {
    let still_fails = |p: &Params| !judge(p).0.is_empty();
    loop {
        let mut candidates = Vec::new();
        if failing.sends > 1 {
            candidates.push(Params {
                sends: failing.sends / 2,
                ..failing.clone()
            });
            candidates.push(Params {
                sends: failing.sends - 1,
                ..failing.clone()
            });
        }
        if failing.systems > 2 {
            candidates.push(Params {
                systems: failing.systems - 1,
                ..failing.clone()
            });
        }
        let off: [fn(&mut Params); 14] = [
            |p| p.loss = 0.0,
            |p| p.duplicate = 0.0,
            |p| p.jitter_us = 0,
            |p| p.link_refusal = 0.0,
            |p| p.inbox_refusal = 0.0,
            |p| p.unknown_module = 0.0,
            |p| p.broadcast = 0.0,
            |p| p.restart = 0.0,
            |p| p.burst = 0.0,
            |p| p.ordered = false,
            |p| p.wall_steps = false,
            |p| p.sessions = false,
            |p| p.outages = false,
            |p| p.two_paths = false,
        ];
        for f in off {
            let mut p = failing.clone();
            f(&mut p);
            if p != failing {
                candidates.push(p);
            }
        }
        match candidates.into_iter().find(still_fails) {
            Some(smaller) => failing = smaller,
            None => return failing,
        }
    }
}

/// Runs `schedules` random schedules from `first_seed`; panics with the first failure, its
/// seed and its shrunk form. Returns (schedules, sends, router calls, outcomes by kind as
/// [`World::tally`] counts them).
fn check(first_seed: u64, schedules: u64, sends: u32) -> (u64, u64, u64, [u64; 5], (u64, u64)) {
    let (mut total_sends, mut total_events, mut tally) = (0, 0, [0u64; 5]);
    let mut switching = (0, 0);
    for seed in first_seed..first_seed + schedules {
        let params = Params::random(seed, sends);
        let mut world = World::new(params.clone());
        world.run();
        total_events += world.events;
        total_sends += world.sends() as u64;
        let (changes, probes) = world.switching();
        switching = (switching.0 + changes, switching.1 + probes);
        for (t, n) in tally.iter_mut().zip(world.tally()) {
            *t += n;
        }
        let wrong = world.falsehoods();
        if !wrong.is_empty() {
            let small = shrink(params.clone());
            let (small_wrong, _) = judge(&small);
            panic!(
                "the oracle caught false outcomes with seed {seed}\n\
                 schedule: {params:?}\nfirst of {} falsehoods: {}\n\
                 shrunk to: {small:?}\nwhich says: {}",
                wrong.len(),
                wrong[..wrong.len().min(5)].join("\n  "),
                small_wrong[..small_wrong.len().min(5)].join("\n  ")
            );
        }
    }
    (schedules, total_sends, total_events, tally, switching)
}

fn env(name: &str) -> Option<u64> {
    std::env::var(name).ok().and_then(|v| v.parse().ok())
}

#[test]
fn every_outcome_is_true_on_random_schedules() {
    // Bounded for CI: a few seconds in a debug build.
    let (schedules, sends, events, tally, (changes, probes)) = check(0, 150, 300);
    let [delivered, sent, unconfirmed, failed, no_session] = tally;
    println!(
        "{schedules} schedules, {sends} sends, {events} router calls: {delivered} delivered, \
         {sent} sent, {unconfirmed} unconfirmed, {failed} failed ({no_session} for want of a \
         session), {changes} path changes, {probes} probes, no false outcome"
    );
    // Schedules with two paths and outages must have switched paths and probed.
    assert!(
        changes > 100 && probes > 100,
        "{changes} path changes, {probes} probes"
    );
    assert!(
        events > 100_000,
        "the schedules did too little: {events} calls"
    );
    // They must reach every kind of outcome, or they test less than they claim.
    assert!(
        delivered > 0 && sent > 0 && unconfirmed > 0 && failed > no_session && no_session > 0,
        "{tally:?}"
    );
}

#[test]
fn bursts_past_a_tiny_duplicate_window_stay_true() {
    for seed in 1_000..1_040 {
        let params = Params {
            dedup_window: 2,
            burst: 0.2,
            loss: 0.2,
            acknowledged_mask: u32::MAX,
            ..Params::random(seed, 400)
        };
        let (wrong, _) = judge(&params);
        assert!(
            wrong.is_empty(),
            "seed {seed}: {params:?}\n{}",
            wrong.join("\n")
        );
    }
}

#[test]
fn stepping_the_wall_clock_changes_no_outcome_and_no_counter() {
    // The routers run on a monotonic clock and take the wall clock only as the stamp: a run
    // whose stamps jump by hours must tell its users exactly what the same run without
    // jumps told them (a router timing anything by the stamp would retransmit, hold or
    // give up differently).
    for seed in 3_000..3_030 {
        let steady = Params {
            wall_steps: false,
            ..Params::random(seed, 400)
        };
        let stepped = Params {
            wall_steps: true,
            ..steady.clone()
        };
        let run = |p: &Params| {
            let mut w = World::new(p.clone());
            w.run();
            assert!(w.falsehoods().is_empty(), "seed {seed}: {p:?}");
            w.told()
        };
        assert_eq!(run(&steady), run(&stepped), "seed {seed}: {stepped:?}");
    }
}

#[test]
fn refusals_whose_acknowledgement_is_lost_stay_true() {
    for seed in 2_000..2_040 {
        let params = Params {
            inbox_refusal: 0.5,
            loss: 0.3,
            restart: 0.0,
            acknowledged_mask: u32::MAX,
            ..Params::random(seed, 300)
        };
        let (wrong, _) = judge(&params);
        assert!(
            wrong.is_empty(),
            "seed {seed}: {params:?}\n{}",
            wrong.join("\n")
        );
    }
}

/// The long run (see the module's documentation); it prints its figures.
#[test]
#[ignore = "the long soak, run by hand: cargo test --release -p hetcomm-router --test oracle -- --ignored --nocapture"]
fn soak() {
    let schedules = env("HETCOMM_ORACLE_SCHEDULES").unwrap_or(5_000);
    let first = env("HETCOMM_ORACLE_FIRST_SEED").unwrap_or(10_000);
    let sends = env("HETCOMM_ORACLE_SENDS").unwrap_or(2_000) as u32;
    let started = std::time::Instant::now();
    let (schedules, sends, events, tally, switching) = check(first, schedules, sends);
    println!(
        "soak: seeds {first}..{}, {schedules} schedules, {sends} sends, {events} router calls, \
         0 false outcomes (delivered, sent, unconfirmed, failed, of which no session: \
         {tally:?}), (path changes, probes) {switching:?}, {:.0} s",
        first + schedules,
        started.elapsed().as_secs_f64()
    );
}

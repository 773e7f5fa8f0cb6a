//! `hetcomm replay`: a recording's sends, sent again into a live fleet or a simulation.

use std::collections::BTreeSet;
use std::path::Path;
use std::time::Duration;

use hetcomm::sim::{SimFleet, SimOptions};
use hetcomm::LocalFleet;
use hetcomm_record::format::Event;
use hetcomm_record::replay::{replay_realtime, replay_sim};
use hetcomm_record::stats::Publisher;
use hetcomm_record::{ReplayFilter, ReplayReport};

/// Flags of `hetcomm replay`.
pub struct ReplayArgs<'a> {
    /// The recording.
    pub file: &'a Path,
    /// The fleet to replay into.
    pub into: &'a Path,
    /// Which recorded sends.
    pub filter: ReplayFilter,
    /// Time scale: 2 replays twice as fast.
    pub speed: f64,
    /// Into a simulation of the fleet (virtual time) instead of the live fleet.
    pub sim: bool,
    /// The simulation's seed.
    pub seed: u64,
    /// Live: how long to wait for outstanding outcomes at the end.
    pub settle: Duration,
}

/// Runs the replay and prints what happened. Exit code 0 when every send was made, 1 when
/// some were refused or unreadable, or the file was damaged (what could be read was replayed).
pub fn run(args: ReplayArgs<'_>) -> anyhow::Result<bool> {
    if !(args.speed.is_finite() && args.speed > 0.0) {
        anyhow::bail!("--speed {}: expected a positive number", args.speed);
    }
    let fleet = hetcomm::load_fleet(args.into)?;
    let report = if args.sim {
        let sim = SimFleet::open(
            fleet,
            SimOptions {
                seed: args.seed,
                ..SimOptions::default()
            },
        )?;
        replay_sim(args.file, &sim, &args.filter, args.speed)?
    } else {
        // Open the systems whose sends are replayed: the filter's, or every recorded sender.
        let names: Vec<String> = if args.filter.systems.is_empty() {
            let mut senders = BTreeSet::new();
            hetcomm_record::read_with(args.file, |e| {
                if let Event::Send(s) = e {
                    if args.filter.accepts(&s.message.source) {
                        senders.insert(s.message.source.system);
                    }
                }
            })?;
            senders.into_iter().collect()
        } else {
            args.filter.systems.clone()
        };
        if names.is_empty() {
            anyhow::bail!("{}: no recorded send to replay", args.file.display());
        }
        let refs: Vec<&str> = names.iter().map(String::as_str).collect();
        let local = LocalFleet::open_systems(fleet, &refs)?;
        let _publisher = Publisher::from_env(local.systems()).map_err(anyhow::Error::msg)?;
        eprintln!(
            "replaying {} as {} into {} at {}× speed",
            args.file.display(),
            names.join(", "),
            args.into.display(),
            args.speed
        );
        replay_realtime(
            args.file,
            local.systems(),
            &args.filter,
            args.speed,
            args.settle,
        )?
    };
    print_report(&report, args.sim);
    let s = &report.stats;
    Ok(report.read.problem.is_none() && s.refused == 0 && s.unreadable == 0)
}

fn print_report(r: &ReplayReport, sim: bool) {
    let s = &r.stats;
    println!("read: {}", r.read.describe());
    println!(
        "replayed {} sends covering {:.3} s of recording in {:.3} s of wall time{}",
        s.sent,
        r.recorded_s,
        r.wall.as_secs_f64(),
        if sim { " (virtual time)" } else { "" }
    );
    println!(
        "outcomes: {} delivered, {} sent (unconfirmable), {} unconfirmed, {} failed, {} pending",
        s.delivered, s.sent_unconfirmable, s.unconfirmed, s.failed, s.pending
    );
    if s.refused > 0 {
        println!(
            "refused: {} ({})",
            s.refused,
            s.first_refusal.as_deref().unwrap_or("")
        );
    }
    if s.unreadable > 0 {
        println!("unreadable payloads: {}", s.unreadable);
    }
}

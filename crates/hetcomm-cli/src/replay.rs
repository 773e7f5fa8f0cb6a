//! `hetcomm replay`: a recording's sends (or, for a recording of what a live system received,
//! those messages) sent again into a live fleet or a simulation.

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
    /// `--foxglove HOST:PORT`: the replaying systems served to Foxglove (live replays only).
    pub foxglove: &'a crate::foxglove::FoxgloveArgs,
}

/// Runs the replay and prints what happened. Exit code 0 when every send was made, 1 when
/// some were refused or unreadable, or the file was damaged (what could be read was replayed).
pub fn run(args: ReplayArgs<'_>) -> anyhow::Result<bool> {
    if !(args.speed.is_finite() && args.speed > 0.0) {
        anyhow::bail!("--speed {}: expected a positive number", args.speed);
    }
    if args.sim && args.foxglove.foxglove.is_some() {
        anyhow::bail!(
            "--foxglove serves a live replay while it happens; a replay --sim runs in virtual \
             time, as fast as it computes: leave out --sim or --foxglove"
        );
    }
    let fleet = hetcomm::load_fleet(args.into)?;
    let mut filter = args.filter;
    let mut live = None;
    let report = if args.sim {
        let sim = SimFleet::open(
            fleet,
            SimOptions {
                seed: args.seed,
                ..SimOptions::default()
            },
        )?;
        if !filter.receipts {
            let contents = Contents::of(args.file, &filter)?;
            filter.receipts = contents.senders.is_empty() && !contents.receipt_sources.is_empty();
        }
        replay_sim(args.file, &sim, &filter, args.speed)?
    } else {
        // Open the systems whose sends are replayed: the filter's, or every recorded sender
        // (of the receipts' messages, when those are replayed).
        let contents = Contents::of(args.file, &filter)?;
        if !filter.receipts && contents.senders.is_empty() && !contents.receipt_sources.is_empty() {
            // A recording of what a live system received (`hetcomm record`): replay that.
            eprintln!(
                "{} holds no sends, only what {} received ({} messages): replaying those, \
                 sent again from {}",
                args.file.display(),
                contents
                    .receivers
                    .iter()
                    .cloned()
                    .collect::<Vec<_>>()
                    .join(", "),
                contents.receipts,
                contents
                    .receipt_sources
                    .iter()
                    .cloned()
                    .collect::<Vec<_>>()
                    .join(", ")
            );
            filter.receipts = true;
        }
        let found = match filter.receipts {
            false => &contents.senders,
            true => &contents.receipt_sources,
        };
        let names: Vec<String> = match filter.systems.is_empty() {
            true => found.iter().cloned().collect(),
            false => filter.systems.clone(),
        };
        if names.is_empty() {
            anyhow::bail!(
                "{}: nothing to replay: it holds {} sends, {} receipts and {} outcomes{}; \
                 record a run with `hetcomm demo --record FILE` (sends) or a live system with \
                 `hetcomm record FLEET --as SYSTEM -o FILE` (receipts)",
                args.file.display(),
                contents.sends,
                contents.receipts,
                contents.outcomes,
                match (filter.receipts, filter.systems.is_empty()) {
                    (_, false) => " from the systems named",
                    _ => "",
                }
            );
        }
        let refs: Vec<&str> = names.iter().map(String::as_str).collect();
        live = args.foxglove.start("hetcomm replay")?;
        let local = LocalFleet::open_systems(fleet, &refs)?;
        let _publisher = Publisher::from_env(local.systems()).map_err(anyhow::Error::msg)?;
        if let Some(live) = &live {
            live.watch(local.systems())?;
        }
        eprintln!(
            "replaying {} as {} into {} at {}× speed",
            args.file.display(),
            names.join(", "),
            args.into.display(),
            args.speed
        );
        replay_realtime(args.file, local.systems(), &filter, args.speed, args.settle)?
    };
    print_report(&report, args.sim);
    if let Some(live) = &live {
        live.finish();
    }
    let s = &report.stats;
    Ok(report.read.problem.is_none() && s.refused == 0 && s.unreadable == 0)
}

/// What a recording holds, as far as choosing what to replay goes.
#[derive(Default)]
struct Contents {
    sends: u64,
    receipts: u64,
    outcomes: u64,
    /// Systems with a recorded first attempt the filter's modules pass.
    senders: BTreeSet<String>,
    /// Sources of the delivered receipts the filter's modules pass.
    receipt_sources: BTreeSet<String>,
    /// The systems whose receipts they are.
    receivers: BTreeSet<String>,
}

impl Contents {
    fn of(file: &Path, filter: &ReplayFilter) -> anyhow::Result<Contents> {
        let mut c = Contents::default();
        let modules_pass =
            |m: &str| filter.modules.is_empty() || filter.modules.iter().any(|f| f == m);
        hetcomm_record::read_with(file, |e| match e {
            Event::Send(s) => {
                c.sends += 1;
                if s.attempt == 1 && modules_pass(&s.message.source.module) {
                    c.senders.insert(s.message.source.system);
                }
            }
            Event::Receipt(r) => {
                c.receipts += 1;
                if r.status == "delivered" && modules_pass(&r.message.source.module) {
                    c.receipt_sources.insert(r.message.source.system);
                    c.receivers.insert(r.message.destination.system);
                }
            }
            Event::Outcome(_) => c.outcomes += 1,
            Event::PathSwitch(_) => {}
        })?;
        Ok(c)
    }
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

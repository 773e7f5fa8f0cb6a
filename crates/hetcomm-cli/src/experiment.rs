//! `hetcomm experiment …`: the thesis's experiments, re-run in virtual time
//! (`hetcomm-experiments`).

use std::path::{Path, PathBuf};
use std::process::ExitCode;
use std::time::Instant;

use clap::{Args, Subcommand, ValueEnum};
use hetcomm_experiments::latency::{self, LatencyConfig};
use hetcomm_experiments::reliability::{self, LossModel, Mode, ReliabilityConfig};
use hetcomm_experiments::report::{self, Format};
use hetcomm_experiments::sweep::{self, SweepConfig};

use crate::security::SecurityArgs;

/// The experiments.
#[derive(Subcommand)]
pub enum Experiment {
    /// The reliability analysis of the thesis (§5.2, Tables 16–20): Bravo, Charlie and Delta
    /// each send one broadcast and five point-to-point messages per trial over the R and B
    /// transports of Table 17, in virtual time. Two modes side by side: `thesis`
    /// (unacknowledged, losses reported by the transport, 3 attempts) and `acknowledged`
    /// (silent losses recovered by the routers' acknowledgements and retransmissions).
    ///
    /// Prints tables in the shape of Tables 19 and 20 and the delivery ratio next to the
    /// thesis's 413 of 420, and writes reliability.json, summary.csv and tables.csv (and the
    /// fleet used, under fleet/) into --out.
    Reliability(ReliabilityArgs),
    /// The delay analysis of the thesis's future work (§6.1): one-way and round-trip delay per
    /// ordered pair and transport of a fleet, under a load (--rate messages per second per
    /// pair) and a payload size (--size). Pairs on emulated links run in the virtual-time
    /// simulator (seeded: the same seed gives the same figures); pairs on real transports run
    /// in real time, every system opened in this process over the real transports, timed on
    /// the monotonic clock. The output states the clock method.
    ///
    /// Prints p50/p90/p99/p99.9/max per pair and writes latency.json, summary.csv,
    /// samples.csv (every sample) and plots/<from>-<to>.png (histogram and CDF) into --out.
    Latency(LatencyArgs),
}

/// Options of `hetcomm experiment latency`.
#[derive(Args)]
pub struct LatencyArgs {
    /// The fleet file to measure (e.g. examples/leader_follower/fleet.toml).
    #[arg(long, value_name = "FILE")]
    fleet: Option<PathBuf>,
    /// Measure the thesis's §5.1 fleet (Tables 6–8) with R and B emulated as in the
    /// reliability experiment (R = `wired`, B = `bluetooth-classic`), and print the delays the
    /// thesis publishes beside ours (written to OUT/fleet/).
    #[arg(long, conflicts_with = "fleet")]
    against_thesis: bool,
    /// Counted probes per ordered pair.
    #[arg(long, default_value_t = LatencyConfig::default().messages)]
    messages: u32,
    /// Probes per pair sent first and not counted.
    #[arg(long, default_value_t = LatencyConfig::default().warmup)]
    warmup: u32,
    /// Load: probes per second per ordered pair (every pair sends at once).
    #[arg(long, value_name = "MSG_PER_S", default_value_t = LatencyConfig::default().rate_hz)]
    rate: f64,
    /// Payload bytes of each probe and echo (at least 4: the sequence number).
    #[arg(long, value_name = "BYTES", default_value_t = LatencyConfig::default().size_bytes)]
    size: usize,
    /// Seed of the simulator (the emulated links' loss and jitter).
    #[arg(long, default_value_t = LatencyConfig::default().seed)]
    seed: u64,
    /// Run every pair in real time, emulated links included (emulated then in real time).
    #[arg(long)]
    realtime: bool,
    /// Closed loop: each pair's next probe leaves once the previous one's echo is back (and
    /// not before its time at --rate): one probe in flight per pair, as a ping–pong. Real time
    /// only; every pair measured needs a way back.
    #[arg(long)]
    closed_loop: bool,
    /// Measure only this ordered pair (repeatable): FROM:TO, friendly names; the echoes still
    /// come back on TO → FROM. Default: every pair the table connects.
    #[arg(long = "pair", value_name = "FROM:TO", value_parser = parse_pair)]
    pairs: Vec<(String, String)>,
    /// After the last probe, how long to wait for the last receipts and echoes, ms.
    #[arg(long, value_name = "MS", default_value_t = 2000)]
    drain_ms: u64,
    /// Output directory (created if missing).
    #[arg(long, value_name = "DIR", default_value = "hetcomm-out/latency")]
    out: PathBuf,
    /// What to print on stdout (files are always written): text, csv (summary.csv) or json.
    #[arg(long, value_enum, default_value_t = FormatArg::Text)]
    format: FormatArg,
    #[command(flatten)]
    security: SecurityArgs,
}

/// Which modes to run.
#[derive(Clone, Copy, Debug, ValueEnum)]
pub enum ModeArg {
    /// Unacknowledged delivery, reported losses, 3 attempts (the thesis's situation).
    Thesis,
    /// Acknowledged delivery, silent losses, RTT-based retransmission.
    Acknowledged,
    /// Both, side by side.
    Both,
}

/// What to print on stdout.
#[derive(Clone, Copy, Debug, ValueEnum)]
pub enum FormatArg {
    /// Tables.
    Text,
    /// summary.csv, a blank line, tables.csv (sweep: sweep.csv).
    Csv,
    /// One JSON object (the report plus wall_time_s and files).
    Json,
}

/// Options of `hetcomm experiment reliability`.
#[derive(Args)]
pub struct ReliabilityArgs {
    /// Fleet file to use instead of the built-in one (Tables 16–18 with R = emulated `wired`,
    /// B = emulated `bluetooth-classic`; written to OUT/fleet/ as a starting point).
    #[arg(long, value_name = "FILE")]
    fleet: Option<PathBuf>,
    /// Trials per mode.
    #[arg(long, default_value_t = reliability::THESIS_TRIALS)]
    trials: u32,
    /// Base seed: the destinations, and each trial's simulation (seed + trial).
    #[arg(long, default_value_t = ReliabilityConfig::default().seed)]
    seed: u64,
    /// Attempt budget of the acknowledged mode (first transmission included). The default
    /// delivers every message even at 30% i.i.d. loss on B.
    #[arg(long, default_value_t = reliability::DEFAULT_ATTEMPTS)]
    attempts: u32,
    /// I.i.d. loss on the B transport, percent (turns the profile's burst loss off).
    #[arg(long, value_name = "PERCENT", conflicts_with = "burst_loss")]
    loss: Option<f64>,
    /// Gilbert–Elliott mean loss on the B transport, percent (needs --burst-length).
    #[arg(long, value_name = "PERCENT", requires = "burst_length")]
    burst_loss: Option<f64>,
    /// Mean burst length of --burst-loss, frames (≥ 1).
    #[arg(long, value_name = "FRAMES", requires = "burst_loss")]
    burst_length: Option<f64>,
    /// Which modes to run.
    #[arg(long, value_enum, default_value_t = ModeArg::Both)]
    mode: ModeArg,
    /// A scenario file (faults, injections, taps in scenario time; docs/harness.md) applied
    /// to every trial from its start.
    #[arg(long, value_name = "FILE")]
    scenario: Option<PathBuf>,
    /// Output directory (created if missing).
    #[arg(long, value_name = "DIR", default_value = "hetcomm-out/reliability")]
    out: PathBuf,
    /// What to print on stdout (files are always written).
    #[arg(long, value_enum, default_value_t = FormatArg::Text)]
    format: FormatArg,
    /// Sweep the loss on B over 0, 5, …, 30%, i.i.d. and bursty (mean burst 3 frames), instead
    /// of one run; writes sweep.csv, sweep.json and sweep.png.
    #[arg(long, conflicts_with_all = ["loss", "burst_loss", "burst_length"])]
    sweep: bool,
    /// Run on the fleet's real transports in real time instead of the virtual-time simulator
    /// (e.g. a --fleet mapping R to a `ros1` transport on a running master). Losses are then
    /// what the real links do; they are not reported to the sender.
    #[arg(long, conflicts_with = "sweep")]
    realtime: bool,
    #[command(flatten)]
    security: SecurityArgs,
}

/// Runs an experiment subcommand.
pub fn run(experiment: Experiment) -> anyhow::Result<ExitCode> {
    match experiment {
        Experiment::Reliability(args) => reliability_cmd(args),
        Experiment::Latency(args) => latency_cmd(args),
    }
}

fn config(args: &ReliabilityArgs) -> ReliabilityConfig {
    let loss = match (args.loss, args.burst_loss, args.burst_length) {
        (Some(percent), _, _) => LossModel::Iid { percent },
        (None, Some(percent), Some(burst_length)) => LossModel::Bursty {
            percent,
            burst_length,
        },
        _ => LossModel::Profile,
    };
    ReliabilityConfig {
        trials: args.trials,
        seed: args.seed,
        attempts: args.attempts,
        modes: match args.mode {
            ModeArg::Thesis => vec![Mode::Thesis],
            ModeArg::Acknowledged => vec![Mode::Acknowledged],
            ModeArg::Both => Mode::ALL.to_vec(),
        },
        loss,
        realtime: args.realtime,
        ..ReliabilityConfig::default()
    }
}

fn print_paths(to_stderr: bool, paths: &[PathBuf]) {
    for p in paths {
        if to_stderr {
            eprintln!("wrote {}", p.display());
        } else {
            println!("wrote {}", p.display());
        }
    }
}

fn load(args: &ReliabilityArgs, out: &Path) -> anyhow::Result<hetcomm::config::Fleet> {
    let path = match &args.fleet {
        Some(path) => path.clone(),
        None => reliability::write_default_fleet(&out.join("fleet"))?,
    };
    args.security.load(&path)
}

fn reliability_cmd(args: ReliabilityArgs) -> anyhow::Result<ExitCode> {
    let start = Instant::now();
    let mut config = config(&args);
    reliability::validate(&config)?;
    let fleet = load(&args, &args.out)?;
    if let Some(path) = &args.scenario {
        match hetcomm::config::scenario::load_scenario(path, &fleet) {
            Ok(sc) => config.scenario = Some(sc),
            Err(errors) => {
                eprintln!("{errors}");
                return Ok(ExitCode::from(2));
            }
        }
    }
    let format = match args.format {
        FormatArg::Text => Format::Text,
        FormatArg::Csv => Format::Csv,
        FormatArg::Json => Format::Json,
    };
    if args.sweep {
        let sweep_config = SweepConfig {
            base: config,
            ..SweepConfig::default()
        };
        let report = sweep::run(&fleet, &sweep_config)?;
        let paths = sweep::write_files(&report, &args.out)?;
        let wall = start.elapsed().as_secs_f64();
        let ok = report
            .points
            .iter()
            .all(|p| p.balanced && p.duplicates_delivered == 0);
        match format {
            Format::Text => {
                print!("{}", sweep::text(&report));
                println!("\nwall time: {wall:.3} s");
                print_paths(false, &paths);
            }
            Format::Csv => {
                print!("{}", sweep::csv(&report));
                eprintln!("wall time: {wall:.3} s");
                print_paths(true, &paths);
            }
            Format::Json => {
                let mut value = serde_json::to_value(&report)?;
                value["wall_time_s"] = serde_json::json!(wall);
                value["files"] = serde_json::json!(paths);
                println!("{}", serde_json::to_string_pretty(&value)?);
            }
        }
        return Ok(exit(ok));
    }
    let report = reliability::run(&fleet, &config)?;
    let mut paths = report::write_files(&report, &args.out)?;
    if args.fleet.is_none() {
        paths.push(args.out.join("fleet").join("fleet.toml"));
    }
    let wall = start.elapsed().as_secs_f64();
    let ok = report
        .modes
        .iter()
        .all(|m| m.accounting.balanced && m.duplicates_delivered == 0);
    match format {
        Format::Text => {
            print!("{}", report::render(&report, format));
            println!(
                "wall time: {wall:.3} s for {} trials × {} mode(s)",
                report.trials,
                report.modes.len()
            );
            print_paths(false, &paths);
        }
        Format::Csv => {
            print!("{}", report::render(&report, format));
            eprintln!("wall time: {wall:.3} s");
            print_paths(true, &paths);
        }
        Format::Json => {
            let mut value = serde_json::to_value(&report)?;
            value["wall_time_s"] = serde_json::json!(wall);
            value["files"] = serde_json::json!(paths);
            println!("{}", serde_json::to_string_pretty(&value)?);
        }
    }
    Ok(exit(ok))
}

fn parse_pair(s: &str) -> Result<(String, String), String> {
    match s.split_once(':') {
        Some((from, to)) if !from.is_empty() && !to.is_empty() => {
            Ok((from.to_string(), to.to_string()))
        }
        _ => Err(format!("expected FROM:TO (two system names), got `{s}`")),
    }
}

fn latency_cmd(args: LatencyArgs) -> anyhow::Result<ExitCode> {
    let start = Instant::now();
    let config = LatencyConfig {
        messages: args.messages,
        warmup: args.warmup,
        rate_hz: args.rate,
        size_bytes: args.size,
        seed: args.seed,
        realtime: args.realtime,
        closed_loop: args.closed_loop,
        pairs: args.pairs.clone(),
        drain: std::time::Duration::from_millis(args.drain_ms),
    };
    latency::validate(&config)?;
    if args.fleet.is_none() && !args.against_thesis {
        anyhow::bail!(
            "say what to measure: --fleet FILE (e.g. examples/leader_follower/fleet.toml) or \
             --against-thesis (the thesis's §5.1 fleet)"
        );
    }
    let (fleet, fleet_file) = match &args.fleet {
        Some(path) => (args.security.load(path)?, None),
        None => {
            let path = latency::thesis::write_fleet(&args.out.join("fleet"))?;
            (args.security.load(&path)?, Some(path))
        }
    };
    let thesis: Option<&latency::ThesisFigures> = if args.against_thesis {
        Some(&latency::thesis::published)
    } else {
        None
    };
    let report = latency::run(&fleet, &config, thesis)?;
    let mut paths = latency::write_files(&report, &args.out)?;
    paths.extend(fleet_file);
    let wall = start.elapsed().as_secs_f64();
    match args.format {
        FormatArg::Text => {
            print!("{}", latency::text(&report));
            println!();
            print_paths(false, &paths);
        }
        FormatArg::Csv => {
            print!("{}", latency::csv_summary(&report));
            print_paths(true, &paths);
        }
        FormatArg::Json => {
            let mut value = serde_json::to_value(&report)?;
            value["wall_time_s"] = serde_json::json!(wall);
            value["files"] = serde_json::json!(paths);
            println!("{}", serde_json::to_string_pretty(&value)?);
        }
    }
    // The wall time varies from run to run: on stderr, so that stdout of a simulated run is
    // the same every time.
    eprintln!("wall time: {wall:.3} s");
    let duplicates: u64 = report.pairs.iter().map(|p| p.duplicates).sum();
    Ok(exit(duplicates == 0))
}

/// Exit status: 0, or 1 when an invariant broke (unbalanced accounting, a duplicate reached an
/// inbox), which the output then shows.
fn exit(ok: bool) -> ExitCode {
    if ok {
        ExitCode::SUCCESS
    } else {
        eprintln!("error: an invariant failed (accounting unbalanced or duplicates delivered)");
        ExitCode::FAILURE
    }
}

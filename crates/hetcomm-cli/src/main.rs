//! The `hetcomm` command line.

use std::path::PathBuf;
use std::process::ExitCode;
use std::time::Duration;

use clap::{Parser, Subcommand};

mod demo;
mod experiment;
mod foxglove;
mod keygen;
mod listen;
mod monitor;
mod names;
mod poke;
mod security;

use security::SecurityArgs;
mod record;
mod replay;
mod topology;

/// hetcomm: a heterogeneous communication layer and test harness for teams of robots.
#[derive(Parser)]
#[command(name = "hetcomm", version, about)]
struct Cli {
    #[command(subcommand)]
    command: Command,
}

#[derive(Subcommand)]
enum Command {
    /// Check a fleet file (or the thesis's legacy files) without opening anything.
    ///
    /// Prints a one-line summary and a line per transport on its security (secured or not,
    /// and which systems it carries lack a public key), and exits 0; or prints every error
    /// with file:line:column and exits 2.
    Validate {
        /// The fleet file (TOML).
        file: Option<PathBuf>,
        /// Legacy id file (Tables 1, 6, 16) instead of a fleet file.
        #[arg(long, requires = "table", conflicts_with = "file")]
        ids: Option<PathBuf>,
        /// Legacy communication table (Tables 2, 7, 17).
        #[arg(long, requires = "ids")]
        table: Option<PathBuf>,
        /// Legacy Bluetooth address file (Tables 3, 8, 18).
        #[arg(long, requires = "ids")]
        bluetooth: Option<PathBuf>,
        /// Read the systems' keys from DIR, as the commands that open systems do with
        /// `--keys DIR` (written by `hetcomm keygen`).
        #[arg(long, value_name = "DIR")]
        keys: Option<PathBuf>,
        /// A scenario file to check against the fleet too (docs/harness.md).
        #[arg(long, value_name = "FILE")]
        scenario: Option<PathBuf>,
    },
    /// Print a commented example fleet file (secured: run `hetcomm keygen` for it next).
    GenerateConfig,
    /// Write a key pair per system of a fleet: DIR/<System>.key (the private key, mode 0600:
    /// it goes to the machine that runs the system, and nowhere else) and DIR/<System>.pub
    /// (the public key, for every machine). Prints what to put in the fleet file.
    Keygen {
        /// The fleet file whose systems get keys (its own key files are not read).
        #[arg(long, required_unless_present = "ids", conflicts_with = "ids")]
        fleet: Option<PathBuf>,
        /// Legacy id file (Tables 1, 6, 16) instead of a fleet file.
        #[arg(long, requires = "table")]
        ids: Option<PathBuf>,
        /// Legacy communication table (Tables 2, 7, 17), with --ids.
        #[arg(long, requires = "ids")]
        table: Option<PathBuf>,
        /// The directory to write the keys into (created, mode 0700, if missing).
        #[arg(long, value_name = "DIR")]
        out: PathBuf,
        /// Replace key files that already exist (by default, keygen refuses).
        #[arg(long)]
        force: bool,
    },
    /// Run the thesis's leader–follower demonstration (§5.1): Alpha leads, Charlie and Tango
    /// follow, virtual environments integrate their poses. Prints the command tables
    /// (Tables 9–12) and pose tables (13–15), and writes CSV and PNG plots.
    Demo {
        /// Seed of the emulated links.
        #[arg(long, default_value_t = 1)]
        seed: u64,
        /// Output folder for tables, CSV and plots.
        #[arg(long, default_value = "hetcomm-out/demo")]
        out: PathBuf,
        /// Fleet file to use instead of the embedded Tables 6–8 fleet (needs Alpha, Charlie,
        /// Tango, their VEs, and modules Plan, Act, World). Tango may be the robot of a bridge
        /// transport (e.g. examples/ros2/leader-follower-ros2.toml or
        /// examples/ros1/leader-follower-ros1.toml, docs/ros-bridges.md).
        #[arg(long, conflicts_with_all = ["r", "b"])]
        fleet: Option<PathBuf>,
        /// What the table letter R means: inproc, wired, wifi, bluetooth-classic (emulated
        /// profiles), ros1, zenoh (through a Zenoh router started in this process; needs
        /// the `zenoh` feature), or mqtt (through the broker of --mqtt-broker; needs the
        /// `mqtt` feature).
        #[arg(long, default_value = "inproc",
              value_parser = ["inproc", "wired", "wifi", "bluetooth-classic", "ros1", "zenoh", "mqtt"])]
        r: String,
        /// What the table letter B means: inproc, wired, wifi, bluetooth-classic (emulated
        /// profiles), bluetooth (real RFCOMM; Table 8 addresses), zenoh (through a Zenoh
        /// router started in this process; needs the `zenoh` feature), or mqtt (through the
        /// broker of --mqtt-broker; needs the `mqtt` feature).
        #[arg(long, default_value = "bluetooth-classic",
              value_parser = ["inproc", "wired", "wifi", "bluetooth-classic", "bluetooth", "zenoh", "mqtt"])]
        b: String,
        /// The MQTT broker `--r mqtt` / `--b mqtt` go through (a running mosquitto, say).
        #[arg(long, value_name = "HOST:PORT", default_value = "127.0.0.1:1883")]
        mqtt_broker: String,
        /// One virtual environment receiving every rover's Wheels through callbacks, instead
        /// of one polling VE per rover.
        #[arg(long)]
        single_ve: bool,
        /// Run in real time (about 15 s) instead of virtual time.
        #[arg(long)]
        realtime: bool,
        /// A follower whose autonomy code runs in another process (e.g. the Python Tango of
        /// examples/python); needs --realtime and a fleet carrying its traffic over UDP/TCP.
        #[arg(long, value_name = "SYSTEM")]
        external: Vec<String>,
        #[command(flatten)]
        security: SecurityArgs,
        #[command(flatten)]
        tools: DemoToolArgs,
        /// A scenario file (faults, injections, taps in scenario time; docs/harness.md), e.g.
        /// examples/leader_follower/scenario-tango-cut.toml. In virtual time the run is also
        /// made without it, and what changed is printed.
        #[arg(long, value_name = "FILE")]
        scenario: Option<PathBuf>,
    },
    /// Print every message arriving at a system of a live fleet (like `rostopic echo`).
    ///
    /// Messages go to stdout, one a line, starting with when it arrived (`+1.234 s` since the
    /// start); `sent=` is the sender's timestamp. On stderr: a status line when something was
    /// dropped (at most once a second), and a summary of every counter at the end — after
    /// --count, at --timeout, on Ctrl-C / SIGTERM, or when stdout is closed (exit code 0 in
    /// every case).
    Listen {
        /// The fleet file.
        fleet: PathBuf,
        /// The system to listen as (its endpoint is opened by this command).
        #[arg(long = "as", value_name = "SYSTEM")]
        system: String,
        /// Only this module (default: every module).
        #[arg(long)]
        module: Option<String>,
        /// Exit after this many messages.
        #[arg(long)]
        count: Option<usize>,
        /// Exit after this many seconds.
        #[arg(long)]
        timeout: Option<f64>,
        /// One JSON object per line instead of text. Times in it are always raw microseconds
        /// (`timestamp_us`, `received_us`); the payload is `payload` when it decodes (a nil
        /// also has `payload_hex`), else `payload_error` and `payload_hex`.
        #[arg(long)]
        json: bool,
        /// A line on stderr for every drop as soon as it is counted, instead of a status line
        /// at most once a second.
        #[arg(long, short)]
        verbose: bool,
        /// Print times as microseconds since the UNIX epoch instead of seconds since the
        /// listener started (`+1.234 s`).
        #[arg(long)]
        raw_times: bool,
        #[command(flatten)]
        security: SecurityArgs,
        #[command(flatten)]
        foxglove: foxglove::FoxgloveArgs,
    },
    /// Send one message from a system of a live fleet and print its outcome (like
    /// `rostopic pub`). Exits 0 when delivered (in the destination module's inbox) or sent
    /// without confirmation, 3 when unconfirmed (frames left but no acknowledgement came back:
    /// it may or may not have arrived), 1 when it certainly failed.
    Send {
        /// The fleet file.
        fleet: PathBuf,
        /// The system to send as (its endpoint is opened by this command).
        #[arg(long = "as", value_name = "SYSTEM")]
        system: String,
        /// Sending module (default: the fleet's first module).
        #[arg(long)]
        from_module: Option<String>,
        /// Destination system, or `All` to broadcast.
        #[arg(long)]
        to: String,
        /// Destination module.
        #[arg(long)]
        module: String,
        /// Message type id.
        #[arg(long = "type")]
        message_type: u32,
        /// The payload as JSON (encoded as the language-neutral MessagePack payload).
        #[arg(long)]
        json: String,
        /// Priority (0–255, default 100).
        #[arg(long, default_value_t = 100)]
        priority: u8,
        /// Longest wait for the outcome, seconds.
        #[arg(long, default_value_t = 10.0)]
        timeout: f64,
        #[command(flatten)]
        security: SecurityArgs,
    },
    /// Record what systems of a live fleet receive into an MCAP file (docs/record-replay.md).
    ///
    /// Opens the systems (their endpoints) in this process, records every message arriving
    /// at them (envelope and payload) until --duration or Ctrl-C, and writes the file. To
    /// record a fleet's sends and outcomes too, record from inside the run (`hetcomm demo
    /// --record`, or hetcomm_record::Recorder in a program).
    Record {
        /// The fleet file.
        fleet: PathBuf,
        /// The systems to record as (comma-separated).
        #[arg(
            long = "as",
            value_name = "SYSTEM[,…]",
            value_delimiter = ',',
            required = true
        )]
        systems: Vec<String>,
        /// The MCAP file to write.
        #[arg(short, long)]
        out: PathBuf,
        /// Stop after this many seconds (default: at Ctrl-C / SIGTERM).
        #[arg(long)]
        duration: Option<f64>,
        /// Raw MessagePack payloads (message encoding `msgpack`) instead of JSON with a JSON
        /// Schema per message type.
        #[arg(long)]
        msgpack: bool,
    },
    /// Send a recording's messages again, with their recorded timing, into a live fleet or a
    /// simulation of one (docs/record-replay.md).
    ///
    /// Each recorded send (first attempts) is sent again by the same system and module, to
    /// the same destination, at the same offset from the recording's start (divided by
    /// --speed). A damaged or truncated file is replayed as far as it reads, and the damage is
    /// reported (exit code 1).
    Replay {
        /// The MCAP recording.
        file: PathBuf,
        /// The fleet to replay into.
        #[arg(long)]
        into: PathBuf,
        /// Only the sends of these systems (comma-separated; default: every recorded sender).
        #[arg(long, value_delimiter = ',')]
        systems: Vec<String>,
        /// Only the sends from these modules (comma-separated).
        #[arg(long, value_delimiter = ',')]
        modules: Vec<String>,
        /// Replay what the recorded systems received (sent again from the recorded sources)
        /// instead of what they sent. The default for a recording that holds receipts only
        /// (`hetcomm record`).
        #[arg(long)]
        receipts: bool,
        /// Time scale: 2 replays twice as fast, 0.5 half as fast.
        #[arg(long, default_value_t = 1.0)]
        speed: f64,
        /// Into a simulation of the fleet (virtual time, as fast as it computes).
        #[arg(long)]
        sim: bool,
        /// The simulation's seed.
        #[arg(long, default_value_t = 1)]
        seed: u64,
        /// Live: seconds to wait for outstanding outcomes at the end.
        #[arg(long, default_value_t = 5.0)]
        settle: f64,
        #[command(flatten)]
        foxglove: foxglove::FoxgloveArgs,
    },
    /// Show live per-pair statistics of a fleet, refreshed once a second
    /// (docs/record-replay.md).
    ///
    /// Processes publish their systems' statistics to the monitor's UDP address when
    /// HETCOMM_MONITOR=host:port is set in their environment (hetcomm demo, listen, send, record,
    /// replay, and programs using hetcomm_record::stats::Publisher).
    Monitor {
        /// The fleet file (names the pairs and transports).
        fleet: PathBuf,
        /// The UDP address to receive statistics on.
        #[arg(long, default_value = hetcomm_record::stats::DEFAULT_MONITOR_ADDR)]
        listen: String,
        /// One JSON object per line and second instead of the terminal view.
        #[arg(long)]
        json: bool,
        /// Exit after this many seconds.
        #[arg(long)]
        duration: Option<f64>,
        #[command(flatten)]
        foxglove: foxglove::FoxgloveArgs,
    },
    /// Draw a fleet's systems and, per ordered pair, the transport that carries it
    /// (docs/record-replay.md). SVG or PNG by the output's extension.
    Topology {
        /// The fleet file.
        fleet: PathBuf,
        /// The picture to write (.svg or .png).
        #[arg(short, long)]
        out: PathBuf,
        /// Also draw pairs that cannot talk (X in the table) as dotted lines.
        #[arg(long)]
        show_x: bool,
    },
    /// Run a Zenoh router for fleets with `zenoh` transports (docs/zenoh.md): the zenoh
    /// crate's router mode, listening on the given endpoints until killed (SIGINT/SIGTERM).
    /// Prints `ready` on stdout once it listens.
    ZenohRouter {
        /// Endpoint to listen on (repeatable).
        #[arg(long, default_value = "tcp/0.0.0.0:7447")]
        listen: Vec<String>,
        /// Answer and send multicast scouting (off by default: peers and clients name the
        /// router in `connect`).
        #[arg(long)]
        multicast_scouting: bool,
        /// Zenoh's lease of the router's sessions, in milliseconds: its clients and peers
        /// consider it gone after hearing nothing for this long.
        #[arg(long, default_value_t = 10_000)]
        lease_ms: u32,
    },
    /// Run an experiment of the thesis: `hetcomm experiment reliability` (§5.2, in virtual
    /// time) or `hetcomm experiment latency` (the delay analysis of §6.1).
    Experiment {
        #[command(subcommand)]
        experiment: experiment::Experiment,
    },
}

/// Recording, replay and monitoring inside `hetcomm demo`.
#[derive(clap::Args)]
struct DemoToolArgs {
    /// Record every send, receipt and outcome of the run into this MCAP file.
    #[arg(long, value_name = "FILE")]
    record: Option<PathBuf>,
    /// Record only these systems (comma-separated; default every system).
    #[arg(long, value_delimiter = ',', requires = "record")]
    record_systems: Vec<String>,
    /// Record raw MessagePack payloads instead of JSON.
    #[arg(long, requires = "record")]
    msgpack: bool,
    /// Replay this recording: the --replace systems' recorded sends stand in for their code.
    #[arg(long, value_name = "FILE", requires = "replace")]
    replay: Option<PathBuf>,
    /// The systems whose code the replay replaces (comma-separated).
    #[arg(long, value_delimiter = ',', requires = "replay")]
    replace: Vec<String>,
    #[command(flatten)]
    foxglove: foxglove::FoxgloveArgs,
}

fn secs(s: f64) -> anyhow::Result<Duration> {
    Duration::try_from_secs_f64(s)
        .map_err(|_| anyhow::anyhow!("{s} is not a valid number of seconds"))
}

fn main() -> ExitCode {
    let cli = Cli::parse();
    match run(cli.command) {
        Ok(code) => code,
        Err(e) => {
            eprintln!("error: {}", for_this_command(&chain(&e)));
            ExitCode::FAILURE
        }
    }
}

/// An error and its causes, each after a colon, as `{:#}` writes them, but a cause whose text
/// the message already holds is not written again (an error that both quotes its source and
/// returns it from `source()` printed every sentence twice).
fn chain(e: &anyhow::Error) -> String {
    let mut out = String::new();
    for cause in e.chain() {
        let text = cause.to_string();
        if out.is_empty() {
            out = text;
        } else if !out.contains(&text) {
            out.push_str(": ");
            out.push_str(&text);
        }
    }
    out
}

/// The library tells a program depending on it to "rebuild with `--features ros1`"; for this
/// command that means rebuilding the `hetcomm-cli` package with its feature of that name.
fn for_this_command(message: &str) -> String {
    const LIBRARY: &str = "rebuild with `--features ";
    let mut out = String::with_capacity(message.len());
    let mut rest = message;
    while let Some(at) = rest.find(LIBRARY) {
        let after = &rest[at + LIBRARY.len()..];
        let Some(end) = after.find('`') else { break };
        let feature = &after[..end];
        out.push_str(&rest[..at]);
        out.push_str(&format!(
            "rebuild this command with `cargo build --release -p hetcomm-cli --features {feature}`"
        ));
        rest = &after[end + 1..];
    }
    out.push_str(rest);
    out
}

fn run(command: Command) -> anyhow::Result<ExitCode> {
    match command {
        Command::Validate {
            file,
            ids,
            table,
            bluetooth,
            keys,
            scenario,
        } => {
            let kinds = hetcomm::registry().kinds();
            let result = match (file, ids, table, &keys) {
                (Some(file), _, _, None) => hetcomm::load_fleet(&file),
                (Some(file), _, _, Some(dir)) => {
                    hetcomm::config::load_with_keys_dir(&file, kinds, dir)
                }
                (None, Some(ids), Some(table), _) => hetcomm::config::load_legacy(
                    &ids,
                    &table,
                    bluetooth.as_deref(),
                )
                .and_then(|mut fleet| match &keys {
                    Some(dir) => hetcomm::config::apply_keys_dir(&mut fleet, dir).map(|()| fleet),
                    None => Ok(fleet),
                }),
                _ => anyhow::bail!(
                    "give a fleet file, or --ids and --table (and optionally --bluetooth)"
                ),
            };
            match result {
                Ok(fleet) => {
                    println!("ok: {}", fleet.summary());
                    // One line per transport. A kind's settings are read by its crate: one not
                    // compiled in is known by name only, and its line says so rather than
                    // letting "ok" claim more was checked than was.
                    for (line, t) in hetcomm::security_lines(&fleet)
                        .iter()
                        .zip(&fleet.transports)
                    {
                        match hetcomm::registry().feature_for(t.kind) {
                            Some(feature) => println!(
                                "  {line}; not compiled into this build, so its own settings \
                                 were not checked (rebuild with `--features {feature}`)"
                            ),
                            None => println!("  {line}"),
                        }
                    }
                    if !fleet.taps.is_empty() {
                        println!("  {} tap(s) placed for the whole run", fleet.taps.len());
                    }
                    for name in fleet.isolated_systems() {
                        println!(
                            "  warning: `{name}` is in [systems] but every pair with it is X: \
                             it can talk to nobody (add it to the table's columns and rows)"
                        );
                    }
                    if let Some(path) = scenario {
                        match hetcomm::config::scenario::load_scenario(&path, &fleet) {
                            Ok(sc) => println!(
                                "ok: scenario {}: {} fault(s), {} injection(s), {} tap(s), last event at {} s",
                                path.display(),
                                sc.faults.len(),
                                sc.injections.len(),
                                sc.taps.len(),
                                sc.end_s()
                            ),
                            Err(errors) => {
                                eprintln!("{errors}");
                                return Ok(ExitCode::from(2));
                            }
                        }
                    }
                    Ok(ExitCode::SUCCESS)
                }
                Err(errors) => {
                    eprintln!("{errors}");
                    Ok(ExitCode::from(2))
                }
            }
        }
        Command::GenerateConfig => {
            print!("{}", hetcomm::config::EXAMPLE_FLEET);
            Ok(ExitCode::SUCCESS)
        }
        Command::Keygen {
            fleet,
            ids,
            table,
            out,
            force,
        } => {
            let loaded = match (&fleet, ids, table) {
                (Some(file), _, _) => {
                    hetcomm::config::load_skipping_keys(file, hetcomm::registry().kinds())
                }
                (None, Some(ids), Some(table)) => hetcomm::config::load_legacy(&ids, &table, None),
                _ => anyhow::bail!("give --fleet FILE, or --ids and --table"),
            };
            let loaded = match loaded {
                Ok(f) => f,
                Err(errors) => {
                    eprintln!("{errors}");
                    return Ok(ExitCode::from(2));
                }
            };
            keygen::keygen(keygen::KeygenArgs {
                fleet_file: fleet.as_deref(),
                fleet: &loaded,
                out: &out,
                force,
            })?;
            Ok(ExitCode::SUCCESS)
        }
        Command::Listen {
            fleet,
            system,
            module,
            count,
            timeout,
            json,
            verbose,
            raw_times,
            security,
            foxglove,
        } => {
            listen::listen(listen::ListenArgs {
                foxglove: &foxglove,
                fleet: &fleet,
                security: &security,
                system: &system,
                module: module.as_deref(),
                count,
                timeout: timeout.map(secs).transpose()?,
                json,
                verbose,
                raw_times,
            })?;
            Ok(ExitCode::SUCCESS)
        }
        Command::Send {
            fleet,
            system,
            from_module,
            to,
            module,
            message_type,
            json,
            priority,
            timeout,
            security,
        } => {
            let verdict = poke::send(poke::SendArgs {
                fleet: &fleet,
                security: &security,
                system: &system,
                from_module: from_module.as_deref(),
                to: &to,
                module: &module,
                message_type,
                json: &json,
                priority,
                timeout: secs(timeout)?,
            })?;
            Ok(verdict.exit_code())
        }
        Command::Experiment { experiment } => experiment::run(experiment),
        Command::Record {
            fleet,
            systems,
            out,
            duration,
            msgpack,
        } => {
            record::record(record::RecordArgs {
                fleet: &fleet,
                systems,
                out: &out,
                duration: duration.map(secs).transpose()?,
                msgpack,
            })?;
            Ok(ExitCode::SUCCESS)
        }
        Command::Replay {
            file,
            into,
            systems,
            modules,
            receipts,
            speed,
            sim,
            seed,
            settle,
            foxglove,
        } => {
            let clean = replay::run(replay::ReplayArgs {
                foxglove: &foxglove,
                file: &file,
                into: &into,
                filter: hetcomm_record::ReplayFilter {
                    systems,
                    modules,
                    receipts,
                },
                speed,
                sim,
                seed,
                settle: secs(settle)?,
            })?;
            Ok(if clean {
                ExitCode::SUCCESS
            } else {
                ExitCode::FAILURE
            })
        }
        Command::Monitor {
            fleet,
            listen,
            json,
            duration,
            foxglove,
        } => {
            monitor::run(monitor::MonitorArgs {
                fleet: &fleet,
                listen: &listen,
                json,
                duration: duration.map(secs).transpose()?,
                foxglove: foxglove.foxglove.as_deref(),
            })?;
            Ok(ExitCode::SUCCESS)
        }
        Command::Topology { fleet, out, show_x } => {
            topology::run(&fleet, &out, show_x)?;
            Ok(ExitCode::SUCCESS)
        }
        Command::ZenohRouter {
            listen,
            multicast_scouting,
            lease_ms,
        } => zenoh_router(&listen, multicast_scouting, lease_ms),
        Command::Demo {
            seed,
            out,
            fleet,
            r,
            b,
            mqtt_broker,
            single_ve,
            realtime,
            external,
            security,
            tools,
            scenario,
        } => {
            if tools.foxglove.foxglove.is_some() && !realtime {
                anyhow::bail!(
                    "--foxglove serves a run while it happens: add --realtime (a virtual-time run \
                     is over in milliseconds; to look at one in Foxglove, --record FILE and open \
                     the file)"
                );
            }
            let hooks = record::DemoTools {
                foxglove: tools.foxglove,
                record: tools.record,
                record_systems: tools.record_systems,
                msgpack: tools.msgpack,
                replay: tools.replay,
                replace: tools.replace,
            }
            .hooks()?;
            demo::run(demo::DemoArgs {
                hooks,
                external,
                security: &security,
                scenario: scenario.as_deref(),
                seed,
                out: &out,
                fleet: fleet.as_deref(),
                r: &r,
                b: &b,
                mqtt_broker: &mqtt_broker,
                single_ve,
                realtime,
            })?;
            Ok(ExitCode::SUCCESS)
        }
    }
}

/// `hetcomm zenoh-router`: runs until the process is killed.
#[cfg(feature = "zenoh")]
fn zenoh_router(
    listen: &[String],
    multicast_scouting: bool,
    lease_ms: u32,
) -> anyhow::Result<ExitCode> {
    use std::io::Write;
    // Enough of Zenoh's receive threads that clients vanishing together do not stall the
    // router (docs/zenoh.md, "Routers and vanished clients"). Set while this process has one
    // thread, before Zenoh reads it.
    hetcomm_link_zenoh::router::use_router_runtime();
    let router = hetcomm_link_zenoh::router::ZenohRouter::start_with_lease(
        listen,
        multicast_scouting,
        lease_ms,
    )?;
    eprintln!(
        "zenoh router {} listening on {} (multicast scouting {}); Ctrl-C to stop",
        router.zenoh_id(),
        listen.join(", "),
        if multicast_scouting { "on" } else { "off" }
    );
    println!("ready");
    let _ = std::io::stdout().flush();
    loop {
        std::thread::park();
    }
}

/// `hetcomm zenoh-router` in a build without Zenoh.
#[cfg(not(feature = "zenoh"))]
fn zenoh_router(
    _listen: &[String],
    _multicast_scouting: bool,
    _lease_ms: u32,
) -> anyhow::Result<ExitCode> {
    anyhow::bail!("this build has no Zenoh: rebuild with `--features zenoh`")
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn a_cause_the_message_already_quotes_is_written_once() {
        #[derive(Debug)]
        struct Inner;
        impl std::fmt::Display for Inner {
            fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
                f.write_str("cannot open a Zenoh client session: tcp/1.2.3.4:7447 did not answer")
            }
        }
        impl std::error::Error for Inner {}
        #[derive(Debug)]
        struct Outer(Inner);
        impl std::fmt::Display for Outer {
            fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
                write!(f, "cannot open transport `z`: {}", self.0)
            }
        }
        impl std::error::Error for Outer {
            fn source(&self) -> Option<&(dyn std::error::Error + 'static)> {
                Some(&self.0)
            }
        }
        let e = anyhow::Error::new(Outer(Inner)).context("opening Alpha");
        assert_eq!(
            chain(&e),
            "opening Alpha: cannot open transport `z`: cannot open a Zenoh client session: \
             tcp/1.2.3.4:7447 did not answer"
        );
    }
}

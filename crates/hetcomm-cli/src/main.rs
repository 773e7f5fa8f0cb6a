//! The `hetcomm` command line.

use std::path::PathBuf;
use std::process::ExitCode;
use std::time::Duration;

use clap::{Parser, Subcommand};

mod demo;
mod experiment;
mod listen;
mod names;
mod poke;

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
    /// Prints a one-line summary and exits 0, or prints every error with file:line:column and
    /// exits 2.
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
    },
    /// Print a commented example fleet file.
    GenerateConfig,
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
        /// Tango, their VEs, and modules Plan, Act, World).
        #[arg(long, conflicts_with_all = ["r", "b"])]
        fleet: Option<PathBuf>,
        /// What the table letter R means: inproc, wired, wifi, bluetooth-classic (emulated
        /// profiles), ros1, or zenoh (through a Zenoh router started in this process; needs
        /// the `zenoh` feature).
        #[arg(long, default_value = "inproc",
              value_parser = ["inproc", "wired", "wifi", "bluetooth-classic", "ros1", "zenoh"])]
        r: String,
        /// What the table letter B means: inproc, wired, wifi, bluetooth-classic (emulated
        /// profiles), bluetooth (real RFCOMM; Table 8 addresses), or zenoh (through a Zenoh
        /// router started in this process; needs the `zenoh` feature).
        #[arg(long, default_value = "bluetooth-classic",
              value_parser = ["inproc", "wired", "wifi", "bluetooth-classic", "bluetooth", "zenoh"])]
        b: String,
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
    /// Run an experiment of the thesis in virtual time (`hetcomm experiment reliability`).
    Experiment {
        #[command(subcommand)]
        experiment: experiment::Experiment,
    },
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
            eprintln!("error: {}", for_this_command(&format!("{e:#}")));
            ExitCode::FAILURE
        }
    }
}

/// The library tells a program depending on it to "rebuild with `--features ros1`"; for this
/// command that means rebuilding the `hetcomm-cli` package with its feature of that name.
fn for_this_command(message: &str) -> String {
    let mut out = message.to_string();
    for feature in ["ros1", "bluetooth", "zenoh"] {
        out = out.replace(
            &format!("rebuild with `--features {feature}`"),
            &format!(
                "rebuild this command with `cargo build --release -p hetcomm-cli --features {feature}`"
            ),
        );
    }
    out
}

fn run(command: Command) -> anyhow::Result<ExitCode> {
    match command {
        Command::Validate {
            file,
            ids,
            table,
            bluetooth,
        } => {
            let result = match (file, ids, table) {
                (Some(file), _, _) => hetcomm::load_fleet(&file),
                (None, Some(ids), Some(table)) => {
                    hetcomm::config::load_legacy(&ids, &table, bluetooth.as_deref())
                }
                _ => anyhow::bail!(
                    "give a fleet file, or --ids and --table (and optionally --bluetooth)"
                ),
            };
            match result {
                Ok(fleet) => {
                    println!("ok: {}", fleet.summary());
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
        Command::Listen {
            fleet,
            system,
            module,
            count,
            timeout,
            json,
            verbose,
            raw_times,
        } => {
            listen::listen(listen::ListenArgs {
                fleet: &fleet,
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
        } => {
            let verdict = poke::send(poke::SendArgs {
                fleet: &fleet,
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
            single_ve,
            realtime,
            external,
        } => {
            demo::run(demo::DemoArgs {
                external,
                seed,
                out: &out,
                fleet: fleet.as_deref(),
                r: &r,
                b: &b,
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

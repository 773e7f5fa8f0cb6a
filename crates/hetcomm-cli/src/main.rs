//! The `hetcomm` command line.

use std::path::PathBuf;
use std::process::ExitCode;

use clap::{Parser, Subcommand};

mod relay;

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
    /// Run systems of a fleet in this process exchanging messages: a relay chain
    /// Alpha → Charlie → Tango on the embedded fleet, or on `--fleet`.
    Demo {
        /// Fleet file to use instead of the embedded one (needs systems Alpha, Charlie,
        /// Tango and modules Plan, Act).
        #[arg(long)]
        fleet: Option<PathBuf>,
        /// Commands the leader sends.
        #[arg(long, default_value_t = 5)]
        commands: u8,
    },
}

fn main() -> ExitCode {
    let cli = Cli::parse();
    match run(cli.command) {
        Ok(code) => code,
        Err(e) => {
            eprintln!("error: {e:#}");
            ExitCode::FAILURE
        }
    }
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
                (Some(file), _, _) => hetcomm::config::load(&file),
                (None, Some(ids), Some(table)) => {
                    hetcomm::config::load_legacy(&ids, &table, bluetooth.as_deref())
                }
                _ => anyhow::bail!("give a fleet file, or --ids and --table (and optionally --bluetooth)"),
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
        Command::Demo { fleet, commands } => {
            relay::run(fleet.as_deref(), commands)?;
            Ok(ExitCode::SUCCESS)
        }
    }
}

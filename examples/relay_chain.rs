//! A relay chain across three processes: Alpha → Charlie → Tango.
//!
//! Start each system in its own terminal (any order; each waits for the next one):
//!
//! ```sh
//! cargo run -p hetcomm-examples --example relay_chain -- Tango
//! cargo run -p hetcomm-examples --example relay_chain -- Charlie
//! cargo run -p hetcomm-examples --example relay_chain -- Alpha
//! ```
//!
//! Alpha's Plan module sends five commands, one per second, to Charlie's Act module (UDP).
//! Charlie prints each one and forwards it to Tango's Act module (TCP). Tango prints them.
//! The fleet file `examples/relay_chain.toml` decides the transports and ports; give another
//! fleet file as a second argument to use other ports:
//! `relay_chain Charlie /path/to/fleet.toml`.
//!
//! The code never mentions UDP or TCP: each process opens one system of the fleet with
//! `Comm::open` and sends to friendly names.

use std::path::PathBuf;
use std::process::ExitCode;
use std::time::{Duration, Instant};

use hetcomm::{Comm, Message, Module, Outcome, RecvError};
use serde::{Deserialize, Serialize};

/// What the leader tells the team to do.
#[derive(Serialize, Deserialize, Message, Debug, Clone, PartialEq)]
#[message(id = 0)]
struct Command {
    /// 1-based position in the mission.
    number: u32,
    /// Commands in the mission.
    of: u32,
    /// What to do.
    action: String,
}

const MISSION: [&str; 5] = [
    "advance 2 m",
    "turn left",
    "advance 1 m",
    "turn right",
    "stop",
];

/// How long a follower waits for the next command, and a sender keeps retrying one command
/// while the next system is not up yet, before giving up.
const PATIENCE: Duration = Duration::from_secs(120);

/// How long a follower stays after the last command.
const LINGER: Duration = Duration::from_millis(500);

fn main() -> ExitCode {
    let mut args = std::env::args().skip(1);
    let (Some(system), fleet) = (args.next(), args.next()) else {
        eprintln!("usage: relay_chain <Alpha|Charlie|Tango> [FLEET_FILE]");
        return ExitCode::from(2);
    };
    let fleet = fleet
        .map(PathBuf::from)
        .unwrap_or_else(|| PathBuf::from(concat!(env!("CARGO_MANIFEST_DIR"), "/relay_chain.toml")));
    match run(&system, &fleet) {
        Ok(()) => ExitCode::SUCCESS,
        Err(e) => {
            eprintln!("{system}: {e}");
            ExitCode::FAILURE
        }
    }
}

fn run(system: &str, fleet: &std::path::Path) -> Result<(), Box<dyn std::error::Error>> {
    let comm = Comm::open(fleet, system)?;
    let endpoints: Vec<String> = comm
        .endpoints()
        .iter()
        .map(|(t, a)| format!("{t} {}", a.as_deref().unwrap_or("(in-process)")))
        .collect();
    println!("{system} ready on {}", endpoints.join(", "));
    match system {
        "Alpha" => alpha(&comm),
        "Charlie" => charlie(&comm),
        "Tango" => tango(&comm),
        other => Err(format!("this example runs Alpha, Charlie or Tango, not {other:?}").into()),
    }
}

/// Sends `command` until it is delivered (the next system may not be started yet).
fn deliver(
    who: &str,
    from: &Module,
    to: &str,
    command: &Command,
) -> Result<Outcome, Box<dyn std::error::Error>> {
    let give_up = Instant::now() + PATIENCE;
    loop {
        let outcome = from.send(to, "Act", command)?.wait();
        if matches!(outcome, Outcome::Delivered { .. }) || Instant::now() > give_up {
            return Ok(outcome);
        }
        eprintln!("{who}: {to} not reached yet ({outcome}); retrying");
        std::thread::sleep(Duration::from_millis(500));
    }
}

/// The leader: five commands, one per second.
fn alpha(comm: &Comm) -> Result<(), Box<dyn std::error::Error>> {
    let plan = comm.module("Plan")?;
    let of = MISSION.len() as u32;
    for (i, action) in MISSION.iter().enumerate() {
        if i > 0 {
            std::thread::sleep(Duration::from_secs(1));
        }
        let command = Command {
            number: i as u32 + 1,
            of,
            action: action.to_string(),
        };
        let outcome = deliver("Alpha", &plan, "Charlie", &command)?;
        println!(
            "Alpha: sent command {}/{of} {:?} to Charlie: {outcome}",
            command.number, command.action
        );
        if !outcome.is_success() {
            return Err(format!("command {} was not delivered", command.number).into());
        }
    }
    Ok(())
}

/// Receives commands in order until the last one; `each` handles every new one.
fn follow(
    comm: &Comm,
    mut each: impl FnMut(&Command, &str) -> Result<(), Box<dyn std::error::Error>>,
) -> Result<(), Box<dyn std::error::Error>> {
    let act = comm.module("Act")?;
    let mut last = 0;
    loop {
        let got = match act.recv_timeout::<Command>(PATIENCE) {
            Ok(got) => got,
            Err(RecvError::Timeout(_)) => {
                return Err(format!("no command for {PATIENCE:?}; giving up").into())
            }
            Err(e) => return Err(e.into()),
        };
        let command = got.message;
        // A sender that retried after a lost acknowledgement may repeat a command.
        if command.number <= last {
            continue;
        }
        last = command.number;
        let from = format!(
            "{}.{}",
            got.envelope.source_system, got.envelope.source_module
        );
        each(&command, &from)?;
        if command.number >= command.of {
            // Linger a moment before leaving, like TCP's TIME_WAIT: the acknowledgement of
            // the last command leaves on a transport thread, and if it was lost the sender
            // repeats the command, which this system's router answers again while it is open.
            while act.recv_timeout::<Command>(LINGER).is_ok() {}
            return Ok(());
        }
    }
}

/// The relay: prints each command and forwards it to Tango.
fn charlie(comm: &Comm) -> Result<(), Box<dyn std::error::Error>> {
    let plan = comm.module("Plan")?;
    follow(comm, |command, from| {
        println!(
            "Charlie: got command {}/{} {:?} from {from}; forwarding to Tango",
            command.number, command.of, command.action
        );
        let outcome = deliver("Charlie", &plan, "Tango", command)?;
        println!(
            "Charlie: forwarded command {} to Tango: {outcome}",
            command.number
        );
        if outcome.is_success() {
            Ok(())
        } else {
            Err(format!("command {} was not delivered to Tango", command.number).into())
        }
    })
}

/// The end of the chain: prints each command.
fn tango(comm: &Comm) -> Result<(), Box<dyn std::error::Error>> {
    follow(comm, |command, from| {
        println!(
            "Tango: command {}/{} {:?} (via {from})",
            command.number, command.of, command.action
        );
        Ok(())
    })
}

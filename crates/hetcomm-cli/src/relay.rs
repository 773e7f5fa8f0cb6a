//! A relay chain in one process: Alpha's Plan sends commands to Charlie's Act, which forwards
//! each to Tango's Act (the thesis's leader–follower chain, without the virtual environment).

use std::path::Path;
use std::time::Duration;

use anyhow::Context;
use hetcomm::{LocalFleet, Message, Outcome};
use serde::{Deserialize, Serialize};

/// The embedded fleet: three rovers, Alpha–Charlie and Charlie–Tango on the in-process link.
pub const FLEET: &str = r#"
name = "relay"
[systems]
Alpha = 0
Charlie = 1
Tango = 2

[modules]
Plan = 0
Act = 1

[transports.wired]
kind = "inproc"

[table]
columns = ["Alpha", "Charlie", "Tango"]
Alpha   = ["X",     "wired", "X"]
Charlie = ["wired", "X",     "wired"]
Tango   = ["X",     "wired", "X"]
"#;

/// What the leader tells followers to do (the thesis's Command message).
#[derive(Serialize, Deserialize, Message, Debug, Clone, Copy, PartialEq)]
#[message(id = 0)]
pub struct Command {
    /// 0 straight, 1 turn left, 2 stop.
    pub code: u8,
}

pub fn run(fleet: Option<&Path>, commands: u8) -> anyhow::Result<()> {
    let config = match fleet {
        Some(path) => hetcomm::config::load(path)?,
        None => hetcomm::config::parse_str(FLEET, "<embedded relay fleet>", None)?,
    };
    let fleet = LocalFleet::open(config)?;
    let leader = fleet.system("Alpha")?.module("Plan")?;
    let charlie = fleet.system("Charlie")?.module("Act")?;
    let tango = fleet.system("Tango")?.module("Act")?;

    // Charlie forwards every command it receives to Tango, from a callback.
    let forward = charlie.clone();
    charlie.on::<Command>(move |r| {
        let outcome = forward
            .send("Tango", "Act", &r.message)
            .map(|t| t.wait().to_string())
            .unwrap_or_else(|e| format!("refused: {e}"));
        println!(
            "  Charlie got {:?} from {}, forwarded: {outcome}",
            r.message, r.envelope.source_system
        );
    })?;

    println!("Alpha → Charlie → Tango, {commands} commands, in-process transport");
    for i in 0..commands {
        let command = Command { code: i % 3 };
        let outcome = leader.send("Charlie", "Act", &command)?.wait();
        println!("Alpha sent {command:?}: {outcome}");
        anyhow::ensure!(matches!(outcome, Outcome::Delivered { .. }), "send failed");
        let got = tango
            .recv_timeout::<Command>(Duration::from_secs(5))
            .context("Tango did not receive the forwarded command")?;
        println!(
            "  Tango got {:?} from {} ({} µs after Charlie forwarded it)",
            got.message,
            got.envelope.source_system,
            got.envelope
                .received_at
                .as_micros()
                .saturating_sub(got.envelope.timestamp().as_micros())
        );
    }
    let stats = fleet.system("Charlie")?.stats().router;
    println!(
        "Charlie: {} sends, {} delivered, {} failed, {} received",
        stats.sends, stats.delivered, stats.failed, stats.received
    );
    Ok(())
}

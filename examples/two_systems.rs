//! Two systems exchanging two user-defined message types, in one process.
//!
//! Run with `cargo run -p hetcomm-examples --example two_systems`.
//!
//! An autonomy developer writes only this: message types as plain structs with a derive, and
//! module code that sends and receives them. Which transport carries the messages is the fleet
//! file's business: change `kind = "inproc"` to `udp` (with endpoints) and nothing here
//! changes.

use std::time::Duration;

use hetcomm::{LocalFleet, Message, Outcome, SendOptions};
use serde::{Deserialize, Serialize};

/// The leader tells a follower what to do.
#[derive(Serialize, Deserialize, Message, Debug, Clone, Copy, PartialEq)]
#[message(id = 0)]
enum Command {
    Straight,
    TurnLeft,
    Stop,
}

/// A rover reports its wheel speeds.
#[derive(Serialize, Deserialize, Message, Debug, Clone, Copy, PartialEq)]
#[message(id = 1)]
struct Wheels {
    left: f64,
    right: f64,
}

const FLEET: &str = r#"
[systems]
Leader = 0
Follower = 1

[modules]
Plan = 0
Act = 1

[transports.wired]
kind = "inproc"

[table]
columns = ["Leader", "Follower"]
Leader   = ["X",     "wired"]
Follower = ["wired", "X"]
"#;

fn main() -> Result<(), Box<dyn std::error::Error>> {
    let fleet = hetcomm::config::parse_str(FLEET, "two_systems.toml", None)?;
    let fleet = LocalFleet::open(fleet)?;

    let leader_plan = fleet.system("Leader")?.module("Plan")?;
    let follower_act = fleet.system("Follower")?.module("Act")?;

    // The follower's Act module: answer every command with its new wheel speeds (callback
    // style: runs on the module's callback thread as each command arrives).
    let act = follower_act.clone();
    follower_act.on::<Command>(move |received| {
        let (left, right) = match received.message {
            Command::Straight => (1.0, 1.0),
            Command::TurnLeft => (-10.0, 10.0),
            Command::Stop => (0.0, 0.0),
        };
        println!(
            "Follower.Act got {:?} from {}.{}",
            received.message, received.envelope.source_system, received.envelope.source_module
        );
        if let Err(e) = act.send("Leader", "Plan", &Wheels { left, right }) {
            eprintln!("could not answer: {e}");
        }
    })?;

    // The leader's Plan module: send commands, wait for each outcome, poll for the answers.
    for command in [Command::Straight, Command::TurnLeft, Command::Stop] {
        let outcome = leader_plan
            .send_with("Follower", "Act", &command, SendOptions::priority(200))?
            .wait();
        println!("Leader.Plan sent {command:?}: {outcome}");
        assert!(matches!(outcome, Outcome::Delivered { .. }));
        let wheels = leader_plan.recv_timeout::<Wheels>(Duration::from_secs(5))?;
        println!("Leader.Plan got {:?}", wheels.message);
    }
    Ok(())
}

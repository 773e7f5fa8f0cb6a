//! Two systems of the leader–follower fleet: Alpha's Plan tells Charlie's Act what to do.

use hetcomm::{LocalFleet, Message};
use serde::{Deserialize, Serialize};

#[derive(Serialize, Deserialize, Message)]
#[message(id = 0)]
struct Command {
    code: u8,
}

fn main() -> Result<(), Box<dyn std::error::Error>> {
    // Every system of the fleet in this process; one robot opens only itself with
    // hetcomm::Comm::open("fleet.toml", "Alpha").
    let fleet = LocalFleet::open_file("examples/leader_follower/fleet.toml")?;
    let plan = fleet.system("Alpha")?.module("Plan")?;
    let outcome = plan.send("Charlie", "Act", &Command { code: 1 })?.wait();
    println!("{outcome}"); // "delivered to the inbox (attempts: 1, …)": not necessarily read
    let act = fleet.system("Charlie")?.module("Act")?;
    let got = act.recv::<Command>()?; // or try_recv, recv_timeout, on::<Command>(callback)
    println!("Charlie.Act got code {}", got.message.code);
    Ok(())
}

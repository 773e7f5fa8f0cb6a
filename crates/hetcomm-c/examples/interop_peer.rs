//! The Rust side of the C/C++ interop tests (`tests/native`, run by ctest): system `Peer` of
//! the fleet `tests/native/fleet.toml.in` receives a `Sample` from the C++ system `Cpp`,
//! checks that its bytes are exactly what Rust writes for the same value, and sends back a
//! changed `Sample`, acknowledged; it exits 0 only if that send was delivered.
//!
//! ```text
//! cargo run -p hetcomm-c --example interop_peer -- FLEET
//! ```

use std::process::ExitCode;
use std::time::Duration;

use hetcomm::{payload, Comm, Message, Outcome};
use serde::{Deserialize, Serialize};

/// The message the tests exchange: the same fields and id as the C++ `Sample` of
/// `tests/native/interop.cpp` and the Python one of `tests/native/interop_peer.py`.
#[derive(Serialize, Deserialize, Message, Debug, Clone, PartialEq)]
#[message(id = 7)]
struct Sample {
    name: String,
    x: f64,
    count: i64,
    values: Vec<u32>,
    ok: bool,
}

fn run(fleet: &str) -> Result<(), String> {
    let comm = Comm::open(fleet, "Peer").map_err(|e| e.to_string())?;
    let m = comm.module("M").map_err(|e| e.to_string())?;
    println!("ready");
    let raw = m
        .recv_raw_timeout(Some(Duration::from_secs(20)))
        .map_err(|e| format!("no message from C++: {e}"))?;
    if raw.envelope.message_type() != Sample::TYPE {
        return Err(format!(
            "type {} from C++, expected {}",
            raw.envelope.message_type(),
            Sample::TYPE
        ));
    }
    let got: Sample = payload::decode(&raw.payload).map_err(|e| e.to_string())?;
    println!("peer: got {got:?} from {}", raw.envelope.source_system);
    let ours = payload::encode(&got).map_err(|e| e.to_string())?;
    if ours[..] != raw.payload[..] {
        return Err(format!(
            "C++ wrote {:02x?}, Rust writes {ours:02x?} for the same value",
            &raw.payload[..]
        ));
    }
    println!("peer: bytes identical to Rust's encoding");
    let mut values = got.values.clone();
    values.push(values.len() as u32);
    let reply = Sample {
        name: format!("{} back", got.name),
        x: got.x * 2.0,
        count: got.count - 1,
        values,
        ok: !got.ok,
    };
    let outcome = m
        .send("Cpp", "M", &reply)
        .map_err(|e| e.to_string())?
        .wait();
    println!("peer: reply {outcome}");
    match outcome {
        Outcome::Delivered { .. } => Ok(()),
        other => Err(format!("reply not delivered: {other}")),
    }
}

fn main() -> ExitCode {
    let Some(fleet) = std::env::args().nth(1) else {
        eprintln!("usage: interop_peer FLEET");
        return ExitCode::from(2);
    };
    match run(&fleet) {
        Ok(()) => ExitCode::SUCCESS,
        Err(e) => {
            eprintln!("peer: {e}");
            ExitCode::FAILURE
        }
    }
}

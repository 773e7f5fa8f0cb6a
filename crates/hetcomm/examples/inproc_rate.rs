//! Quick in-process hand-off figures: `cargo run --release -p hetcomm --example inproc_rate`.
//! The benchmark suite (`hetcomm bench`) is the reference; this is a developer's probe.
//! It measures the send side alone (queueing into a large inbox), then a sender and a
//! receiver running at the same time on two threads.

use std::time::Instant;

use hetcomm::{LocalFleet, Message};
use serde::{Deserialize, Serialize};

#[derive(Serialize, Deserialize, Message)]
#[message(id = 1)]
struct Small {
    a: u32,
}

fn fleet(delivery: &str) -> LocalFleet {
    let text = format!(
        r#"
[systems]
A = 0
B = 1
[modules]
M = 0
[inbox]
capacity = 2000000
[transports.t]
kind = "inproc"
delivery = "{delivery}"
[table]
columns = ["A", "B"]
A = ["X", "t"]
B = ["t", "X"]
"#
    );
    LocalFleet::open(hetcomm::config::parse_str(&text, "probe.toml", None).unwrap()).unwrap()
}

fn main() {
    let n: u32 = std::env::var("N")
        .ok()
        .and_then(|s| s.parse().ok())
        .unwrap_or(1_000_000);
    for delivery in ["unacknowledged", "acknowledged"] {
        let f = fleet(delivery);
        let a = f.system("A").unwrap().module("M").unwrap();
        let b = f.system("B").unwrap().module("M").unwrap();
        let to_b = a.sender::<Small>("B", "M").unwrap();
        let start = Instant::now();
        for i in 0..n {
            let _ = to_b.send(&Small { a: i }).unwrap();
        }
        let sent = start.elapsed();
        let mut got = 0;
        while b.try_recv::<Small>().unwrap().is_some() {
            got += 1;
        }
        println!(
            "{delivery}, send through a Sender, then drain: send side {:.0} ns/msg ({:.2} M msg/s); received {got}",
            sent.as_nanos() as f64 / n as f64,
            n as f64 / sent.as_secs_f64() / 1e6,
        );

        let receiver = std::thread::spawn(move || {
            let mut got = 0u32;
            while got < n {
                if b.recv_timeout::<Small>(std::time::Duration::from_secs(2))
                    .is_err()
                {
                    break;
                }
                got += 1;
            }
            got
        });
        let start = Instant::now();
        for i in 0..n {
            let _ = to_b.send(&Small { a: i }).unwrap();
        }
        let got = receiver.join().unwrap();
        let total = start.elapsed();
        println!(
            "{delivery}, concurrent through a Sender: received {got} in {:.3} s = {:.2} M msg/s",
            total.as_secs_f64(),
            got as f64 / total.as_secs_f64() / 1e6
        );
    }
}

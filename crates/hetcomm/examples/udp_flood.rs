//! A developer's probe of the 64-byte UDP path in one process (two systems, real sockets):
//! `cargo run --release -p hetcomm --example udp_flood`. `hetcomm-bench` is the reference.

use std::time::{Duration, Instant};

use hetcomm::LocalFleet;

fn main() {
    let port = |()| {
        std::net::UdpSocket::bind("127.0.0.1:0")
            .and_then(|s| s.local_addr())
            .map(|a| a.port())
            .expect("a free port")
    };
    let (pa, pb) = (port(()), port(()));
    let text = format!(
        r#"
[systems]
A = 0
B = 1
[modules]
M = 0
[inbox]
capacity = 1000000
[transports.t]
kind = "udp"
delivery = "unacknowledged"
endpoints = {{ A = "127.0.0.1:{pa}", B = "127.0.0.1:{pb}" }}
[table]
columns = ["A", "B"]
A = ["X", "t"]
B = ["t", "X"]
"#
    );
    let fleet = LocalFleet::open(hetcomm::config::parse_str(&text, "flood.toml", None).unwrap())
        .expect("fleet opens");
    let a = fleet.system("A").unwrap().module("M").unwrap();
    let b = fleet.system("B").unwrap().module("M").unwrap();
    let receiver = std::thread::spawn(move || {
        let mut n = 0u64;
        while b.recv_raw_timeout(Some(Duration::from_millis(200))).is_ok() {
            n += 1;
        }
        n
    });
    let msg = [7u8; 64];
    let secs: f64 = std::env::var("SECS")
        .ok()
        .and_then(|s| s.parse().ok())
        .unwrap_or(2.0);
    let start = Instant::now();
    let mut sent = 0u64;
    while start.elapsed().as_secs_f64() < secs {
        for _ in 0..64 {
            let _ = a.send_raw("B", "M", hetcomm::MessageType(1), &msg, Default::default());
            sent += 1;
        }
    }
    let took = start.elapsed().as_secs_f64();
    let got = receiver.join().unwrap();
    println!(
        "sent {sent} ({:.2} M/s), received {got} ({:.2} M/s over the sending time)",
        sent as f64 / took / 1e6,
        got as f64 / took / 1e6
    );
}

//! Router micro-benchmark: one message through two sans-IO routers — `send`,
//! `poll_transmit`, `handle_frame` at the destination, `poll_delivery` — with 10, 100 and
//! 1000 systems in the sender's route table, unacknowledged and acknowledged (the ack goes
//! back and is handled too).
//!
//! `cargo bench -p hetcomm-bench --bench router`

// criterion_group! makes public functions it cannot document; benches are no API.
#![allow(missing_docs)]

use criterion::{black_box, criterion_group, criterion_main, BenchmarkId, Criterion};
use hetcomm::wire::AckStatus;
use hetcomm::{Address, MessageType, ModuleId, SystemId, Time};
use hetcomm_router::{Route, Router, RouterConfig, SendRequest};

fn route(acknowledged: bool) -> Route {
    Route {
        link: 0,
        tag: b'R',
        acknowledged,
        attempts: 3,
        max_frame: 1 << 20,
        max_in_flight: 1024,
        max_in_flight_bytes: usize::MAX,
    }
}

fn pair(n: u16, acknowledged: bool) -> (Router<u32>, Router<u32>) {
    let routes = (1..n).map(|s| (SystemId(s), route(acknowledged))).collect();
    let a = Router::new(RouterConfig::new(SystemId(0), 1, routes));
    let mut bcfg = RouterConfig::new(SystemId(1), 2, vec![(SystemId(0), route(acknowledged))]);
    bcfg.known_systems = (0..n).map(SystemId).collect();
    let b = Router::new(bcfg);
    (a, b)
}

fn round(c: &mut Criterion) {
    let mut g = c.benchmark_group("router round");
    let payload = [7u8; 64];
    for acknowledged in [false, true] {
        for n in [10u16, 100, 1000] {
            let (mut a, mut b) = pair(n, acknowledged);
            let mut now = 0u64;
            let id = BenchmarkId::new(if acknowledged { "ack" } else { "unack" }, n);
            g.bench_function(id, |bench| {
                bench.iter(|| {
                    now += 10;
                    let t = Time(now);
                    let req = SendRequest::new(
                        ModuleId(0),
                        Address {
                            system: SystemId(1),
                            module: ModuleId(0),
                        },
                        MessageType(1),
                        &payload,
                    );
                    let _ = a.send(t, req, 0);
                    while let Some(tx) = a.poll_transmit(t) {
                        b.handle_frame(t, 0, &tx.frame);
                        a.transmit_result(t, tx, Ok(()));
                    }
                    while let Some(d) = b.poll_delivery() {
                        black_box(d.payload.len());
                        if let Some(token) = d.token {
                            b.delivery_result(t, token, AckStatus::Delivered);
                        }
                    }
                    while let Some(tx) = b.poll_transmit(t) {
                        a.handle_frame(t, 0, &tx.frame);
                    }
                    while a.poll_event().is_some() {}
                })
            });
        }
    }
    g.finish();
}

criterion_group!(benches, round);
criterion_main!(benches);

//! What the harness costs in process: 64-byte messages from one system to another over an
//! in-process route (send, then take from the inbox), with no tap, with an observe-only tap on
//! the path, and with a tap on another path of the receiving system; and a topic value
//! published to one subscriber, without and with an observe-only tap.
//!
//! `cargo bench -p hetcomm-bench --bench harness`. These cases run one after the other and
//! moved by up to 170 ns between runs on the shared development VM, more than the costs they
//! compare: the issue's targets are verified by `hetcomm-bench --only harness` instead
//! (`crates/hetcomm-bench/src/harness_cost.rs`: interleaved rounds, thread CPU time, paired
//! ratios), which `benchmarks/run.sh` reports.

// criterion_group! makes public functions it cannot document; benches are no API.
#![allow(missing_docs)]

use std::sync::atomic::{AtomicU64, Ordering};
use std::sync::Arc;

use criterion::{black_box, criterion_group, criterion_main, Criterion};
use hetcomm::{LocalFleet, Message, MessageType, SendOptions, TapAction, TapPath};
use serde::{Deserialize, Serialize};

const FLEET: &str = r#"
[systems]
A = 0
B = 1
[modules]
Plan = 0
Act = 1
[transports.net]
kind = "inproc"
[table]
columns = ["A", "B"]
A = ["X", "net"]
B = ["net", "X"]
"#;

#[derive(Serialize, Deserialize, Message, Clone)]
#[message(id = 70)]
struct Value {
    bytes: Vec<u8>,
}

fn messages(c: &mut Criterion) {
    let fleet = LocalFleet::open(hetcomm::parse_fleet(FLEET, "bench.toml", None).unwrap()).unwrap();
    let a = fleet.system("A").unwrap();
    let b = fleet.system("B").unwrap();
    let sender = a
        .module("Plan")
        .unwrap()
        .raw_sender("B", "Act", MessageType(70))
        .unwrap();
    let act = b.module("Act").unwrap();
    let payload = [7u8; 64];
    let mut g = c.benchmark_group("harness 64 B in process");
    let one = |g: &mut criterion::BenchmarkGroup<'_, _>, name: &str| {
        g.bench_function(name, |bench| {
            bench.iter(|| {
                let t = sender
                    .send(black_box(&payload), SendOptions::default())
                    .unwrap();
                black_box(t);
                black_box(act.try_recv_raw().unwrap());
            })
        });
    };
    one(&mut g, "no tap");
    let seen = Arc::new(AtomicU64::new(0));
    let s = seen.clone();
    let tap = b
        .tap(
            &TapPath::messages("B").from("A").module("Act"),
            TapAction::observe(move |_| {
                s.fetch_add(1, Ordering::Relaxed);
            }),
        )
        .unwrap();
    one(&mut g, "observe tap");
    drop(tap);
    let other = b
        .tap(&TapPath::messages("B").module("Plan"), TapAction::Drop)
        .unwrap();
    one(&mut g, "tap on another path");
    drop(other);
    one(&mut g, "no tap again");
    g.finish();
    assert!(seen.load(Ordering::Relaxed) > 0);
}

fn topics(c: &mut Criterion) {
    let fleet = LocalFleet::open(hetcomm::parse_fleet(FLEET, "bench.toml", None).unwrap()).unwrap();
    let b = fleet.system("B").unwrap();
    let publisher = b.node("Plan").unwrap().advertise::<Value>("v").unwrap();
    let sub = b.node("Act").unwrap().subscribe::<Value>("v").unwrap();
    let value = Arc::new(Value { bytes: vec![7; 64] });
    let mut g = c.benchmark_group("harness topic value");
    g.bench_function("no tap", |bench| {
        bench.iter(|| {
            publisher.publish_arc(value.clone()).unwrap();
            black_box(sub.try_recv().unwrap());
        })
    });
    let _tap = b
        .tap(
            &TapPath::topic("B", "v"),
            TapAction::observe(|m| {
                black_box(m.topic());
            }),
        )
        .unwrap();
    g.bench_function("observe tap", |bench| {
        bench.iter(|| {
            publisher.publish_arc(value.clone()).unwrap();
            black_box(sub.try_recv().unwrap());
        })
    });
    g.finish();
}

criterion_group!(benches, messages, topics);
criterion_main!(benches);

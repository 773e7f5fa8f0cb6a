//! Codec micro-benchmarks: frame encode/decode (`hetcomm::wire`) at 64 B and 64 KiB, and
//! payload encode/decode of a small struct (`hetcomm::payload`).
//!
//! `cargo bench -p hetcomm-bench --bench codec`

// criterion_group! makes public functions it cannot document; benches are no API.
#![allow(missing_docs)]

use criterion::{black_box, criterion_group, criterion_main, BenchmarkId, Criterion, Throughput};
use hetcomm::{payload, wire, Address, Header, MessageType, ModuleId, SystemId};
use serde::{Deserialize, Serialize};

/// A small message, like a wheel-speed command.
#[derive(Serialize, Deserialize, Debug, PartialEq)]
struct Wheels {
    code: u8,
    left: f64,
    right: f64,
    seq: u32,
}

fn header() -> Header {
    let mut h = Header::data(
        Address {
            system: SystemId(1),
            module: ModuleId(2),
        },
        Address {
            system: SystemId(3),
            module: ModuleId(4),
        },
        MessageType(7),
    );
    h.seq = 42;
    h.incarnation = 0x1234_5678;
    h
}

fn frames(c: &mut Criterion) {
    let mut g = c.benchmark_group("wire");
    for size in [64usize, 64 * 1024] {
        let payload = vec![0xabu8; size];
        let h = header();
        g.throughput(Throughput::Bytes(size as u64));
        g.bench_with_input(BenchmarkId::new("encode", size), &payload, |b, p| {
            b.iter(|| wire::encode(black_box(&h), black_box(p)))
        });
        let frame = wire::encode(&h, &payload);
        g.bench_with_input(BenchmarkId::new("decode", size), &frame, |b, f| {
            b.iter(|| wire::decode(black_box(f)).map(|fr| fr.payload.len()))
        });
    }
    g.finish();
}

fn payloads(c: &mut Criterion) {
    let mut g = c.benchmark_group("payload");
    let msg = Wheels {
        code: 3,
        left: 0.25,
        right: -0.25,
        seq: 99,
    };
    g.bench_function("encode small struct", |b| {
        b.iter(|| payload::encode(black_box(&msg)))
    });
    let bytes = payload::encode(&msg).unwrap_or_default();
    g.bench_function("decode small struct", |b| {
        b.iter(|| payload::decode::<Wheels>(black_box(&bytes)))
    });
    g.finish();
}

criterion_group!(benches, frames, payloads);
criterion_main!(benches);

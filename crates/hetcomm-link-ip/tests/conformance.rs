//! The shared conformance suite, run against every transport of this crate, bare and wrapped
//! in emulation (a model that changes nothing: what is checked is that the wrapping keeps
//! everything the link offers). The driven configurations run in `stream_driven.rs` and
//! `udp_batch.rs`.

mod common;

use std::collections::{HashMap, HashSet};
use std::sync::Arc;

use common::{TcpHarness, UdpHarness, UnixHarness};
use hetcomm_core::SystemId;
use hetcomm_link::conformance::{self, Layered};
use hetcomm_link::layer::LayerStack;
use hetcomm_link_ip::stream::StreamConfig;
use hetcomm_link_ip::UdpConfig;

#[test]
fn tcp_passes_conformance() {
    conformance::run_all(&mut TcpHarness::new(StreamConfig::default()));
}

#[test]
fn udp_passes_conformance_with_ethernet_sized_datagrams() {
    conformance::run_all(&mut UdpHarness::new(UdpConfig::default()));
}

#[test]
fn udp_passes_conformance_with_loopback_sized_datagrams() {
    conformance::run_all(&mut UdpHarness::new(UdpConfig::loopback()));
}

#[test]
fn unix_stream_layer_passes_conformance() {
    conformance::run_all(&mut UnixHarness::new(StreamConfig::default()));
}

#[test]
fn tcp_wrapped_in_emulation_passes_conformance() {
    conformance::run_all(&mut Layered::emulated(TcpHarness::new(
        StreamConfig::default(),
    )));
}

#[test]
fn udp_wrapped_in_emulation_passes_conformance() {
    conformance::run_all(&mut Layered::emulated(
        UdpHarness::new(UdpConfig::default()),
    ));
    conformance::run_all(&mut Layered::emulated(UdpHarness::new(
        UdpConfig::loopback(),
    )));
}

#[test]
fn unix_stream_layer_wrapped_in_emulation_passes_conformance() {
    conformance::run_all(&mut Layered::emulated(UnixHarness::new(
        StreamConfig::default(),
    )));
}

/// The security layer over a link, per system (each with its own keys and sessions), for
/// systems 0–9 that all know each other's public keys and may all talk.
fn secured<H: conformance::Harness>(
    inner: H,
) -> conformance::LayeredPerSystem<H, impl FnMut(SystemId) -> LayerStack> {
    use hetcomm_security::{Handshakes, Keypair, Policy, SecurityLayer};
    let keys: HashMap<SystemId, Keypair> = (0..10)
        .map(|i| (SystemId(i), Keypair::generate().expect("a key")))
        .collect();
    conformance::LayeredPerSystem {
        inner,
        make: move |id: SystemId| {
            let all: HashSet<SystemId> = keys.keys().copied().collect();
            let policy = Policy {
                local: id,
                keypair: keys[&id].clone(),
                peers: keys.iter().map(|(&s, k)| (s, k.public)).collect(),
                data_from: all.clone(),
                acks_from: all,
            };
            LayerStack::new().with(Arc::new(SecurityLayer::new(
                "conformance",
                policy,
                Handshakes::OverTheLink,
            )))
        },
    }
}

#[test]
fn udp_secured_passes_conformance() {
    conformance::run_all(&mut secured(UdpHarness::new(UdpConfig::default())));
    conformance::run_all(&mut secured(UdpHarness::new(UdpConfig::loopback())));
}

#[test]
fn tcp_secured_passes_conformance() {
    conformance::run_all(&mut secured(TcpHarness::new(StreamConfig::default())));
}

#[test]
fn unix_stream_secured_passes_conformance() {
    conformance::run_all(&mut secured(UnixHarness::new(StreamConfig::default())));
}

//! The shared conformance suite, run against every transport of this crate, bare and wrapped
//! in emulation (a model that changes nothing: what is checked is that the wrapping keeps
//! everything the link offers). The driven configurations run in `stream_driven.rs` and
//! `udp_batch.rs`.

mod common;

use common::{TcpHarness, UdpHarness, UnixHarness};
use hetcomm_core::SystemId;
use hetcomm_link::conformance::{self, Layered};
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

/// Systems 0–9 under security layers that all know each other.
fn secured<H: conformance::Harness>(inner: H) -> impl conformance::Harness {
    hetcomm_security::conformance::secured(inner, (0..10).map(SystemId))
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

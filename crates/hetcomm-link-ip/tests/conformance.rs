//! The shared conformance suite, run against every transport of this crate.

mod common;

use common::{TcpHarness, UdpHarness, UnixHarness};
use hetcomm_link::conformance;
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

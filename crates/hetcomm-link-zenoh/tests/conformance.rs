//! The shared conformance suite on `zenoh` links: peer to peer (no router), and as clients of
//! a Zenoh router; each bare and wrapped in emulation.

mod common;

use common::ZenohHarness;
use hetcomm_link::conformance::{self, Layered};

#[test]
fn zenoh_peers_pass_conformance() {
    conformance::run_all(&mut ZenohHarness::peers());
}

#[test]
fn zenoh_clients_of_a_router_pass_conformance() {
    conformance::run_all(&mut ZenohHarness::clients());
}

#[test]
fn zenoh_peers_wrapped_in_emulation_pass_conformance() {
    conformance::run_all(&mut Layered::emulated(ZenohHarness::peers()));
}

#[test]
fn zenoh_clients_wrapped_in_emulation_pass_conformance() {
    conformance::run_all(&mut Layered::emulated(ZenohHarness::clients()));
}

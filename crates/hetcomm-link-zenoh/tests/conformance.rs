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

/// Clients of a router, each link under the security layer (a Noise handshake per pair over
/// Zenoh puts, every frame sealed), as a secured `zenoh` transport opens it.
#[test]
fn zenoh_clients_of_a_router_pass_conformance_secured() {
    conformance::run_all(&mut hetcomm_security::conformance::secured(
        ZenohHarness::clients(),
        [hetcomm::SystemId(1), hetcomm::SystemId(2)],
    ));
}

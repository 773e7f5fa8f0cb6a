//! The shared conformance suite on `shm` links, bare and wrapped in emulation.

mod common;

use common::ShmHarness;
use hetcomm_link::conformance::{self, Layered};

#[test]
fn shm_passes_conformance() {
    conformance::run_all(&mut ShmHarness::new());
}

#[test]
fn shm_wrapped_in_emulation_passes_conformance() {
    conformance::run_all(&mut Layered::emulated(ShmHarness::new()));
}

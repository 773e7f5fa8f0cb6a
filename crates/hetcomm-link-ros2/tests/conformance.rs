//! The shared link conformance suite on `ros2` links (each system its own DDS participant, on
//! loopback, discovered without multicast), bare and wrapped in emulation, each with a receive
//! thread of the link's own and read through `Link::readable` (as the runtime opens them).

use std::sync::Arc;

use hetcomm_core::SystemId;
use hetcomm_link::conformance::{self, Harness, Layered};
use hetcomm_link::{FrameSink, Link};
use hetcomm_link_ros2::{Ros2Link, Ros2Settings};

/// Opens `ros2` links for systems A (1) and B (2) on a domain and namespace of their own, so
/// that tests running at the same time (here or in another process) do not meet.
struct Ros2Harness {
    settings: Ros2Settings,
    names: Vec<(SystemId, String)>,
    /// Links read through `Link::readable` (as the runtime opens them), not a thread.
    driven: bool,
}

impl Ros2Harness {
    fn new(domain_id: u16) -> Ros2Harness {
        Ros2Harness {
            settings: Ros2Settings {
                domain_id,
                namespace: format!("/conformance_{}", std::process::id()),
                ..Ros2Settings::default()
            },
            names: vec![(SystemId(1), "A".into()), (SystemId(2), "B".into())],
            driven: false,
        }
    }

    fn driven(domain_id: u16) -> Ros2Harness {
        Ros2Harness {
            driven: true,
            ..Ros2Harness::new(domain_id)
        }
    }
}

impl Harness for Ros2Harness {
    fn open(&mut self, system: SystemId, sink: Arc<dyn FrameSink>) -> Box<dyn Link> {
        let link = match self.driven {
            true => Ros2Link::open_driven(system, &self.names, &self.settings, sink),
            false => Ros2Link::open(system, &self.names, &self.settings, sink),
        };
        Box::new(link.expect("open ros2 link"))
    }
}

#[test]
fn ros2_links_pass_conformance() {
    conformance::run_all(&mut Ros2Harness::new(61));
}

#[test]
fn ros2_links_wrapped_in_emulation_pass_conformance() {
    conformance::run_all(&mut Layered::emulated(Ros2Harness::new(62)));
}

#[test]
fn driven_ros2_links_pass_conformance() {
    conformance::run_all(&mut Ros2Harness::driven(67));
}

#[test]
fn driven_ros2_links_wrapped_in_emulation_pass_conformance() {
    conformance::run_all(&mut Layered::emulated(Ros2Harness::driven(68)));
}

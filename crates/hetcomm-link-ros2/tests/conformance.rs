//! The shared link conformance suite on `ros2` links (each system its own DDS participant, on
//! loopback, discovered without multicast), bare and wrapped in emulation, each with a receive
//! thread of the link's own and read through `Link::readable` (as the runtime opens them); on
//! rustdds, and on Cyclone DDS with the `cyclone` feature (there the two systems of one
//! process share Cyclone's instance of the domain).

use std::sync::Arc;

use hetcomm_core::SystemId;
use hetcomm_link::conformance::{self, Harness, Layered};
use hetcomm_link::{FrameSink, Link};
use hetcomm_link_ros2::factory::open_link;
use hetcomm_link_ros2::{Backend, Ros2Settings};

/// Opens `ros2` links for systems A (1) and B (2) on a domain and namespace of their own, so
/// that tests running at the same time (here or in another process) do not meet.
struct Ros2Harness {
    settings: Ros2Settings,
    names: Vec<(SystemId, String)>,
    /// Links read through `Link::readable` (as the runtime opens them), not a thread.
    driven: bool,
}

impl Ros2Harness {
    fn new(dds: Backend, domain_id: u16, driven: bool) -> Ros2Harness {
        Ros2Harness {
            settings: Ros2Settings {
                domain_id,
                namespace: format!("/conformance_{}", std::process::id()),
                dds,
                ..Ros2Settings::default()
            },
            names: vec![(SystemId(1), "A".into()), (SystemId(2), "B".into())],
            driven,
        }
    }
}

impl Harness for Ros2Harness {
    fn open(&mut self, system: SystemId, sink: Arc<dyn FrameSink>) -> Box<dyn Link> {
        open_link(system, &self.names, &self.settings, sink, self.driven).expect("open ros2 link")
    }
}

/// The four runs (thread / driven, bare / emulated) for one backend, each on its domain.
macro_rules! conformance_tests {
    ($backend:ident, $dds:expr, $domains:expr) => {
        mod $backend {
            use super::*;

            #[test]
            fn links_pass_conformance() {
                conformance::run_all(&mut Ros2Harness::new($dds, $domains[0], false));
            }

            #[test]
            fn links_wrapped_in_emulation_pass_conformance() {
                let h = Ros2Harness::new($dds, $domains[1], false);
                conformance::run_all(&mut Layered::emulated(h));
            }

            #[test]
            fn driven_links_pass_conformance() {
                conformance::run_all(&mut Ros2Harness::new($dds, $domains[2], true));
            }

            #[test]
            fn driven_links_wrapped_in_emulation_pass_conformance() {
                let h = Ros2Harness::new($dds, $domains[3], true);
                conformance::run_all(&mut Layered::emulated(h));
            }
        }
    };
}

conformance_tests!(rustdds, Backend::RustDds, [61, 62, 67, 68]);
#[cfg(feature = "cyclone")]
conformance_tests!(cyclone, Backend::Cyclone, [71, 72, 73, 74]);

/// Cyclone DDS links whose listeners deliver (`deliver_on_receive_thread`), driven as the
/// runtime opens them: frames a listener could not deliver (nested in another listener) are
/// read through `Link::readable`.
#[cfg(feature = "cyclone")]
#[test]
fn cyclone_links_delivering_on_the_receive_thread_pass_conformance() {
    let mut h = Ros2Harness::new(Backend::Cyclone, 83, true);
    h.settings.deliver_on_receive_thread = true;
    conformance::run_all(&mut h);
}

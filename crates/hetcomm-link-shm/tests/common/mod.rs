//! What the `shm` tests share: links between systems of a fleet with a name of its own (so
//! that tests running at once, and leftovers of earlier runs, never meet).

#![allow(dead_code)]

use std::sync::atomic::{AtomicU32, Ordering};
use std::sync::Arc;

use hetcomm_core::SystemId;
use hetcomm_link::conformance::Harness;
use hetcomm_link::{FrameSink, Link};
use hetcomm_link_shm::{ShmLink, ShmLinkConfig, ShmSettings};

/// A fleet name no other test (in this run or an earlier one) uses.
pub fn unique_fleet(what: &str) -> String {
    static N: AtomicU32 = AtomicU32::new(0);
    let nanos = std::time::SystemTime::now()
        .duration_since(std::time::UNIX_EPOCH)
        .map(|d| d.subsec_nanos())
        .unwrap_or(0);
    format!(
        "t-{what}-{}-{}-{nanos}",
        std::process::id(),
        N.fetch_add(1, Ordering::Relaxed)
    )
}

/// The link config of `local` among systems 1 and 2 (`A`, `B`) and 3 (`C`).
pub fn config(fleet: &str, local: SystemId, settings: ShmSettings) -> ShmLinkConfig {
    ShmLinkConfig {
        local,
        systems: vec![
            (SystemId(1), "A".into()),
            (SystemId(2), "B".into()),
            (SystemId(3), "C".into()),
        ],
        fleet: fleet.into(),
        settings,
    }
}

/// Opens `shm` links of one fleet for the conformance suite.
pub struct ShmHarness {
    pub fleet: String,
    pub settings: ShmSettings,
}

impl ShmHarness {
    pub fn new() -> ShmHarness {
        ShmHarness {
            fleet: unique_fleet("conf"),
            settings: ShmSettings::default(),
        }
    }
}

impl Harness for ShmHarness {
    fn open(&mut self, system: SystemId, sink: Arc<dyn FrameSink>) -> Box<dyn Link> {
        let link = ShmLink::open(config(&self.fleet, system, self.settings.clone()), sink)
            .unwrap_or_else(|e| panic!("open shm link for {system}: {e}"));
        Box::new(link)
    }
}

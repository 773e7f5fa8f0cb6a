//! Shared by the tests: Zenoh links for systems 1, 2 and 999 on loopback, peer-to-peer or as
//! clients of a router started in the test process.

#![allow(dead_code)]

use std::collections::HashMap;
use std::sync::atomic::{AtomicU32, Ordering};
use std::sync::Arc;

use hetcomm_core::SystemId;
use hetcomm_link::conformance::Harness;
use hetcomm_link::{FrameSink, Link};
use hetcomm_link_zenoh::router::ZenohRouter;
use hetcomm_link_zenoh::{Mode, ZenohLink, ZenohLinkConfig, ZenohSettings};

/// A free TCP port on 127.0.0.1 (bound, read, released).
pub fn free_port() -> u16 {
    std::net::TcpListener::bind("127.0.0.1:0")
        .and_then(|l| l.local_addr())
        .map(|a| a.port())
        .expect("bind 127.0.0.1:0")
}

/// A key-expression prefix no other test of this process uses.
pub fn unique_prefix() -> String {
    static N: AtomicU32 = AtomicU32::new(0);
    format!(
        "hetcomm-test/{}-{}",
        std::process::id(),
        N.fetch_add(1, Ordering::Relaxed)
    )
}

/// Names for the systems the conformance suite uses (1 and 2) and a few more.
pub fn systems() -> HashMap<SystemId, String> {
    (1..=8).map(|i| (SystemId(i), format!("S{i}"))).collect()
}

/// A router on a free loopback port, multicast scouting off.
pub fn router() -> (ZenohRouter, String) {
    let endpoint = format!("tcp/127.0.0.1:{}", free_port());
    let router = ZenohRouter::start(std::slice::from_ref(&endpoint), false).expect("router");
    (router, endpoint)
}

/// Opens links the conformance suite asks for.
pub struct ZenohHarness {
    mode: Mode,
    prefix: String,
    /// Client mode: the router's endpoint.
    router_endpoint: Option<String>,
    /// Peer mode: where system 1 listens now (the others connect there).
    first_listen: Option<String>,
    _router: Option<ZenohRouter>,
}

impl ZenohHarness {
    /// Peers without a router: system 1 listens on a fresh port each time it opens, the others
    /// connect to it; multicast scouting off.
    pub fn peers() -> ZenohHarness {
        ZenohHarness {
            mode: Mode::Peer,
            prefix: unique_prefix(),
            router_endpoint: None,
            first_listen: None,
            _router: None,
        }
    }

    /// Clients of a router this harness starts.
    pub fn clients() -> ZenohHarness {
        let (router, endpoint) = router();
        ZenohHarness {
            mode: Mode::Client,
            prefix: unique_prefix(),
            router_endpoint: Some(endpoint),
            first_listen: None,
            _router: Some(router),
        }
    }

    /// The settings system `system` opens with.
    pub fn settings(&mut self, system: SystemId) -> ZenohSettings {
        let mut s = ZenohSettings {
            mode: self.mode,
            multicast_scouting: false,
            prefix: self.prefix.clone(),
            ..ZenohSettings::default()
        };
        match self.mode {
            Mode::Client => s.connect = vec![self.router_endpoint.clone().expect("router")],
            Mode::Peer if system == SystemId(1) => {
                let listen = format!("tcp/127.0.0.1:{}", free_port());
                self.first_listen = Some(listen.clone());
                s.listen = vec![listen];
            }
            Mode::Peer => {
                s.listen = vec![format!("tcp/127.0.0.1:{}", free_port())];
                s.connect = self.first_listen.clone().into_iter().collect();
            }
        }
        s
    }

    /// Opens system `system`'s link.
    pub fn open_link(&mut self, system: SystemId, sink: Arc<dyn FrameSink>) -> ZenohLink {
        let settings = self.settings(system);
        ZenohLink::open(
            ZenohLinkConfig {
                local: system,
                systems: systems(),
                settings,
            },
            sink,
        )
        .unwrap_or_else(|e| panic!("open {system}: {e}"))
    }
}

impl Harness for ZenohHarness {
    fn open(&mut self, system: SystemId, sink: Arc<dyn FrameSink>) -> Box<dyn Link> {
        Box::new(self.open_link(system, sink))
    }
}

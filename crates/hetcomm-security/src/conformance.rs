//! The link conformance suite over secured links: a harness that puts a [`SecurityLayer`]
//! (its own keys and sessions per system) over each link another harness opens. Every link
//! kind runs it to show that sealing loses nothing the link offers.

use std::collections::{HashMap, HashSet};
use std::sync::Arc;

use hetcomm_core::SystemId;
use hetcomm_link::conformance::{Harness, LayeredPerSystem};
use hetcomm_link::layer::LayerStack;

use crate::{Handshakes, Keypair, Policy, SecurityLayer};

/// `inner`'s links, each under a security layer: `systems` all know each other's public keys
/// and may all talk, with handshakes over the links themselves.
pub fn secured<H: Harness>(
    inner: H,
    systems: impl IntoIterator<Item = SystemId>,
) -> LayeredPerSystem<H, impl FnMut(SystemId) -> LayerStack> {
    let keys: HashMap<SystemId, Keypair> = systems
        .into_iter()
        .map(|s| (s, Keypair::generate().expect("the OS gives random bytes")))
        .collect();
    LayeredPerSystem {
        inner,
        make: move |id: SystemId| {
            let all: HashSet<SystemId> = keys.keys().copied().collect();
            let policy = Policy {
                local: id,
                keypair: keys
                    .get(&id)
                    .unwrap_or_else(|| panic!("system {id} has no key in this harness"))
                    .clone(),
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

//! A secured link's upkeep thread (handshake retries and timeouts, for handshakes over the
//! link) ends when the link is dropped: nothing of a closed link keeps running. Its own test
//! binary, so that no other test's layers run threads while this one counts them.

use std::collections::{HashMap, HashSet};
use std::sync::Arc;
use std::time::{Duration, Instant};

use hetcomm_core::SystemId;
use hetcomm_link::layer::{LayerContext, LinkLayer};
use hetcomm_link::{FrameSink, Link, LinkCaps, LinkError, Peer};
use hetcomm_security::{Handshakes, Keypair, Policy, SecurityLayer};

/// A link that sends nowhere.
struct Void;

impl Link for Void {
    fn caps(&self) -> LinkCaps {
        LinkCaps {
            max_frame: 1 << 16,
            mtu: 1 << 16,
            reliable: false,
            ordered: true,
            broadcast: false,
        }
    }

    fn send(&self, _to: SystemId, _frame: &[u8]) -> Result<(), LinkError> {
        Ok(())
    }
}

struct Ignore;

impl FrameSink for Ignore {
    fn on_frame(&self, _frame: &[u8], _from: Peer) {}
}

/// Threads of this process named `hc-security` (the layers' upkeep threads).
fn upkeep_threads() -> usize {
    std::fs::read_dir("/proc/self/task")
        .unwrap()
        .filter_map(|t| std::fs::read_to_string(t.ok()?.path().join("comm")).ok())
        .filter(|name| name.trim() == "hc-security")
        .count()
}

/// Waits (bounded) until `n` upkeep threads run: a new thread names itself once it starts.
fn wait_for(n: usize) -> usize {
    let deadline = Instant::now() + Duration::from_secs(5);
    while upkeep_threads() != n && Instant::now() < deadline {
        std::thread::sleep(Duration::from_millis(5));
    }
    upkeep_threads()
}

#[test]
fn dropping_a_secured_link_stops_its_upkeep_thread_at_once() {
    let (a, b) = (SystemId(0), SystemId(1));
    let (ka, kb) = (Keypair::generate().unwrap(), Keypair::generate().unwrap());
    let policy = Policy {
        local: a,
        keypair: ka,
        peers: HashMap::from([(b, kb.public)]),
        data_from: HashSet::from([b]),
        acks_from: HashSet::from([b]),
    };
    let layer = SecurityLayer::new("t", policy, Handshakes::OverTheLink);
    let ctx = LayerContext::new(a);
    let link = layer
        .wrap(&ctx, Arc::new(Ignore), &mut |_sink| Ok(Arc::new(Void)))
        .unwrap();
    assert_eq!(
        wait_for(1),
        1,
        "the upkeep thread runs while the link is open"
    );
    drop(link);
    // Joined by the drop, not left to notice on its next tick (up to 100 ms later).
    assert_eq!(upkeep_threads(), 0);
}

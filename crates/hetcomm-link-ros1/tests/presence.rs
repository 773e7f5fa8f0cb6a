//! Presence on `ros1` links (issue 36), against a real ROS master: a link reports a
//! destination up (`LinkEvent::PeerUp`) when its subscriber is connected, and down
//! (`LinkEvent::PeerDown`) when the master no longer lists a subscriber of its topic (its node
//! unregistered: the destination's link closed), through `FrameSink::on_event`, so that
//! failover can use it.

mod common;

use std::collections::BTreeMap;
use std::sync::{Arc, Condvar, Mutex};
use std::time::{Duration, Instant};

use common::Master;
use hetcomm_core::SystemId;
use hetcomm_link::{FrameSink, Link, LinkEvent, Peer};
use hetcomm_link_ros1::Ros1Settings;
use hetcomm_link_ros1::{Ros1Config, Ros1Link};

const A: SystemId = SystemId(1);
const B: SystemId = SystemId(2);

/// Records the events it is told.
#[derive(Default)]
struct Events {
    seen: Mutex<Vec<LinkEvent>>,
    changed: Condvar,
}

impl FrameSink for Events {
    fn on_frame(&self, _frame: &[u8], _from: Peer) {}

    fn on_event(&self, event: LinkEvent) {
        self.seen.lock().unwrap().push(event);
        self.changed.notify_all();
    }
}

impl Events {
    /// Waits (at most 20 s) until `n` events were told; all of them then.
    fn wait_for(&self, n: usize) -> Vec<LinkEvent> {
        let deadline = Instant::now() + Duration::from_secs(20);
        let mut seen = self.seen.lock().unwrap();
        while seen.len() < n {
            let left = deadline.saturating_duration_since(Instant::now());
            assert!(
                !left.is_zero(),
                "not {n} events within 20 s (told: {seen:?})"
            );
            seen = self.changed.wait_timeout(seen, left).unwrap().0;
        }
        seen.clone()
    }
}

#[test]
fn a_peer_unregistering_is_reported_down_and_coming_back_up() {
    let master = Master::start();
    let settings = Ros1Settings {
        master_uri: master.uri(),
        namespace: Some(format!("presence_{}", std::process::id())),
        connect_timeout_ms: Some(3000),
    };
    let names: BTreeMap<SystemId, String> = [(A, "A".to_string()), (B, "B".to_string())].into();
    let open = |id, sink: Arc<dyn FrameSink>| {
        Ros1Link::open(id, &names, &settings, sink, Ros1Config::default()).expect("open")
    };
    let events = Arc::new(Events::default());
    let a = open(A, events.clone());
    assert!(events.seen.lock().unwrap().is_empty(), "nothing before B");
    let b = open(B, Arc::new(Events::default()));
    // A send connects to B's subscriber: B is up.
    a.send(B, &[0u8; 48]).expect("send to B");
    assert_eq!(events.wait_for(1), [LinkEvent::PeerUp(B)]);
    // B's node unregisters when its link closes: B is down.
    drop(b);
    assert_eq!(
        events.wait_for(2),
        [LinkEvent::PeerUp(B), LinkEvent::PeerDown(B)]
    );
    // B again: up once connected.
    let _b = open(B, Arc::new(Events::default()));
    a.send(B, &[0u8; 48]).expect("send to B again");
    let up_down_up = [
        LinkEvent::PeerUp(B),
        LinkEvent::PeerDown(B),
        LinkEvent::PeerUp(B),
    ];
    assert_eq!(events.wait_for(3), up_down_up);
    // Nothing more while B stays.
    std::thread::sleep(Duration::from_millis(1500));
    assert_eq!(events.wait_for(3), up_down_up);
}

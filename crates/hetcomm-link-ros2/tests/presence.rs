//! Presence on `ros2` links (issue 36): a link reports a destination up
//! (`LinkEvent::PeerUp`) when a DDS reader matches its writer to that destination, and down
//! (`LinkEvent::PeerDown`) when the last one unmatches (the destination's link closed), through
//! `FrameSink::on_event`, so that failover can use it; with a receive thread and driven.

use std::sync::{Arc, Condvar, Mutex};
use std::time::{Duration, Instant};

use hetcomm_core::SystemId;
use hetcomm_link::{FrameSink, LinkEvent, Peer, Readable};
use hetcomm_link_ros2::factory::open_link;
use hetcomm_link_ros2::Ros2Settings;

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
    /// Waits (at most 20 s, reading `driven` meanwhile if given) until `n` events were told;
    /// all of them then.
    fn wait_for(&self, n: usize, driven: Option<&dyn Readable>) -> Vec<LinkEvent> {
        let deadline = Instant::now() + Duration::from_secs(20);
        loop {
            if let Some(r) = driven {
                let _ = r.read_ready(64);
            }
            let seen = self.seen.lock().unwrap();
            if seen.len() >= n {
                return seen.clone();
            }
            assert!(
                Instant::now() < deadline,
                "not {n} events within 20 s (told: {seen:?})"
            );
            let _ = self
                .changed
                .wait_timeout(seen, Duration::from_millis(20))
                .unwrap();
        }
    }
}

fn presence_follows_the_peer(domain_id: u16, driven: bool) {
    let settings = Ros2Settings {
        domain_id,
        namespace: format!("/presence_{}_{domain_id}", std::process::id()),
        ..Ros2Settings::default()
    };
    let names = vec![(A, "A".to_string()), (B, "B".to_string())];
    let events = Arc::new(Events::default());
    let a = open_link(A, &names, &settings, events.clone(), driven).expect("open A");
    let readable = || a.readable();
    assert!(events.seen.lock().unwrap().is_empty(), "nothing before B");
    let b = open_link(B, &names, &settings, Arc::new(Events::default()), false).expect("open B");
    let seen = events.wait_for(1, readable());
    assert_eq!(seen, [LinkEvent::PeerUp(B)]);
    // Frames go once B is up.
    a.send(B, &[0u8; 48]).expect("send to B");
    drop(b);
    let seen = events.wait_for(2, readable());
    assert_eq!(seen, [LinkEvent::PeerUp(B), LinkEvent::PeerDown(B)]);
    // And up again when B comes back.
    let _b = open_link(B, &names, &settings, Arc::new(Events::default()), false).expect("B again");
    let seen = events.wait_for(3, readable());
    let up_down_up = [
        LinkEvent::PeerUp(B),
        LinkEvent::PeerDown(B),
        LinkEvent::PeerUp(B),
    ];
    assert_eq!(seen, up_down_up);
    // Nothing more while B stays.
    std::thread::sleep(Duration::from_millis(500));
    assert_eq!(events.wait_for(3, readable()), up_down_up);
}

#[test]
fn a_reader_matching_and_unmatching_is_reported_as_the_peer_up_and_down() {
    presence_follows_the_peer(91, false);
}

#[test]
fn driven_links_report_presence_too() {
    presence_follows_the_peer(92, true);
}

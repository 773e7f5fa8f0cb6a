//! Presence through the link seam: a system coming online and leaving is reported to the sink
//! of every link that follows it (`FrameSink::on_event`: `PeerUp`, `PeerDown`), and joins and
//! leaves reach `watch_presence`, what `hetcomm listen` prints.

mod common;

use std::sync::{Arc, Mutex};
use std::time::{Duration, Instant};

use common::{MqttHarness, Qos};
use hetcomm_core::SystemId;
use hetcomm_link::{FrameSink, LinkEvent, Peer};
use hetcomm_link_mqtt::{watch_presence, PresenceEvent};

/// Records the peer events reported through the seam.
#[derive(Default)]
struct PeerEvents(Mutex<Vec<LinkEvent>>);

impl PeerEvents {
    fn count(&self, event: LinkEvent) -> usize {
        self.0
            .lock()
            .unwrap()
            .iter()
            .filter(|&&e| e == event)
            .count()
    }
}

impl FrameSink for PeerEvents {
    fn on_frame(&self, _frame: &[u8], _from: Peer) {}
    fn on_event(&self, event: LinkEvent) {
        self.0.lock().unwrap().push(event);
    }
}

fn wait_until(what: &str, check: impl Fn() -> bool) {
    let deadline = Instant::now() + Duration::from_secs(10);
    while !check() {
        assert!(Instant::now() < deadline, "not within 10 s: {what}");
        std::thread::sleep(Duration::from_millis(10));
    }
}

#[test]
fn a_system_coming_online_is_reported_through_the_seam_and_leaving_to_the_feed() {
    let (a_id, b_id) = (SystemId(1), SystemId(2));
    let feed = watch_presence();
    let mut h = MqttHarness::new(Qos::AtLeastOnce);
    let events = Arc::new(PeerEvents::default());
    let a = h.open_link(a_id, events.clone());
    let b = h.open_link(b_id, Arc::new(PeerEvents::default()));
    wait_until("B reported up to A's sink", || {
        events.count(LinkEvent::PeerUp(b_id)) == 1
    });
    assert_eq!(a.presence(), [b_id]);
    drop(b);
    wait_until("A sees B gone", || a.presence().is_empty());
    wait_until("B reported down to A's sink", || {
        events.count(LinkEvent::PeerDown(b_id)) == 1
    });
    let _b = h.open_link(b_id, Arc::new(PeerEvents::default()));
    wait_until("B reported up again", || {
        events.count(LinkEvent::PeerUp(b_id)) == 2
    });
    assert_eq!(
        *events.0.lock().unwrap(),
        [
            LinkEvent::PeerUp(b_id),
            LinkEvent::PeerDown(b_id),
            LinkEvent::PeerUp(b_id)
        ],
        "what A's sink was told, in order"
    );
    // What A's link saw, in order (the feed has every link of the process: B's too).
    let seen_by_a: Vec<PresenceEvent> = std::iter::from_fn(|| feed.try_recv().ok())
        .filter(|(local, _)| *local == a_id)
        .map(|(_, e)| e)
        .filter(|e| matches!(e, PresenceEvent::Joined(s) | PresenceEvent::Left(s) if *s == b_id))
        .collect();
    assert_eq!(
        seen_by_a,
        [
            PresenceEvent::Joined(b_id),
            PresenceEvent::Left(b_id),
            PresenceEvent::Joined(b_id)
        ]
    );
}

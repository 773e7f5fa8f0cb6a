//! Presence through the link seam: a system coming online is reported to the sink of every
//! link that follows it (`FrameSink::on_peer_up`), and joins and leaves reach
//! `watch_presence`, what `hetcomm listen` prints.

mod common;

use std::sync::{Arc, Mutex};
use std::time::{Duration, Instant};

use common::{MqttHarness, Qos};
use hetcomm_core::SystemId;
use hetcomm_link::{FrameSink, Peer};
use hetcomm_link_mqtt::{watch_presence, PresenceEvent};

/// Records the peers reported up.
#[derive(Default)]
struct PeerUps(Mutex<Vec<SystemId>>);

impl FrameSink for PeerUps {
    fn on_frame(&self, _frame: &[u8], _from: Peer) {}
    fn on_peer_up(&self, peer: SystemId) {
        self.0.lock().unwrap().push(peer);
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
    let ups = Arc::new(PeerUps::default());
    let a = h.open_link(a_id, ups.clone());
    let b = h.open_link(b_id, Arc::new(PeerUps::default()));
    wait_until("B reported up to A's sink", || {
        ups.0.lock().unwrap().contains(&b_id)
    });
    assert_eq!(a.presence(), [b_id]);
    drop(b);
    wait_until("A sees B gone", || a.presence().is_empty());
    let _b = h.open_link(b_id, Arc::new(PeerUps::default()));
    wait_until("B reported up again", || {
        ups.0.lock().unwrap().iter().filter(|&&p| p == b_id).count() == 2
    });
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

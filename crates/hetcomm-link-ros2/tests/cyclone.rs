//! The Cyclone DDS backend's own cases (feature `cyclone`): two links of one process that
//! answer every frame from inside their sinks. Cyclone delivers to readers of the same process
//! on the writing thread, so the link must not take and deliver samples from inside the
//! listener (an answer would re-enter the listener it came from, which Cyclone waits for: a
//! deadlock); the ping-pong must run to the end, also when the listener delivers
//! (`deliver_on_receive_thread`).
#![cfg(feature = "cyclone")]

use std::sync::atomic::{AtomicU64, Ordering};
use std::sync::{Arc, OnceLock, Weak};
use std::time::{Duration, Instant};

use hetcomm_core::SystemId;
use hetcomm_link::{FrameSink, Link, Peer};
use hetcomm_link_ros2::cyclone::CycloneLink;
use hetcomm_link_ros2::{Backend, Ros2Settings};

/// Answers each frame (a counter) with the next one, up to `last`.
struct Echo {
    /// Weak: the link holds the sink.
    link: OnceLock<Weak<CycloneLink>>,
    to: SystemId,
    seen: AtomicU64,
    last: u64,
}

impl FrameSink for Echo {
    fn on_frame(&self, frame: &[u8], _from: Peer) {
        let n = u64::from_le_bytes(frame.try_into().expect("8 bytes"));
        assert_eq!(
            n,
            self.seen.load(Ordering::SeqCst) * 2 + u64::from(self.to == SystemId(2))
        );
        self.seen.fetch_add(1, Ordering::SeqCst);
        if n < self.last {
            let link = self.link.get().and_then(Weak::upgrade).expect("link open");
            link.send(self.to, &(n + 1).to_le_bytes()).expect("answer");
        }
    }
}

#[test]
fn links_answering_from_inside_their_sinks_do_not_deadlock() {
    ping_pong(Ros2Settings {
        domain_id: 82,
        namespace: format!("/answer_{}", std::process::id()),
        dds: Backend::Cyclone,
        ..Ros2Settings::default()
    });
}

/// The same when the listener delivers (`deliver_on_receive_thread`): a listener reached
/// from inside another listener on the same thread must only signal.
#[test]
fn links_delivering_in_their_listeners_and_answering_there_do_not_deadlock() {
    ping_pong(Ros2Settings {
        domain_id: 82,
        namespace: format!("/answer_listener_{}", std::process::id()),
        dds: Backend::Cyclone,
        deliver_on_receive_thread: true,
        ..Ros2Settings::default()
    });
}

fn ping_pong(settings: Ros2Settings) {
    let names = vec![(SystemId(1), "A".into()), (SystemId(2), "B".into())];
    let last = 400;
    let echo = |to| {
        Arc::new(Echo {
            link: OnceLock::new(),
            to,
            seen: AtomicU64::new(0),
            last,
        })
    };
    let (ea, eb) = (echo(SystemId(2)), echo(SystemId(1)));
    let a = Arc::new(CycloneLink::open(SystemId(1), &names, &settings, ea.clone()).unwrap());
    let b = Arc::new(CycloneLink::open(SystemId(2), &names, &settings, eb.clone()).unwrap());
    ea.link.set(Arc::downgrade(&a)).ok();
    eb.link.set(Arc::downgrade(&b)).ok();
    // A sends 0 to B; B answers 1 to A; A answers 2 to B; ... up to `last`.
    // From a thread of its own: a deadlock would hang it, not the check below.
    let first = a.clone();
    std::thread::spawn(move || first.send(SystemId(2), &0u64.to_le_bytes()).expect("send"));
    let deadline = Instant::now() + Duration::from_secs(20);
    let total = || ea.seen.load(Ordering::SeqCst) + eb.seen.load(Ordering::SeqCst);
    while total() < last + 1 {
        assert!(Instant::now() < deadline, "stuck after {} frames", total());
        std::thread::sleep(Duration::from_millis(5));
    }
    assert_eq!(
        (
            eb.seen.load(Ordering::SeqCst),
            ea.seen.load(Ordering::SeqCst)
        ),
        (201, 200)
    );
    assert_eq!(a.stats().frames_dropped + b.stats().frames_dropped, 0);
}

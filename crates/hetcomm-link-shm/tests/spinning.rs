//! A receiver that spins (`Readable::set_spinning`) is read through its queue
//! (`Readable::pending`) and its senders skip the wake-up meanwhile; when it stops spinning,
//! a frame that came without a wake-up still makes its descriptor readable, and later frames
//! wake it as before.

mod common;

use std::sync::Arc;

use common::{config, unique_fleet};
use hetcomm_core::SystemId;
use hetcomm_link::conformance::CollectSink;
use hetcomm_link::{Link, Readable};
use hetcomm_link_shm::{ShmLink, ShmSettings};

const A: SystemId = SystemId(1);
const B: SystemId = SystemId(2);

/// Whether `rx`'s descriptor polls readable now.
fn fd_readable(rx: &dyn Readable) -> bool {
    let mut p = libc::pollfd {
        fd: rx.fd(),
        events: libc::POLLIN,
        revents: 0,
    };
    // SAFETY: one valid pollfd, exclusively borrowed for the call.
    let n = unsafe { libc::poll(&mut p, 1, 0) };
    n == 1 && p.revents & libc::POLLIN != 0
}

/// Reads what `rx`'s descriptor announces until it is quiet, as a sleeping reactor would.
fn drain(rx: &dyn Readable) {
    while fd_readable(rx) {
        rx.read_ready(64).unwrap();
    }
}

#[test]
fn a_spinning_receiver_is_read_from_its_queue_without_wake_ups_and_wakes_after() {
    let fleet = unique_fleet("spin");
    let sink_b = CollectSink::new();
    // B first: A finds B's flag when it opens.
    let b = ShmLink::open(
        config(&fleet, B, ShmSettings::default()),
        Arc::new(sink_b.clone()),
    )
    .unwrap();
    let a = ShmLink::open(
        config(&fleet, A, ShmSettings::default()),
        Arc::new(CollectSink::new()),
    )
    .unwrap();
    let rx = b.readable().unwrap();
    drain(rx);
    assert_eq!(rx.pending(), Some(false), "nothing sent yet");

    // Sleeping: a frame wakes the descriptor.
    a.send(B, b"asleep").unwrap();
    assert!(fd_readable(rx), "a sleeping receiver is woken");
    drain(rx);
    assert_eq!(sink_b.frames().len(), 1);

    // Spinning: the frame is in the queue, and no wake-up was sent for it.
    rx.set_spinning(true);
    a.send(B, b"spinning 1").unwrap();
    assert_eq!(rx.pending(), Some(true), "the queue shows the frame");
    assert!(!fd_readable(rx), "the sender skipped the wake-up");
    assert_eq!(rx.read_ready(64).unwrap(), 1);
    assert_eq!(rx.pending(), Some(false));

    // A frame that came while spinning but was not read: stopping wakes the descriptor.
    a.send(B, b"spinning 2").unwrap();
    assert!(!fd_readable(rx));
    rx.set_spinning(false);
    assert!(
        fd_readable(rx),
        "stopping announces the frame no wake-up did"
    );
    drain(rx);

    // Asleep again: senders wake it again.
    a.send(B, b"asleep again").unwrap();
    assert!(fd_readable(rx), "senders wake it once it stopped spinning");
    drain(rx);
    let got: Vec<Vec<u8>> = sink_b.frames().into_iter().map(|f| f.bytes).collect();
    assert_eq!(
        got,
        [
            b"asleep".to_vec(),
            b"spinning 1".to_vec(),
            b"spinning 2".to_vec(),
            b"asleep again".to_vec(),
        ]
    );
}

#[test]
fn a_sender_opened_before_its_receiver_finds_the_flag_later() {
    let fleet = unique_fleet("spin-late");
    let settings = ShmSettings {
        liveness_ms: 10,
        ..ShmSettings::default()
    };
    // A first: B's flag does not exist yet when A opens.
    let a = ShmLink::open(
        config(&fleet, A, settings.clone()),
        Arc::new(CollectSink::new()),
    )
    .unwrap();
    let sink_b = CollectSink::new();
    let b = ShmLink::open(config(&fleet, B, settings), Arc::new(sink_b.clone())).unwrap();
    let rx = b.readable().unwrap();
    rx.set_spinning(true);
    // Until A's upkeep opens B's flag, A notifies: the frame wakes B even though it spins.
    a.send(B, b"before").unwrap();
    assert!(fd_readable(rx), "without the flag, the sender always wakes");
    assert_eq!(rx.read_ready(64).unwrap(), 1);
    // A's upkeep (from its reader, every `liveness_ms`) opens the flag.
    let arx = a.readable().unwrap();
    let deadline = std::time::Instant::now() + std::time::Duration::from_secs(5);
    let mut sent = 0;
    loop {
        std::thread::sleep(std::time::Duration::from_millis(15));
        arx.read_ready(64).unwrap();
        drain_listener_only(rx);
        a.send(B, b"after").unwrap();
        sent += 1;
        if !fd_readable(rx) {
            break;
        }
        assert!(
            std::time::Instant::now() < deadline,
            "A never found B's spinning flag"
        );
    }
    rx.set_spinning(false);
    drain(rx);
    assert_eq!(sink_b.frames().len(), 1 + sent);
}

/// Empties the descriptor of `rx` (its pending wake-ups) while it spins: one read while
/// spinning takes the frames, and stopping and starting again consumes the wake-ups.
fn drain_listener_only(rx: &dyn Readable) {
    rx.set_spinning(false);
    drain(rx);
    rx.set_spinning(true);
}

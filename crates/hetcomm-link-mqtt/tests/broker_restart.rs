//! The broker killed (SIGKILL) and restarted mid-stream, with every outcome accounted for:
//! acknowledged, nothing is lost and nothing delivered twice; unacknowledged, sends made while
//! the broker is away fail (after `reconnect_wait_ms`) naming it, none of them arrives, and
//! nothing arrives twice. Each test has a broker of its own (it kills it).

mod common;

use std::collections::BTreeSet;
use std::sync::{Arc, Mutex};
use std::time::{Duration, Instant};

use common::fleet::{keys, open_pair};
use common::{unique_fleet, Mosquitto};
use hetcomm::{FailReason, MessageType, Outcome, SendOptions};

const N: u16 = 200;

struct Run {
    outcomes: Vec<Outcome>,
    received: Vec<u16>,
}

/// Streams N messages from A to B (one every 5 ms), killing the broker after the 60th and
/// starting it again a second later.
fn stream_through_a_restart(more: &str) -> Run {
    let broker = Arc::new(Mutex::new(Mosquitto::start("")));
    let address = broker.lock().unwrap().address.clone();
    let (a, b) = open_pair(&keys(&address, &unique_fleet(), more));
    let (from, to) = (a.module("M").unwrap(), b.module("M").unwrap());
    let mut tickets = Vec::new();
    let mut outage = None;
    for i in 0..N {
        let payload = [0xcd, (i >> 8) as u8, i as u8]; // MessagePack uint 16
        match from.send_raw("B", "M", MessageType(7), &payload, SendOptions::default()) {
            Ok(t) => tickets.push(t),
            Err(e) => panic!("send {i}: {e}"),
        }
        if i == 60 {
            let broker = broker.clone();
            outage = Some(std::thread::spawn(move || {
                broker.lock().unwrap().kill();
                let killed = Instant::now();
                std::thread::sleep(Duration::from_secs(1));
                broker.lock().unwrap().restart();
                killed.elapsed()
            }));
        }
        std::thread::sleep(Duration::from_millis(5));
    }
    let down = outage.expect("the outage").join().expect("restart");
    let outcomes: Vec<Outcome> = tickets.into_iter().map(|t| t.wait()).collect();
    let mut received = Vec::new();
    while let Ok(m) = to.recv_raw_timeout(Some(Duration::from_secs(3))) {
        received.push(u16::from_be_bytes([m.payload[1], m.payload[2]]));
    }
    let count = |f: fn(&Outcome) -> bool| outcomes.iter().filter(|o| f(o)).count();
    eprintln!(
        "{more:?}: broker down {down:?}; {} delivered, {} sent or relayed, {} unconfirmed, {} failed; {} received",
        count(|o| matches!(o, Outcome::Delivered { .. })),
        count(|o| matches!(o, Outcome::Sent { .. } | Outcome::Relayed { .. })),
        count(|o| matches!(o, Outcome::Unconfirmed { .. })),
        count(|o| matches!(o, Outcome::Failed { .. })),
        received.len()
    );
    Run { outcomes, received }
}

/// Nothing arrived twice, and nothing that failed arrived.
fn check_truthful(run: &Run) -> BTreeSet<u16> {
    let unique: BTreeSet<u16> = run.received.iter().copied().collect();
    assert_eq!(unique.len(), run.received.len(), "a message arrived twice");
    for (i, o) in run.outcomes.iter().enumerate() {
        if o.is_failed() {
            assert!(
                !unique.contains(&(i as u16)),
                "message {i} failed ({o}) but arrived"
            );
        }
        if matches!(o, Outcome::Delivered { .. }) {
            assert!(
                unique.contains(&(i as u16)),
                "message {i} delivered but not received"
            );
        }
    }
    unique
}

#[test]
fn acknowledged_mode_loses_nothing_and_delivers_nothing_twice_across_a_broker_restart() {
    // Attempts for the outage: with the default 3, a frame lost with the broker (and its
    // retransmissions, a few milliseconds apart on loopback, lost while the other end is still
    // resubscribing) can end *unconfirmed*: truthful, but not delivered.
    let run = stream_through_a_restart("reconnect_wait_ms = 5000\nattempts = 8");
    let unique = check_truthful(&run);
    for (i, o) in run.outcomes.iter().enumerate() {
        assert!(matches!(o, Outcome::Delivered { .. }), "message {i}: {o}");
    }
    assert_eq!(unique, (0..N).collect::<BTreeSet<u16>>());
}

/// Unacknowledged at QoS 1 (the default): a send the broker confirmed is *relayed*; one whose
/// PUBACK the broker's death swallowed is *unconfirmed* (the broker said nothing in time);
/// one made while it is away fails naming it. A send whose first frame the link refused and
/// the router retried ends the same way: the retry's frame takes a receipt too.
#[test]
fn unacknowledged_sends_during_a_broker_restart_fail_naming_the_broker() {
    let run = stream_through_a_restart("delivery = \"unacknowledged\"\nreconnect_wait_ms = 200");
    let unique = check_truthful(&run);
    let failed: Vec<&Outcome> = run.outcomes.iter().filter(|o| o.is_failed()).collect();
    assert!(
        !failed.is_empty(),
        "no send failed while the broker was away"
    );
    for o in &failed {
        let Outcome::Failed { reason, .. } = o else {
            unreachable!()
        };
        let text = reason.to_string();
        let unreachable =
            text.contains("MQTT broker mqtt://127.0.0.1:") && text.contains("unreachable");
        let nobody = matches!(reason, FailReason::Relay(_)) && text.contains("no subscriber");
        assert!(unreachable || nobody, "{text}");
    }
    for (i, o) in run.outcomes.iter().enumerate() {
        let unanswered = matches!(
            o,
            Outcome::Unconfirmed { reason: FailReason::Relay(why), .. }
                if why.contains("broker mqtt://127.0.0.1:")
        );
        assert!(
            matches!(o, Outcome::Relayed { .. } | Outcome::Failed { .. }) || unanswered,
            "message {i}: {o}"
        );
    }
    // Before the outage, the broker confirmed every send.
    assert!((0..50).all(|i| matches!(run.outcomes[i], Outcome::Relayed { .. })));
    // Traffic resumed: the last messages, sent long after the restart, arrived.
    assert!(
        unique.contains(&(N - 1)),
        "nothing after the restart arrived"
    );
    // Before the outage, everything arrived.
    assert!((0..50).all(|i| unique.contains(&i)));
}

/// A send the broker does not confirm within `reconnect_wait_ms` (the broker frozen: its
/// connection stays open, nothing answers) ends *unconfirmed*, saying so, within the bound;
/// with the broker killed, a send fails naming it. QoS 0 stays *sent*: nothing to confirm.
#[test]
fn an_unacknowledged_send_the_broker_does_not_confirm_is_unconfirmed_and_one_to_a_dead_broker_fails(
) {
    let broker = Mosquitto::start("");
    let more = "delivery = \"unacknowledged\"\nreconnect_wait_ms = 300";
    let (a, b) = open_pair(&keys(&broker.address, &unique_fleet(), more));
    let (from, to) = (a.module("M").unwrap(), b.module("M").unwrap());
    let send = |i: u8| {
        from.send_raw("B", "M", MessageType(7), &[0x91, i], SendOptions::default())
            .expect("send")
    };
    assert_eq!(send(1).wait(), Outcome::Relayed { attempts: 1 });
    to.recv_raw_timeout(Some(Duration::from_secs(5)))
        .expect("the relayed message arrives");

    broker.pause();
    let started = Instant::now();
    let outcome = send(2)
        .wait_timeout(Duration::from_secs(5))
        .expect("an outcome within the bound, though the broker says nothing");
    let waited = started.elapsed();
    broker.resume();
    let Outcome::Unconfirmed {
        reason: FailReason::Relay(why),
        attempts: 1,
    } = &outcome
    else {
        panic!("{outcome}");
    };
    assert!(
        why.contains(&format!("the broker mqtt://{}", broker.address))
            && why.contains("did not confirm it within 300 ms"),
        "{why}"
    );
    assert!(
        waited >= Duration::from_millis(300) && waited < Duration::from_secs(2),
        "{waited:?}"
    );
    assert!(
        outcome.to_string().starts_with("unconfirmed: "),
        "{outcome}"
    );

    let mut broker = broker;
    broker.kill();
    // The link sees the connection close (the kernel closes a dead process's sockets) at once;
    // a send made before it did would be queued, and end unconfirmed like the one above.
    std::thread::sleep(Duration::from_millis(500));
    let outcome = send(3).wait();
    let Outcome::Failed { reason, .. } = &outcome else {
        panic!("{outcome}");
    };
    let text = reason.to_string();
    assert!(
        text.contains(&format!("MQTT broker mqtt://{}", broker.address))
            && text.contains("unreachable"),
        "{text}"
    );
}

//! `RawSender::send_many`: a batch of sends, each with its own truthful outcome, in order,
//! numbered as single sends are; in-process (one pass through the inbox) and over UDP (one by
//! one).

use hetcomm::{FailReason, LocalFleet, MessageType, Outcome, SendOptions};

const DATA: MessageType = MessageType(40);

/// Two systems on one transport of `kind`; module `M` holds `capacity` messages and drops
/// the newest past that.
fn fleet(kind: &str, delivery: &str, capacity: usize) -> LocalFleet {
    let endpoints = if kind == "udp" {
        let port = |_| {
            std::net::UdpSocket::bind("127.0.0.1:0")
                .unwrap()
                .local_addr()
                .unwrap()
                .port()
        };
        format!(
            "[transports.t.endpoints]\nA = \"127.0.0.1:{}\"\nB = \"127.0.0.1:{}\"\n",
            port(0),
            port(1)
        )
    } else {
        String::new()
    };
    let text = format!(
        "[systems]\nA = 1\nB = 2\n[modules]\nM = {{ id = 0, inbox_capacity = {capacity}, overflow = \"drop-newest\" }}\n\
         [transports.t]\nkind = \"{kind}\"\ndelivery = \"{delivery}\"\n{endpoints}\
         [table]\ncolumns = [\"A\", \"B\"]\nA = [\"X\", \"t\"]\nB = [\"t\", \"X\"]\n"
    );
    LocalFleet::open(hetcomm::config::parse_str(&text, "batch.toml", None).unwrap()).unwrap()
}

fn payloads(n: u8) -> Vec<Vec<u8>> {
    (0..n).map(|i| vec![i; 64]).collect()
}

#[test]
fn an_in_process_batch_is_delivered_in_order_with_one_outcome_each() {
    for delivery in ["acknowledged", "unacknowledged"] {
        let f = fleet("inproc", delivery, 64);
        let a = f.system("A").unwrap().module("M").unwrap();
        let b = f.system("B").unwrap().module("M").unwrap();
        let to_b = a.raw_sender("B", "M", DATA).unwrap();
        // A single send first: the batch continues its numbering.
        to_b.send(&[9; 8], SendOptions::default()).unwrap();
        let batch = payloads(20);
        let slices: Vec<&[u8]> = batch.iter().map(Vec::as_slice).collect();
        let tickets = to_b.send_many(&slices, SendOptions::default());
        assert_eq!(tickets.len(), 20);
        for t in &tickets {
            let outcome = t.as_ref().unwrap().try_outcome().expect("known at once");
            match delivery {
                "acknowledged" => {
                    assert!(matches!(outcome, Outcome::Delivered { .. }), "{outcome:?}")
                }
                _ => assert!(matches!(outcome, Outcome::Sent { .. }), "{outcome:?}"),
            }
        }
        let first = b.try_recv_raw().unwrap();
        assert_eq!(first.envelope.id().seq, 1);
        for (i, p) in batch.iter().enumerate() {
            let m = b
                .try_recv_raw()
                .expect("every message of the batch arrived");
            assert_eq!(
                &m.payload[..],
                &p[..],
                "{delivery}: message {i} out of order"
            );
            assert_eq!(m.envelope.id().seq, i as u64 + 2);
            assert_eq!(m.envelope.source_system, "A");
        }
        assert!(b.try_recv_raw().is_none());
        let stats = f.system("A").unwrap().stats().router;
        assert_eq!(stats.sends, 21, "{delivery}");
        if delivery == "acknowledged" {
            assert_eq!(stats.delivered, 21);
        }
    }
}

#[test]
fn a_batch_larger_than_the_room_left_fails_exactly_those_that_did_not_fit() {
    let f = fleet("inproc", "acknowledged", 8);
    let a = f.system("A").unwrap().module("M").unwrap();
    let b = f.system("B").unwrap().module("M").unwrap();
    let to_b = a.raw_sender("B", "M", DATA).unwrap();
    let batch = payloads(5);
    let slices: Vec<&[u8]> = batch.iter().map(Vec::as_slice).collect();
    // 5 fit, then 3 of the next 5: the last 2 find the inbox full.
    let first = to_b.send_many(&slices, SendOptions::default());
    let second = to_b.send_many(&slices, SendOptions::default());
    let outcomes: Vec<Outcome> = first
        .iter()
        .chain(&second)
        .map(|t| t.as_ref().unwrap().try_outcome().unwrap())
        .collect();
    for (i, o) in outcomes.iter().enumerate() {
        if i < 8 {
            assert!(matches!(o, Outcome::Delivered { .. }), "send {i}: {o:?}");
        } else {
            assert!(
                matches!(
                    o,
                    Outcome::Failed {
                        reason: FailReason::InboxFull,
                        ..
                    }
                ),
                "send {i}: {o:?}"
            );
        }
    }
    let mut got = Vec::new();
    while let Some(m) = b.try_recv_raw() {
        got.push(m.payload[0]);
    }
    assert_eq!(
        got,
        vec![0, 1, 2, 3, 4, 0, 1, 2],
        "the delivered ones, in order"
    );
    let inbox = f.system("B").unwrap().stats();
    let dropped: u64 = inbox.inboxes.iter().map(|(_, s)| s.dropped()).sum();
    assert_eq!(dropped, 2, "the two that did not fit are counted");
}

#[test]
fn a_batch_over_udp_is_sent_one_by_one_with_the_same_outcomes() {
    let f = fleet("udp", "acknowledged", 64);
    let a = f.system("A").unwrap().module("M").unwrap();
    let b = f.system("B").unwrap().module("M").unwrap();
    let to_b = a.raw_sender("B", "M", DATA).unwrap();
    let batch = payloads(10);
    let slices: Vec<&[u8]> = batch.iter().map(Vec::as_slice).collect();
    let tickets = to_b.send_many(&slices, SendOptions::default());
    for t in tickets {
        let outcome = t
            .unwrap()
            .wait_timeout(std::time::Duration::from_secs(10))
            .unwrap();
        assert!(matches!(outcome, Outcome::Delivered { .. }), "{outcome:?}");
    }
    // UDP may reorder (and the first frames wait for the secure session): each arrived once.
    let mut got: Vec<Vec<u8>> = (0..batch.len())
        .map(|_| {
            let m = b
                .recv_raw_timeout(Some(std::time::Duration::from_secs(5)))
                .unwrap();
            m.payload[..].to_vec()
        })
        .collect();
    got.sort();
    assert_eq!(got, batch);
}

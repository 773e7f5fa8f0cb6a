//! A full inbox under the `block` policy never stops a link being read: messages from a link
//! that find no room are refused at once and answered "inbox full", and what each sender is
//! told is what happened.

use std::time::{Duration, Instant};

use hetcomm::{FailReason, LocalFleet, MessageType, Outcome};

mod common;

const TY: MessageType = MessageType(1);

#[test]
fn a_full_block_inbox_refuses_link_messages_at_once_and_outcomes_match_receipts() {
    let text = common::udp_pair_text(
        "[inbox]\nblock_timeout_ms = 5000",
        r#"M = { id = 0, inbox_capacity = 8, overflow = "block" }"#,
        "",
    );
    let fleet =
        LocalFleet::open(hetcomm::config::parse_str(&text, "block.toml", None).unwrap()).unwrap();
    let a = fleet.system("A").unwrap().module("M").unwrap();
    let b = fleet.system("B").unwrap().module("M").unwrap();
    const N: u32 = 200;
    let started = Instant::now();
    let tickets: Vec<_> = (0..N)
        .map(|i| {
            a.send_raw("B", "M", TY, &i.to_le_bytes(), Default::default())
                .unwrap()
        })
        .collect();
    let outcomes: Vec<Outcome> = tickets
        .iter()
        .map(|t| t.wait_timeout(Duration::from_secs(30)).expect("an outcome"))
        .collect();
    // Waiting 5 s per message for room (the old behaviour) would take minutes; refusing at
    // once keeps the whole exchange well under the block timeout of one message.
    let elapsed = started.elapsed();
    assert!(
        elapsed < Duration::from_secs(5),
        "the link was stopped waiting for room: {elapsed:?}"
    );
    let mut delivered = std::collections::BTreeSet::new();
    let mut refused = 0u64;
    for (i, o) in outcomes.iter().enumerate() {
        match o {
            Outcome::Delivered { .. } => {
                delivered.insert(i as u32);
            }
            Outcome::Failed {
                reason: FailReason::InboxFull,
                ..
            } => refused += 1,
            other => panic!("send {i}: {other}"),
        }
    }
    assert_eq!(delivered.len(), 8, "exactly the inbox's capacity got in");
    let stats = b.inbox_stats();
    assert_eq!(stats.refused_from_link, refused, "{stats:?}");
    assert_eq!(stats.dropped_after_wait, 0, "{stats:?}");
    // What the senders were told is what happened: the delivered ones are in the inbox, the
    // refused ones are not, and nothing arrives later.
    std::thread::sleep(Duration::from_millis(200));
    let mut got = std::collections::BTreeSet::new();
    while let Some(r) = b.try_recv_raw() {
        got.insert(u32::from_le_bytes(r.payload[..4].try_into().unwrap()));
    }
    assert_eq!(got, delivered);
}

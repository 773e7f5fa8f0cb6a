//! The module API on a fleet of five systems in one process (in-process transport).

use std::sync::atomic::{AtomicUsize, Ordering};
use std::sync::{Arc, Mutex};
use std::time::Duration;

use hetcomm::{FailReason, LocalFleet, Message, Outcome, RecvError, SendError, SendOptions};
use serde::{Deserialize, Serialize};

#[derive(Serialize, Deserialize, Message, Debug, Clone, PartialEq)]
#[message(id = 10)]
struct Command {
    code: u8,
}

#[derive(Serialize, Deserialize, Message, Debug, Clone, PartialEq)]
#[message(id = 11)]
struct Wheels {
    left: f64,
    right: f64,
}

#[derive(Serialize, Deserialize, Message, Debug, Clone, PartialEq)]
#[message(id = 10)]
struct Impostor(u32);

const NAMES: [&str; 5] = ["Alpha", "Bravo", "Charlie", "Delta", "Tango"];

/// Five systems; every pair on `wired` except Alpha ↔ Tango, which is X. `extra` is appended
/// to the [modules] / transport sections.
fn fleet_text(act_module: &str, delivery: &str) -> String {
    let mut table = String::from(
        "[table]\ncolumns = [\"Alpha\", \"Bravo\", \"Charlie\", \"Delta\", \"Tango\"]\n",
    );
    for (i, row) in NAMES.iter().enumerate() {
        let cells: Vec<String> = NAMES
            .iter()
            .enumerate()
            .map(|(j, col)| {
                let x = i == j
                    || (*row == "Alpha" && *col == "Tango")
                    || (*row == "Tango" && *col == "Alpha");
                format!("\"{}\"", if x { "X" } else { "wired" })
            })
            .collect();
        table.push_str(&format!("{row} = [{}]\n", cells.join(", ")));
    }
    format!(
        r#"
name = "five"
[systems]
Alpha = 0
Bravo = 1
Charlie = 2
Delta = 3
Tango = 4

[modules]
Plan = 1
Act = {act_module}

[transports.wired]
kind = "inproc"
delivery = "{delivery}"

{table}"#
    )
}

fn open(act_module: &str, delivery: &str) -> LocalFleet {
    let text = fleet_text(act_module, delivery);
    let fleet = hetcomm::config::parse_str(&text, "five.toml", None)
        .unwrap_or_else(|e| panic!("fleet does not parse: {e}\n{text}"));
    LocalFleet::open(fleet).expect("open fleet")
}

fn default_fleet() -> LocalFleet {
    open("2", "acknowledged")
}

#[test]
fn point_to_point_lands_in_the_right_inbox() {
    let f = default_fleet();
    let plan = f.system("Alpha").unwrap().module("Plan").unwrap();
    let outcome = plan
        .send("Charlie", "Act", &Command { code: 1 })
        .unwrap()
        .wait();
    assert!(
        matches!(outcome, Outcome::Delivered { attempts: 1, .. }),
        "{outcome:?}"
    );
    for name in NAMES {
        let sys = f.system(name).unwrap();
        let act = sys.module("Act").unwrap();
        let plan = sys.module("Plan").unwrap();
        assert!(!plan.has_message(), "{name}.Plan got a message");
        assert_eq!(act.has_message(), name == "Charlie", "{name}.Act");
    }
    let act = f.system("Charlie").unwrap().module("Act").unwrap();
    assert_eq!(act.next_type(), Some(Command::TYPE));
    let got = act.try_recv::<Command>().unwrap().unwrap();
    assert_eq!(got.message, Command { code: 1 });
    assert_eq!(got.envelope.source_system, "Alpha");
    assert_eq!(got.envelope.source_module, "Plan");
    assert!(got.envelope.timestamp().as_micros() > 0);
    assert!(got.envelope.received_at >= got.envelope.timestamp());
    assert!(!act.has_message());
}

#[test]
fn broadcast_reaches_every_allowed_system_once() {
    let f = default_fleet();
    let plan = f.system("Bravo").unwrap().module("Plan").unwrap();
    let outcomes = plan
        .broadcast(
            "Act",
            &Wheels {
                left: 1.0,
                right: 1.0,
            },
        )
        .unwrap()
        .wait();
    let mut dests: Vec<&str> = outcomes.iter().map(|(d, _)| d.as_str()).collect();
    dests.sort_unstable();
    assert_eq!(dests, vec!["Alpha", "Charlie", "Delta", "Tango"]);
    assert!(outcomes
        .iter()
        .all(|(_, o)| matches!(o, Outcome::Delivered { .. })));
    for name in ["Alpha", "Charlie", "Delta", "Tango"] {
        let act = f.system(name).unwrap().module("Act").unwrap();
        let got = act.try_recv::<Wheels>().unwrap().expect(name);
        assert!(got.envelope.is_broadcast());
        assert!(!act.has_message(), "{name} got two copies");
    }
    assert!(!f
        .system("Bravo")
        .unwrap()
        .module("Act")
        .unwrap()
        .has_message());

    // From Alpha, Tango is X: the broadcast skips it.
    let alpha = f.system("Alpha").unwrap().module("Plan").unwrap();
    let outcomes = alpha
        .broadcast("Plan", &Command { code: 0 })
        .unwrap()
        .wait();
    assert_eq!(outcomes.len(), 3);
    assert!(outcomes.iter().all(|(d, _)| d != "Tango"));
}

#[test]
fn x_pairs_are_refused_naming_both_systems() {
    let f = default_fleet();
    let plan = f.system("Alpha").unwrap().module("Plan").unwrap();
    let err = plan.send("Tango", "Act", &Command { code: 2 }).unwrap_err();
    assert!(matches!(err, SendError::NoRoute { .. }));
    assert_eq!(
        err.to_string(),
        "no traffic allowed from `Alpha` to `Tango`: the communication table says X for this pair"
    );
    let err = plan.send("Alpha", "Act", &Command { code: 2 }).unwrap_err();
    assert!(err.to_string().contains("from `Alpha` to `Alpha`"), "{err}");
    assert!(matches!(
        plan.send("Nobody", "Act", &Command { code: 2 }),
        Err(SendError::UnknownSystem(_))
    ));
    assert!(matches!(
        plan.send("Bravo", "Nothing", &Command { code: 2 }),
        Err(SendError::UnknownModule(_))
    ));
}

/// Commands 1 to 6 from `plan` to Delta's Act at priorities 10, 200, 10, 100, 200, 100:
/// taken by priority, then arrival, they come as 2, 5, 4, 6, 1, 3.
fn send_six_priorities(plan: &hetcomm::Module) {
    for (code, prio) in [(1, 10), (2, 200), (3, 10), (4, 100), (5, 200), (6, 100)] {
        plan.send_with(
            "Delta",
            "Act",
            &Command { code },
            SendOptions::priority(prio),
        )
        .unwrap()
        .wait();
    }
}

#[test]
fn polling_order_is_priority_then_arrival() {
    let f = default_fleet();
    let plan = f.system("Alpha").unwrap().module("Plan").unwrap();
    let act = f.system("Delta").unwrap().module("Act").unwrap();
    send_six_priorities(&plan);
    let order: Vec<u8> = std::iter::from_fn(|| act.try_recv::<Command>().unwrap())
        .map(|r| r.message.code)
        .collect();
    assert_eq!(order, vec![2, 5, 4, 6, 1, 3]);
}

#[test]
fn many_at_once_keeps_priority_order_and_the_bound() {
    let f = default_fleet();
    let plan = f.system("Alpha").unwrap().module("Plan").unwrap();
    let act = f.system("Delta").unwrap().module("Act").unwrap();
    let mut out = Vec::new();
    assert!(matches!(
        act.recv_raw_many(&mut out, 4, Some(Duration::from_millis(20))),
        Err(RecvError::Timeout(_))
    ));
    assert!(out.is_empty());
    send_six_priorities(&plan);
    let code = |m: &hetcomm::RawMessage| {
        hetcomm::payload::decode::<Command>(&m.payload)
            .unwrap()
            .code
    };
    assert_eq!(act.recv_raw_many(&mut out, 4, None).unwrap(), 4);
    assert_eq!(out.iter().map(code).collect::<Vec<_>>(), vec![2, 5, 4, 6]);
    assert_eq!(out[0].envelope.source_system, "Alpha");
    // Appended after what `out` held; the rest, fewer than asked for.
    assert_eq!(act.recv_raw_many(&mut out, 10, None).unwrap(), 2);
    assert_eq!(
        out.iter().map(code).collect::<Vec<_>>(),
        vec![2, 5, 4, 6, 1, 3]
    );
    assert_eq!(act.recv_raw_many(&mut out, 0, None).unwrap(), 0);
    let s = act.inbox_stats();
    assert_eq!((s.taken, s.len), (6, 0));
}

#[test]
fn wrong_type_recv_errors_and_keeps_the_message() {
    let f = default_fleet();
    let plan = f.system("Alpha").unwrap().module("Plan").unwrap();
    let act = f.system("Bravo").unwrap().module("Act").unwrap();
    plan.send(
        "Bravo",
        "Act",
        &Wheels {
            left: -10.0,
            right: 10.0,
        },
    )
    .unwrap()
    .wait();
    let err = act.try_recv::<Command>().unwrap_err();
    assert!(matches!(err, RecvError::WrongType { .. }), "{err}");
    assert_eq!(
        err.to_string(),
        "next message is of type 11 (Wheels), not 10 (Command); it stays in the inbox"
    );
    assert!(matches!(
        act.recv_timeout::<Command>(Duration::from_millis(10)),
        Err(RecvError::WrongType { .. })
    ));
    assert_eq!(act.pending(), 1);
    let got = act.recv::<Wheels>().unwrap();
    assert_eq!(
        got.message,
        Wheels {
            left: -10.0,
            right: 10.0
        }
    );
}

#[test]
fn two_types_with_one_id_are_refused_naming_both() {
    let f = default_fleet();
    let alpha = f.system("Alpha").unwrap();
    alpha.register::<Command>().unwrap();
    let err = alpha.register::<Impostor>().unwrap_err();
    assert_eq!(
        err.to_string(),
        "message type id 10 is claimed by both `Command` and `Impostor`: give one of them another id"
    );
    let plan = alpha.module("Plan").unwrap();
    assert!(matches!(
        plan.send("Bravo", "Act", &Impostor(1)),
        Err(SendError::TypeConflict(_))
    ));
}

#[test]
fn callbacks_fire_once_per_message() {
    let f = default_fleet();
    let act = f.system("Charlie").unwrap().module("Act").unwrap();
    let seen = Arc::new(Mutex::new(Vec::new()));
    let calls = Arc::new(AtomicUsize::new(0));
    let (s, c) = (seen.clone(), calls.clone());
    let (done_tx, done_rx) = std::sync::mpsc::channel();
    act.on::<Wheels>(move |r| {
        s.lock()
            .unwrap()
            .push((r.envelope.source_system.to_string(), r.message.left));
        if c.fetch_add(1, Ordering::SeqCst) + 1 == 40 {
            done_tx.send(()).unwrap();
        }
    })
    .unwrap();
    // Ten messages from each of four systems, sent concurrently.
    let handles: Vec<_> = ["Alpha", "Bravo", "Delta", "Tango"]
        .into_iter()
        .map(|name| {
            let plan = f.system(name).unwrap().module("Plan").unwrap();
            std::thread::spawn(move || {
                for i in 0..10 {
                    let o = plan
                        .send(
                            "Charlie",
                            "Act",
                            &Wheels {
                                left: i as f64,
                                right: 0.0,
                            },
                        )
                        .unwrap()
                        .wait();
                    assert!(matches!(o, Outcome::Delivered { .. }));
                }
            })
        })
        .collect();
    for h in handles {
        h.join().unwrap();
    }
    done_rx
        .recv_timeout(Duration::from_secs(10))
        .expect("callbacks");
    assert_eq!(calls.load(Ordering::SeqCst), 40);
    let seen = seen.lock().unwrap();
    for name in ["Alpha", "Bravo", "Delta", "Tango"] {
        let lefts: Vec<f64> = seen
            .iter()
            .filter(|(s, _)| s == name)
            .map(|(_, l)| *l)
            .collect();
        assert_eq!(
            lefts,
            (0..10).map(|i| i as f64).collect::<Vec<_>>(),
            "{name}"
        );
    }
    // Callback messages do not also land in the polling inbox; other types still do.
    assert!(!act.has_message());
    f.system("Alpha")
        .unwrap()
        .module("Plan")
        .unwrap()
        .send("Charlie", "Act", &Command { code: 0 })
        .unwrap()
        .wait();
    assert_eq!(act.next_type(), Some(Command::TYPE));
}

#[test]
fn unacknowledged_transport_reports_sent_without_confirmation() {
    let f = open("2", "unacknowledged");
    let plan = f.system("Alpha").unwrap().module("Plan").unwrap();
    let o = plan
        .send("Bravo", "Act", &Command { code: 1 })
        .unwrap()
        .wait();
    assert_eq!(o, Outcome::Sent { attempts: 1 });
    assert!(f
        .system("Bravo")
        .unwrap()
        .module("Act")
        .unwrap()
        .has_message());
}

#[test]
fn unreachable_peer_is_retried_then_reported() {
    // Only Alpha is opened: Bravo has no endpoint on the in-process hub.
    let text = fleet_text("2", "acknowledged");
    let fleet = hetcomm::config::parse_str(&text, "five.toml", None).unwrap();
    let alpha = hetcomm::Comm::open_fleet(&fleet, "Alpha").unwrap();
    let plan = alpha.module("Plan").unwrap();
    let o = plan
        .send("Bravo", "Act", &Command { code: 1 })
        .unwrap()
        .wait();
    match o {
        Outcome::Failed {
            reason: FailReason::Unreachable(why),
            attempts: 3,
        } => {
            // The ticket names the destination; the reason says why, without the peer's id.
            assert!(why.contains("in-process transport"), "{why}");
            assert!(!why.contains("peer 1"), "{why}");
        }
        other => panic!("expected unreachable after 3 attempts, got {other:?}"),
    }
    let stats = alpha.stats().router;
    assert_eq!(
        (stats.transmissions, stats.retransmissions, stats.failed),
        (3, 2, 1)
    );
    assert_eq!(stats.in_flight(), 0);
}

#[test]
fn unacknowledged_send_to_an_unreachable_peer_is_retried_then_reported() {
    // As above, unacknowledged: the outcome of a refused frame still ends Failed, after the
    // transport's attempts (3 by default, or 1), and the counters stay exact.
    for attempts in [None, Some(1)] {
        let mut text = fleet_text("2", "unacknowledged");
        if let Some(n) = attempts {
            text = text.replace(
                "delivery = \"unacknowledged\"",
                &format!("delivery = \"unacknowledged\"\nattempts = {n}"),
            );
        }
        let fleet = hetcomm::config::parse_str(&text, "five.toml", None).unwrap();
        let alpha = hetcomm::Comm::open_fleet(&fleet, "Alpha").unwrap();
        let plan = alpha.module("Plan").unwrap();
        let ticket = plan.send("Bravo", "Act", &Command { code: 1 }).unwrap();
        let expected = attempts.unwrap_or(3);
        if expected == 1 {
            // Nothing left to try: known when `send` returns.
            assert!(ticket.try_outcome().is_some());
        }
        match ticket.wait() {
            Outcome::Failed {
                reason: FailReason::Unreachable(why),
                attempts,
            } if attempts == expected => assert!(why.contains("in-process transport"), "{why}"),
            other => panic!("expected unreachable after {expected} attempts, got {other:?}"),
        }
        let stats = alpha.stats().router;
        assert_eq!(
            (
                stats.sends,
                stats.transmissions,
                stats.retransmissions,
                stats.failed,
                stats.sent
            ),
            (1, u64::from(expected), u64::from(expected - 1), 1, 0)
        );
        assert_eq!(stats.in_flight(), 0);
    }
}

fn overflow_fleet(policy: &str) -> LocalFleet {
    open(
        &format!("{{ id = 2, inbox_capacity = 3, overflow = \"{policy}\" }}"),
        "acknowledged",
    )
}

#[test]
fn overflow_drop_newest_refuses_and_counts() {
    let f = overflow_fleet("drop-newest");
    let plan = f.system("Alpha").unwrap().module("Plan").unwrap();
    let act = f.system("Bravo").unwrap().module("Act").unwrap();
    let outcomes: Vec<Outcome> = (0..5)
        .map(|code| plan.send("Bravo", "Act", &Command { code }).unwrap().wait())
        .collect();
    assert!(outcomes[..3]
        .iter()
        .all(|o| matches!(o, Outcome::Delivered { .. })));
    assert!(
        outcomes[3..].iter().all(|o| matches!(
            o,
            Outcome::Failed {
                reason: FailReason::InboxFull,
                ..
            }
        )),
        "{outcomes:?}"
    );
    let s = act.inbox_stats();
    assert_eq!((s.dropped_newest, s.dropped_oldest, s.len), (2, 0, 3));
    let codes: Vec<u8> = std::iter::from_fn(|| act.try_recv::<Command>().unwrap())
        .map(|r| r.message.code)
        .collect();
    assert_eq!(codes, vec![0, 1, 2]);
}

#[test]
fn overflow_drop_oldest_evicts_and_counts() {
    let f = overflow_fleet("drop-oldest");
    let plan = f.system("Alpha").unwrap().module("Plan").unwrap();
    let act = f.system("Bravo").unwrap().module("Act").unwrap();
    for code in 0..7 {
        let o = plan.send("Bravo", "Act", &Command { code }).unwrap().wait();
        assert!(matches!(o, Outcome::Delivered { .. }));
    }
    let s = act.inbox_stats();
    assert_eq!((s.dropped_oldest, s.dropped_newest, s.len), (4, 0, 3));
    let codes: Vec<u8> = std::iter::from_fn(|| act.try_recv::<Command>().unwrap())
        .map(|r| r.message.code)
        .collect();
    assert_eq!(codes, vec![4, 5, 6]);
}

#[test]
fn overflow_block_makes_the_sender_wait() {
    let text = fleet_text(
        "{ id = 2, inbox_capacity = 2, overflow = \"block\" }",
        "acknowledged",
    )
    .replace("[modules]", "[inbox]\nblock_timeout_ms = 50\n\n[modules]");
    let fleet = hetcomm::config::parse_str(&text, "five.toml", None).unwrap();
    let f = LocalFleet::open(fleet).unwrap();
    let plan = f.system("Alpha").unwrap().module("Plan").unwrap();
    let act = f.system("Bravo").unwrap().module("Act").unwrap();
    for code in 0..2 {
        plan.send("Bravo", "Act", &Command { code }).unwrap().wait();
    }
    // Full, nobody reading: the third send waits ~50 ms, then fails as inbox full.
    let started = std::time::Instant::now();
    let o = plan
        .send("Bravo", "Act", &Command { code: 2 })
        .unwrap()
        .wait();
    assert!(
        matches!(
            o,
            Outcome::Failed {
                reason: FailReason::InboxFull,
                ..
            }
        ),
        "{o:?}"
    );
    assert!(started.elapsed() >= Duration::from_millis(50));
    assert_eq!(act.inbox_stats().dropped_after_wait, 1);
    // With a reader making room, a waiting sender gets through.
    let reader = {
        let act = act.clone();
        std::thread::spawn(move || {
            (0..3)
                .map(|_| {
                    act.recv_timeout::<Command>(Duration::from_secs(10))
                        .unwrap()
                        .message
                        .code
                })
                .collect::<Vec<_>>()
        })
    };
    let o = plan
        .send("Bravo", "Act", &Command { code: 3 })
        .unwrap()
        .wait();
    assert!(matches!(o, Outcome::Delivered { .. }), "{o:?}");
    assert_eq!(reader.join().unwrap(), vec![0, 1, 3]);
    assert_eq!(act.inbox_stats().dropped(), 1);
}

#[test]
fn recv_timeout_times_out_and_blocking_recv_wakes() {
    let f = default_fleet();
    let act = f.system("Delta").unwrap().module("Act").unwrap();
    assert!(matches!(
        act.recv_timeout::<Command>(Duration::from_millis(20)),
        Err(RecvError::Timeout(_))
    ));
    let waiter = {
        let act = act.clone();
        std::thread::spawn(move || act.recv::<Command>().unwrap().message)
    };
    f.system("Charlie")
        .unwrap()
        .module("Plan")
        .unwrap()
        .send("Delta", "Act", &Command { code: 9 })
        .unwrap();
    assert_eq!(waiter.join().unwrap(), Command { code: 9 });
}

#[test]
fn a_kind_not_built_yet_fails_to_open_naming_it() {
    let text = r#"
[systems]
A = 0
B = 1
[modules]
Plan = 0
[transports.z]
kind = "zenoh"
[table]
columns = ["A", "B"]
A = ["X", "z"]
B = ["z", "X"]
"#;
    let fleet = hetcomm::config::parse_str(text, "z.toml", None).unwrap();
    let err = match LocalFleet::open(fleet) {
        Ok(_) => panic!("a zenoh transport opened"),
        Err(e) => e,
    };
    assert!(
        matches!(err, hetcomm::OpenError::KindUnavailable { .. }),
        "{err}"
    );
    let text = err.to_string();
    assert!(
        text.starts_with(
            "transport `z` is of kind `zenoh`, which is not available yet in this build"
        ),
        "{text}"
    );
    assert!(!text.contains("unknown variant"), "{text}");
}

#[test]
fn a_sender_handle_sends_like_send() {
    for delivery in ["acknowledged", "unacknowledged"] {
        let f = open("2", delivery);
        let plan = f.system("Alpha").unwrap().module("Plan").unwrap();
        let act = f.system("Charlie").unwrap().module("Act").unwrap();
        let to_act = plan.sender::<Command>("Charlie", "Act").unwrap();
        assert_eq!(to_act.destination(), "Charlie");
        let raw = plan.raw_sender("Charlie", "Act", Wheels::TYPE).unwrap();
        let first = to_act.send(&Command { code: 1 }).unwrap();
        assert_eq!(first.destination(), "Charlie");
        let outcome = first.wait();
        match delivery {
            "acknowledged" => assert!(matches!(outcome, Outcome::Delivered { .. }), "{outcome:?}"),
            _ => assert!(matches!(outcome, Outcome::Sent { .. }), "{outcome:?}"),
        }
        let wheels = hetcomm::payload::encode(&Wheels {
            left: 1.0,
            right: 2.0,
        })
        .unwrap();
        raw.send(&wheels, SendOptions::priority(200)).unwrap();
        to_act.clone().send(&Command { code: 2 }).unwrap();
        // Priority first, then arrival; every message numbered by Alpha's router in turn.
        let w = act.try_recv::<Wheels>().unwrap().unwrap();
        assert_eq!(
            w.message,
            Wheels {
                left: 1.0,
                right: 2.0
            }
        );
        let a = act.try_recv::<Command>().unwrap().unwrap();
        let b = act.try_recv::<Command>().unwrap().unwrap();
        assert_eq!((a.message.code, b.message.code), (1, 2));
        assert_eq!(
            (
                a.envelope.id().seq,
                w.envelope.id().seq,
                b.envelope.id().seq
            ),
            (1, 2, 3)
        );
        assert_eq!(b.envelope.source_system, "Alpha");
        let stats = f.system("Alpha").unwrap().stats();
        assert_eq!(stats.router.sends, 3, "{delivery}");
    }
}

#[test]
fn a_sender_handle_refuses_what_send_refuses() {
    let f = default_fleet();
    let plan = f.system("Alpha").unwrap().module("Plan").unwrap();
    assert!(matches!(
        plan.sender::<Command>("Nowhere", "Act"),
        Err(SendError::UnknownSystem(_))
    ));
    assert!(matches!(
        plan.sender::<Command>("Bravo", "Nobody"),
        Err(SendError::UnknownModule(_))
    ));
    // Alpha ↔ Tango is X.
    assert!(matches!(
        plan.raw_sender("Tango", "Act", Command::TYPE),
        Err(SendError::NoRoute { .. })
    ));
    plan.sender::<Command>("Bravo", "Act").unwrap();
    assert!(matches!(
        plan.sender::<Impostor>("Bravo", "Act"),
        Err(SendError::TypeConflict(_))
    ));
}

#[test]
fn a_sender_handle_follows_its_destination_closing_and_reopening() {
    // Its own fleet name: systems of one fleet opened one by one meet on a process-wide
    // hub, and another test counts on Bravo not being there.
    let text = fleet_text("2", "acknowledged").replace("name = \"five\"", "name = \"reopen\"");
    let fleet = hetcomm::config::parse_str(&text, "five.toml", None).unwrap();
    let alpha = hetcomm::Comm::open_fleet(&fleet, "Alpha").unwrap();
    let bravo = hetcomm::Comm::open_fleet(&fleet, "Bravo").unwrap();
    let plan = alpha.module("Plan").unwrap();
    let to_bravo = plan.sender::<Command>("Bravo", "Act").unwrap();
    let o = to_bravo.send(&Command { code: 1 }).unwrap().wait();
    assert!(matches!(o, Outcome::Delivered { .. }), "{o:?}");
    drop(bravo);
    let o = to_bravo.send(&Command { code: 2 }).unwrap().wait();
    // Not delivered. The closed system's in-process endpoint stays registered until its last
    // link handle is gone, so the frames are taken and dropped there: the sender cannot tell
    // that from a lost acknowledgement and says unconfirmed, not failed.
    assert!(
        matches!(o, Outcome::Failed { .. } | Outcome::Unconfirmed { .. }),
        "{o:?}"
    );
    // Opened again: the same handle finds the new system.
    let bravo = hetcomm::Comm::open_fleet(&fleet, "Bravo").unwrap();
    let o = to_bravo.send(&Command { code: 3 }).unwrap().wait();
    assert!(matches!(o, Outcome::Delivered { .. }), "{o:?}");
    let got = bravo.module("Act").unwrap().try_recv::<Command>().unwrap();
    assert_eq!(got.map(|r| r.message.code), Some(3));
}

#[test]
fn a_full_window_refuses_sends_until_an_outcome_frees_a_place() {
    // Alpha and Charlie are opened, Bravo and Delta are not: sends to them are refused by
    // the link and wait for their retries, each holding a place of Bravo's window of two.
    let text = fleet_text("2", "acknowledged").replace(
        "delivery = \"acknowledged\"",
        "delivery = \"acknowledged\"\nmax_in_flight = 2",
    );
    let fleet = hetcomm::config::parse_str(&text, "five.toml", None).unwrap();
    let alpha = hetcomm::Comm::open_fleet(&fleet, "Alpha").unwrap();
    let charlie = hetcomm::Comm::open_fleet(&fleet, "Charlie").unwrap();
    let plan = alpha.module("Plan").unwrap();
    let waiting: Vec<_> = (0..2)
        .map(|code| plan.send("Bravo", "Act", &Command { code }).unwrap())
        .collect();
    assert!(waiting.iter().all(|t| t.try_outcome().is_none()));
    let refused = plan.send("Bravo", "Act", &Command { code: 2 }).unwrap_err();
    assert!(
        matches!(&refused, SendError::Backpressure { to, limit: 2 } if to == "Bravo"),
        "{refused:?}"
    );
    assert!(refused.to_string().contains("max_in_flight"), "{refused}");

    // A broadcast still reaches the others; Bravo's ticket says why it was not sent.
    let outcomes = plan.broadcast("Act", &Command { code: 3 }).unwrap().wait();
    let of = |name: &str| {
        outcomes
            .iter()
            .find(|(n, _)| n == name)
            .map(|(_, o)| o.clone())
            .unwrap_or_else(|| panic!("no outcome for {name}: {outcomes:?}"))
    };
    assert_eq!(
        of("Bravo"),
        Outcome::Failed {
            reason: FailReason::Backpressure,
            attempts: 0
        }
    );
    assert!(matches!(of("Charlie"), Outcome::Delivered { .. }));
    assert!(matches!(
        of("Delta"),
        Outcome::Failed {
            reason: FailReason::Unreachable(_),
            ..
        }
    ));
    let act = charlie.module("Act").unwrap();
    assert_eq!(act.try_recv::<Command>().unwrap().unwrap().message.code, 3);

    // The two waiting sends end (Bravo stays unreachable), which frees the window.
    for t in &waiting {
        assert!(matches!(
            t.wait(),
            Outcome::Failed {
                reason: FailReason::Unreachable(_),
                attempts: 3
            }
        ));
    }
    let again = plan.send("Bravo", "Act", &Command { code: 4 }).unwrap();
    assert!(again.try_outcome().is_none(), "accepted and waiting again");
    let stats = alpha.stats().router;
    assert_eq!(stats.backpressured, 2, "one send and one broadcast copy");
    // Two waiting, two broadcast copies and the last one; the refused ones are not sends.
    assert_eq!(stats.sends, 5);
}

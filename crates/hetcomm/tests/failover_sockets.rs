//! Failover over real sockets: A and B talk over UDP first (through an emulation layer whose
//! outage blackholes it mid-stream: the UDP socket still takes every datagram, nothing
//! arrives) with TCP as second choice, both secured. The stream of acknowledged sends moves to
//! TCP during the outage and back to UDP after it, and every send is accounted for: one
//! outcome each, all delivered, each message in B's inbox exactly once, each outcome naming
//! the transport that carried it.

mod common;

use std::collections::BTreeSet;
use std::time::{Duration, Instant};

use common::free_udp_port;
use hetcomm::{LocalFleet, MessageType, Outcome, PathSwitch};

const TY: MessageType = MessageType(1);

fn free_tcp_port() -> u16 {
    std::net::TcpListener::bind("127.0.0.1:0")
        .and_then(|l| l.local_addr())
        .map(|a| a.port())
        .expect("a free TCP port")
}

fn fleet(outage_start_ms: u64, outage_ms: u64) -> LocalFleet {
    let text = fleet_text(outage_start_ms, outage_ms);
    let fleet =
        hetcomm::config::parse_str(&text, "failover.toml", None).unwrap_or_else(|e| panic!("{e}"));
    LocalFleet::open(fleet).unwrap_or_else(|e| panic!("{e}"))
}

/// The fleet file: A and B over `wifi` (UDP with an outage) first, `wired` (TCP) second.
fn fleet_text(outage_start_ms: u64, outage_ms: u64) -> String {
    let (ua, ub) = (free_udp_port(), free_udp_port());
    let (ta, tb) = (free_tcp_port(), free_tcp_port());
    format!(
        r#"
[systems]
A = 0
B = 1
[modules]
M = 0
[transports.udp]
kind = "udp"
endpoints = {{ A = "127.0.0.1:{ua}", B = "127.0.0.1:{ub}" }}
[transports.wifi]
kind = "emulated"
over = "udp"
outage_start_ms = {outage_start_ms}
outage_duration_ms = {outage_ms}
[transports.wired]
kind = "tcp"
endpoints = {{ A = "127.0.0.1:{ta}", B = "127.0.0.1:{tb}" }}
[table]
columns = ["A", "B"]
A = ["X", "wifi,wired"]
B = ["wifi,wired", "X"]
"#
    )
}

#[test]
fn a_blackholed_udp_path_moves_to_tcp_and_back_with_every_send_accounted_for() {
    let f = fleet(1_500, 1_500);
    let opened = Instant::now();
    let a_sys = f.system("A").unwrap();
    let b_sys = f.system("B").unwrap();
    let a = a_sys.module("M").unwrap();
    let b = b_sys.module("M").unwrap();
    let n: u32 = 1_000;
    // B reads everything while A sends one message every 5 ms for 5 s.
    let reader = std::thread::spawn(move || {
        let mut got = Vec::new();
        while let Ok(m) = b.recv_raw_timeout(Some(Duration::from_secs(5))) {
            got.push(u32::from_le_bytes(m.payload[..4].try_into().unwrap()));
        }
        got
    });
    let mut tickets = Vec::new();
    let mut switches: Vec<(Duration, PathSwitch)> = Vec::new();
    for i in 0..n {
        let due = Duration::from_millis(5 * u64::from(i));
        if let Some(wait) = due.checked_sub(opened.elapsed()) {
            std::thread::sleep(wait);
        }
        let t = a
            .send_raw("B", "M", TY, &i.to_le_bytes(), Default::default())
            .unwrap_or_else(|e| panic!("send {i}: {e}"));
        tickets.push((opened.elapsed(), t));
        for s in a_sys.path_changes() {
            switches.push((opened.elapsed(), s));
        }
    }
    let mut on = std::collections::BTreeMap::<(bool, String), u32>::new();
    for (i, (sent_at, t)) in tickets.iter().enumerate() {
        let outcome = t
            .wait_timeout(Duration::from_secs(10))
            .unwrap_or_else(|| panic!("send {i} has no outcome"));
        assert!(
            matches!(outcome, Outcome::Delivered { .. }),
            "send {i} (at {sent_at:?}): {outcome}"
        );
        let transport = t
            .transport()
            .unwrap_or_else(|| panic!("send {i} names no transport"));
        // Sent during the outage (past its detection) or not.
        let during =
            *sent_at > Duration::from_millis(1_800) && *sent_at < Duration::from_millis(2_900);
        *on.entry((during, transport.to_string())).or_default() += 1;
    }
    switches.extend(
        a_sys
            .path_changes()
            .into_iter()
            .map(|s| (opened.elapsed(), s)),
    );
    let got = reader.join().unwrap();
    let distinct: BTreeSet<u32> = got.iter().copied().collect();
    assert_eq!(
        got.len(),
        distinct.len(),
        "a message entered B's inbox twice"
    );
    assert_eq!(
        distinct,
        (0..n).collect::<BTreeSet<_>>(),
        "B's inbox misses messages"
    );
    let s = a_sys.stats().router;
    assert_eq!(
        (s.sends, s.delivered, s.in_flight()),
        (u64::from(n), u64::from(n), 0),
        "{s:?}"
    );
    // Away to wired within the outage's first 0.4 s, back to wifi within 0.6 s of its end.
    // (A loaded machine that stalls a side for a whole retransmission budget may add a
    // switch and its return elsewhere: that is the router doing its job, so it is allowed,
    // within bounds.)
    let moved = |from: &str, to: &str, lo: u64, hi: u64| {
        switches.iter().any(|(at, s)| {
            s.from == from
                && s.now == to
                && *at >= Duration::from_millis(lo)
                && *at < Duration::from_millis(hi)
        })
    };
    assert!(moved("wifi", "wired", 1_400, 1_900), "{switches:?}");
    assert!(moved("wired", "wifi", 3_000, 3_600), "{switches:?}");
    assert!(switches.len() <= 6, "{switches:?}");
    assert_eq!(s.path_changes, switches.len() as u64);
    // During the outage the wired path carried what was sent; before and after it, wifi.
    let during_wired = on.get(&(true, "wired".to_string())).copied().unwrap_or(0);
    let during_wifi = on.get(&(true, "wifi".to_string())).copied().unwrap_or(0);
    let outside_wifi = on.get(&(false, "wifi".to_string())).copied().unwrap_or(0);
    assert!(during_wired > 150 && during_wifi == 0, "{on:?}");
    assert!(outside_wifi > 400, "{on:?}");
    println!(
        "transports of the outcomes (during the outage, transport): {on:?}; switches {switches:?}"
    );
    let paths = a_sys.paths("B");
    assert_eq!(paths.len(), 2);
    assert_eq!(
        (paths[0].transport.as_str(), paths[1].transport.as_str()),
        ("wifi", "wired")
    );
}

#[test]
fn a_pair_s_transports_change_while_running() {
    let f = fleet(600_000, 1_000);
    let a_sys = f.system("A").unwrap();
    let a = a_sys.module("M").unwrap();
    let b = f.system("B").unwrap().module("M").unwrap();
    let send = |i: u32| {
        let t = a
            .send_raw("B", "M", TY, &i.to_le_bytes(), Default::default())
            .unwrap();
        let o = t.wait_timeout(Duration::from_secs(5)).expect("an outcome");
        assert!(matches!(o, Outcome::Delivered { .. }), "send {i}: {o}");
        t.transport().expect("names its transport").to_string()
    };
    assert_eq!(send(0), "wifi");
    // Several consumers, each sees every switch: two watches (one read while switches
    // happen), an observer, the stats, and `path_changes`.
    let watch = a_sys.watch_paths();
    let early = a_sys.watch_paths();
    #[derive(Default)]
    struct Seen(std::sync::Mutex<Vec<(String, String, String, u64)>>);
    impl hetcomm::Observer for Seen {
        fn on_path_change(&self, r: &hetcomm::observe::PathChangeRecord<'_>) {
            let row = (r.to_name.into(), r.from.into(), r.now.into(), r.number);
            self.0.lock().unwrap().push(row);
        }
    }
    let seen = std::sync::Arc::new(Seen::default());
    let _observing = a_sys.observe(seen.clone());
    a_sys.set_transports("B", &["wired"]).unwrap();
    let first = early
        .next_timeout(Duration::from_secs(1))
        .expect("a switch");
    assert_eq!((first.from.as_str(), first.now.as_str()), ("wifi", "wired"));
    assert_eq!(send(1), "wired");
    assert_eq!(a_sys.paths("B").len(), 1);
    a_sys.set_transports("B", &["wifi", "wired"]).unwrap();
    assert_eq!(send(2), "wifi");
    let moves: Vec<(String, String)> = a_sys
        .path_changes()
        .into_iter()
        .map(|c| (c.from, c.now))
        .collect();
    let expected =
        [("wifi", "wired"), ("wired", "wifi")].map(|(x, y)| (x.to_string(), y.to_string()));
    assert_eq!(moves, expected);
    let watched: Vec<(String, String)> =
        watch.drain().into_iter().map(|c| (c.from, c.now)).collect();
    assert_eq!(watched, expected);
    let rest: Vec<(String, String)> = early.drain().into_iter().map(|c| (c.from, c.now)).collect();
    assert_eq!(rest, expected[1..]);
    let observed = seen.0.lock().unwrap().clone();
    assert_eq!(
        observed,
        [("B", "wifi", "wired", 1), ("B", "wired", "wifi", 2)].map(|(a, b, c, n)| (
            a.to_string(),
            b.to_string(),
            c.to_string(),
            n
        ))
    );
    let in_stats: Vec<(String, String)> = a_sys
        .stats()
        .path_switches
        .into_iter()
        .map(|c| (c.from, c.now))
        .collect();
    assert_eq!(in_stats, expected);
    assert!(
        a_sys.path_changes().is_empty(),
        "path_changes returns each switch once"
    );
    assert_eq!(watch.dropped(), 0);
    // Refused, and nothing changes: a transport outside the pair's cell, an unknown system.
    let err = a_sys.set_transports("B", &["udp"]).unwrap_err();
    assert!(
        matches!(err, hetcomm::PathsError::NotListed { .. }),
        "{err}"
    );
    assert!(err.to_string().contains("lists `wifi,wired`"), "{err}");
    assert!(a_sys.set_transports("Zulu", &["wifi"]).is_err());
    assert!(a_sys.set_transports("B", &[]).is_err());
    assert_eq!(send(3), "wifi");
    for i in 0..4u32 {
        let m = b.recv_raw_timeout(Some(Duration::from_secs(2))).unwrap();
        assert_eq!(m.payload, i.to_le_bytes());
    }
}

#[test]
fn a_reloaded_fleet_applies_live_or_changes_nothing_and_says_why() {
    let text = fleet_text(600_000, 1_000);
    let parse = |t: &str| {
        hetcomm::config::parse_str(t, "reloaded.toml", None).unwrap_or_else(|e| panic!("{e}"))
    };
    let f = LocalFleet::open(parse(&text)).unwrap();
    // The same file with both cells changed to `cell`.
    let with_cell = |cell: &str| text.replace("\"wifi,wired\"", &format!("\"{cell}\""));
    let a_sys = f.system("A").unwrap();
    let a = a_sys.module("M").unwrap();
    let _b = f.system("B").unwrap().module("M").unwrap();
    let send = |i: u32| {
        let t = a
            .send_raw("B", "M", TY, &i.to_le_bytes(), Default::default())
            .unwrap();
        let o = t.wait_timeout(Duration::from_secs(5)).expect("an outcome");
        assert!(matches!(o, Outcome::Delivered { .. }), "send {i}: {o}");
        t.transport().expect("names its transport").to_string()
    };
    assert_eq!(send(0), "wifi");
    // Valid: the pair's cell reordered; applied live, the difference listed.
    let r = a_sys
        .reload_fleet(&parse(&with_cell("wired,wifi")))
        .unwrap();
    assert_eq!(
        r.changes,
        [
            "pair A -> B: wifi,wired -> wired,wifi",
            "pair B -> A: wifi,wired -> wired,wifi"
        ]
    );
    assert_eq!(
        r.applied,
        [(
            "B".to_string(),
            vec!["wired".to_string(), "wifi".to_string()]
        )]
    );
    assert_eq!(send(1), "wired");
    assert_eq!(a_sys.paths("B")[0].transport, "wired");
    // Invalid: a new system A would send to. Refused, nothing changes.
    let with_c = with_cell("wifi,wired")
        .replace("B = 1\n", "B = 1\nC = 2\n")
        .replace(
            "columns = [\"A\", \"B\"]",
            "columns = [\"A\", \"B\", \"C\"]",
        )
        .replace(
            "A = [\"X\", \"wifi,wired\"]",
            "A = [\"X\", \"wifi,wired\", \"wired\"]",
        )
        .replace(
            "B = [\"wifi,wired\", \"X\"]",
            "B = [\"wifi,wired\", \"X\", \"X\"]\nC = [\"wired\", \"X\", \"X\"]",
        )
        .replace("B = \"127.0.0.1:", "C = \"127.0.0.1:1\", B = \"127.0.0.1:");
    let err = a_sys.reload_fleet(&parse(&with_c)).unwrap_err();
    let hetcomm::ReloadError::Refused { reasons, changes } = &err else {
        panic!("{err}")
    };
    assert!(
        reasons.iter().any(|r| r.contains("system `C` is new")),
        "{reasons:?}"
    );
    assert!(
        changes
            .iter()
            .any(|c| c.contains("system `C` (id 2) added")),
        "{changes:?}"
    );
    assert!(
        err.to_string().starts_with("refused, nothing changed"),
        "{err}"
    );
    assert_eq!(send(2), "wired", "the refused reload moved nothing");
    // A changed id; a transport not open for the pair: refused, each with its reason.
    let err = a_sys
        .reload_fleet(&parse(&text.replace("B = 1\n", "B = 7\n")))
        .unwrap_err()
        .to_string();
    assert!(err.contains("system `B` changes id (1 -> 7)"), "{err}");
    let err = a_sys
        .reload_fleet(&parse(&with_cell("wifi,udp")))
        .unwrap_err()
        .to_string();
    assert!(
        err.contains("`udp` not open for this pair here (it opened wifi,wired)"),
        "{err}"
    );
    assert_eq!(send(3), "wired");
    // A file that does not load: its errors, nothing changed.
    let broken = std::env::temp_dir().join(format!("hetcomm-reload-{}.toml", std::process::id()));
    std::fs::write(&broken, with_cell("wifi,nope")).unwrap();
    let err = a_sys.reload(&broken).unwrap_err();
    assert!(matches!(err, hetcomm::ReloadError::Config(_)), "{err}");
    assert!(err.to_string().contains("nope"), "{err}");
    std::fs::remove_file(&broken).ok();
    assert_eq!(send(4), "wired");
    // Compared with the last one applied: the first order again.
    let r = a_sys.reload_fleet(&parse(&text)).unwrap();
    assert_eq!(r.applied.len(), 1);
    assert_eq!(send(5), "wifi");
    let switches: Vec<(String, String)> = a_sys
        .path_changes()
        .into_iter()
        .map(|c| (c.from, c.now))
        .collect();
    let expected =
        [("wifi", "wired"), ("wired", "wifi")].map(|(x, y)| (x.to_string(), y.to_string()));
    assert_eq!(switches, expected);
}

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
    let (ua, ub) = (free_udp_port(), free_udp_port());
    let (ta, tb) = (free_tcp_port(), free_tcp_port());
    let text = format!(
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
    );
    let fleet =
        hetcomm::config::parse_str(&text, "failover.toml", None).unwrap_or_else(|e| panic!("{e}"));
    LocalFleet::open(fleet).unwrap_or_else(|e| panic!("{e}"))
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
    a_sys.set_transports("B", &["wired"]).unwrap();
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

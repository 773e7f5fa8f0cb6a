//! The `zenoh` kind through the facade: fleet-file keys and their located errors, opening
//! errors, acknowledged and unacknowledged delivery between systems that find each other
//! through a router, presence making a send to a system that left fail at once, and a
//! malformed put counted and dropped.

mod common;

use std::time::{Duration, Instant};

use hetcomm::{Comm, Outcome, SendOptions};
use hetcomm_link_zenoh::{data_key, Mode, ZenohSettings};
use zenoh::Wait;

/// A fleet of A and B on one zenoh transport `z` with `keys`. Unsecured: these tests look at
/// the transport (a malformed put must reach its counters); the secured path over zenoh runs
/// in the conformance suite and the multi-host script.
fn fleet_text(keys: &str) -> String {
    format!(
        r#"[systems]
A = 0
B = 1
[modules]
M = 0
[transports.z]
kind = "zenoh"
{keys}
security = "none"
[table]
columns = ["A", "B"]
A = ["X", "z"]
B = ["z", "X"]
"#
    )
}

fn client_keys(endpoint: &str, prefix: &str, more: &str) -> String {
    format!(
        "mode = \"client\"\nconnect = [\"{endpoint}\"]\nmulticast_scouting = false\nprefix = \"{prefix}\"\n{more}"
    )
}

fn open_pair(keys: &str) -> (Comm, Comm) {
    let fleet = hetcomm::parse_fleet(&fleet_text(keys), "z.toml", None).expect("valid fleet");
    let a = Comm::open_fleet(&fleet, "A").expect("open A");
    let b = Comm::open_fleet(&fleet, "B").expect("open B");
    (a, b)
}

#[test]
fn the_keys_parse_into_settings_and_their_mistakes_are_located() {
    let text = fleet_text(
        "mode = \"client\"\nconnect = [\"tcp/10.0.0.1:7447\"]\nprefix = \"site-a/fleet\"\npresence_timeout_ms = 500",
    );
    let fleet = hetcomm::parse_fleet(&text, "z.toml", None).expect("valid");
    let hetcomm::config::TransportSettings::Registered(s) = &fleet.transports[0].settings else {
        panic!("registered settings expected");
    };
    assert_eq!(
        s.downcast_ref::<ZenohSettings>(),
        Some(&ZenohSettings {
            mode: Mode::Client,
            connect: vec!["tcp/10.0.0.1:7447".into()],
            prefix: "site-a/fleet".into(),
            presence_timeout_ms: 500,
            ..ZenohSettings::default()
        })
    );

    let errors = |keys: &str| {
        hetcomm::parse_fleet(&fleet_text(keys), "z.toml", None)
            .unwrap_err()
            .to_string()
    };
    assert_eq!(
        errors("prefix = \"fleet/*\""),
        "z.toml:8:10: `prefix` is not a usable Zenoh key expression: the prefix may not contain wildcards (`*`, `**`, `$*`)\n  \
         help: use chunks of letters, digits, `-`, `_` and `.` separated by `/`, e.g. \"hetcomm/site-a\""
    );
    let e = errors("prefix = \"a//b\"");
    assert!(
        e.starts_with("z.toml:8:10: `prefix` is not a usable Zenoh key expression: Zenoh rejects `a//b/sys/x`"),
        "{e}"
    );
    assert_eq!(
        errors("mode = \"clinet\""),
        "z.toml:8:8: unknown mode `clinet`\n  help: did you mean `client`? valid modes: peer, client"
    );
    assert_eq!(
        errors("mode = \"client\"\nlisten = [\"tcp/0.0.0.0:7447\"]"),
        "z.toml:9:10: a Zenoh client does not listen\n  help: leave `listen` out, or use `mode = \"peer\"`"
    );
    assert_eq!(
        errors("connect = \"tcp/10.0.0.1:7447\""),
        "z.toml:8:11: `transports.z.connect` must be an array of strings, found string `\"tcp/10.0.0.1:7447\"`\n  \
         help: a list of Zenoh endpoints, e.g. [\"tcp/192.168.1.10:7447\"]"
    );
    let e = errors("connect = [\"udp/10.0.0.1:7447\"]");
    assert!(
        e.starts_with("z.toml:8:11: `udp/10.0.0.1:7447`: this build carries Zenoh over `tcp/…` endpoints only"),
        "{e}"
    );
    assert_eq!(
        errors("mode = \"client\"\nmulticast_scouting = false"),
        "z.toml:6:1: a Zenoh client needs a router: `connect` is empty and multicast scouting is off\n  \
         help: add `connect = [\"tcp/ROUTER:7447\"]`"
    );
    let e = errors("prefx = \"x\"");
    assert!(
        e.contains("unknown key `prefx`") && e.contains("did you mean `prefix`"),
        "{e}"
    );
}

#[test]
fn an_unreachable_router_fails_the_open_within_seconds_naming_it() {
    let endpoint = format!("tcp/127.0.0.1:{}", common::free_port());
    let keys = client_keys(
        &endpoint,
        &common::unique_prefix(),
        "open_timeout_ms = 1000",
    );
    let fleet = hetcomm::parse_fleet(&fleet_text(&keys), "z.toml", None).expect("valid");
    let started = Instant::now();
    let Err(err) = Comm::open_fleet(&fleet, "A") else {
        panic!("no router listens there: opening must fail");
    };
    let text = err.to_string();
    assert!(
        started.elapsed() < Duration::from_secs(5),
        "took {:?}",
        started.elapsed()
    );
    assert!(
        text.contains(&endpoint) && text.contains("did not answer"),
        "{text}"
    );
}

#[test]
fn acknowledged_sends_are_delivered_and_a_system_that_left_fails_at_once() {
    let (_router, endpoint) = common::router();
    let (a, b) = open_pair(&client_keys(&endpoint, &common::unique_prefix(), ""));
    let from = a.module("M").unwrap();
    let to = b.module("M").unwrap();
    for i in 0..20u8 {
        let outcome = from
            .send_raw(
                "B",
                "M",
                hetcomm::MessageType(7),
                &[0x91, i],
                SendOptions::default(),
            )
            .expect("send")
            .wait();
        assert!(matches!(outcome, Outcome::Delivered { .. }), "{outcome}");
        let got = to
            .recv_raw_timeout(Some(Duration::from_secs(5)))
            .expect("recv");
        assert_eq!(got.payload, [0x91, i]);
    }
    drop(to);
    drop(b);
    // Once A has seen B's token go, a send fails at once, saying why.
    let deadline = Instant::now() + Duration::from_secs(10);
    loop {
        let started = Instant::now();
        let outcome = from
            .send_raw(
                "B",
                "M",
                hetcomm::MessageType(7),
                &[0x90],
                SendOptions::default(),
            )
            .expect("send")
            .wait();
        match outcome {
            Outcome::Failed { reason, .. } if reason.to_string().contains("is absent") => {
                assert!(
                    started.elapsed() < Duration::from_millis(500),
                    "{:?}",
                    started.elapsed()
                );
                assert!(reason.to_string().contains("liveliness token"), "{reason}");
                break;
            }
            // Sent while B was still seen: may end unconfirmed, never delivered.
            Outcome::Delivered { .. } => panic!("delivered to a closed system"),
            _ => assert!(Instant::now() < deadline, "B never seen leaving: {outcome}"),
        }
    }
}

#[test]
fn unacknowledged_sends_are_sent_and_arrive_between_peers_through_a_router() {
    let (_router, endpoint) = common::router();
    let keys = format!(
        "mode = \"peer\"\nconnect = [\"{endpoint}\"]\nlisten = [\"tcp/127.0.0.1:0\"]\nmulticast_scouting = false\nprefix = \"{}\"\ndelivery = \"unacknowledged\"",
        common::unique_prefix()
    );
    let (a, b) = open_pair(&keys);
    let from = a.module("M").unwrap();
    let to = b.module("M").unwrap();
    for i in 0..50u8 {
        let outcome = from
            .send_raw(
                "B",
                "M",
                hetcomm::MessageType(7),
                &[0x91, i],
                SendOptions::default(),
            )
            .expect("send")
            .wait();
        assert!(matches!(outcome, Outcome::Sent { .. }), "{outcome}");
    }
    let mut got = Vec::new();
    while got.len() < 50 {
        match to.recv_raw_timeout(Some(Duration::from_secs(5))) {
            Ok(m) => got.push(m.payload[1]),
            Err(e) => panic!("after {} messages: {e:?}", got.len()),
        }
    }
    got.sort_unstable();
    assert_eq!(got, (0..50).collect::<Vec<u8>>());
}

/// A plain Zenoh client of the router at `endpoint` (not a hetcomm system).
fn raw_client(endpoint: &str) -> zenoh::Session {
    let mut c = zenoh::Config::default();
    c.insert_json5("mode", "\"client\"").unwrap();
    c.insert_json5("connect/endpoints", &format!("[\"{endpoint}\"]"))
        .unwrap();
    c.insert_json5("scouting/multicast/enabled", "false")
        .unwrap();
    zenoh::open(c).wait().expect("raw session")
}

#[test]
fn a_malformed_put_is_counted_and_dropped() {
    let (_router, endpoint) = common::router();
    let prefix = common::unique_prefix();
    let (a, b) = open_pair(&client_keys(&endpoint, &prefix, ""));
    // A plain Zenoh client puts bytes that are not a frame on B's key.
    let raw = raw_client(&endpoint);
    let key = data_key(&prefix, "B");
    let deadline = Instant::now() + Duration::from_secs(10);
    while b.stats().router.malformed == 0 {
        assert!(
            Instant::now() < deadline,
            "the malformed put was not counted"
        );
        raw.put(&key, b"not a frame".to_vec()).wait().expect("put");
        std::thread::sleep(Duration::from_millis(50));
    }
    // B still takes real frames.
    let outcome = a
        .module("M")
        .unwrap()
        .send_raw(
            "B",
            "M",
            hetcomm::MessageType(7),
            &[0xc0],
            SendOptions::default(),
        )
        .unwrap()
        .wait();
    assert!(matches!(outcome, Outcome::Delivered { .. }), "{outcome}");
    let _ = raw.close().wait();
}

/// A put may carry several frames as a batch (docs/zenoh.md: the UDP batch layout): a plain
/// Zenoh client puts two data frames from A in one put on B's key, and B's module takes both,
/// in order.
#[test]
fn a_batch_of_frames_in_one_put_is_delivered_frame_by_frame() {
    use hetcomm_core::wire::{self, Header};
    use hetcomm_core::{Address, ModuleId, SystemId};
    let (_router, endpoint) = common::router();
    let prefix = common::unique_prefix();
    let fleet = hetcomm::parse_fleet(
        &fleet_text(&client_keys(&endpoint, &prefix, "")),
        "z.toml",
        None,
    )
    .expect("valid fleet");
    let b = Comm::open_fleet(&fleet, "B").expect("open B");
    let m = b.module("M").unwrap();
    let raw = raw_client(&endpoint);
    // The batch header: "HB", version 1, a reserved zero; then (u32 length, frame) records.
    let mut put = b"HB\x01\x00".to_vec();
    for seq in 1..=2u64 {
        let mut h = Header::data(
            Address {
                system: SystemId(0),
                module: ModuleId(0),
            },
            Address {
                system: SystemId(1),
                module: ModuleId(0),
            },
            hetcomm_core::MessageType(9),
        );
        h.seq = seq;
        h.incarnation = 7;
        // MessagePack `false` and `true`.
        let frame = wire::encode(&h, &[0xc1 + seq as u8]);
        put.extend_from_slice(&(frame.len() as u32).to_le_bytes());
        put.extend_from_slice(&frame);
    }
    // Until B's subscription has reached the router, a put may go nowhere: repeat it (B
    // drops the duplicates) until the first frame arrives.
    let deadline = Instant::now() + Duration::from_secs(10);
    let first = loop {
        raw.put(data_key(&prefix, "B"), put.clone())
            .wait()
            .expect("put");
        if let Ok(msg) = m.recv_raw_timeout(Some(Duration::from_millis(100))) {
            break msg;
        }
        assert!(Instant::now() < deadline, "nothing arrived");
    };
    let second = m
        .recv_raw_timeout(Some(Duration::from_secs(5)))
        .expect("the second frame of the put");
    assert_eq!(
        (&first.payload[..], &second.payload[..]),
        (&[0xc2][..], &[0xc3][..])
    );
    assert_eq!(b.stats().router.malformed, 0);
    let _ = raw.close().wait();
}

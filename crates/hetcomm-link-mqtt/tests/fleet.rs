//! The `mqtt` kind through the facade, against a real mosquitto: fleet-file keys and their
//! located errors, an unreachable broker, acknowledged and unacknowledged delivery at both
//! QoS levels, presence (a closed system and a vanished one fail at once, saying why), and bad
//! input: a malformed frame, a retained garbage message, an oversized message.

mod common;

use std::time::{Duration, Instant};

use common::fleet::{eventually, keys, open, open_pair, send, RawClient};
use common::{broker, unique_fleet, Mosquitto};
use hetcomm::{MessageType, Outcome, SendError, SendOptions};
use hetcomm_link_mqtt::{data_topic, presence_topic, Broker, MqttSettings, Qos};
use rumqttc::v5::mqttbytes::v5::LastWill;
use rumqttc::v5::mqttbytes::QoS;

#[test]
fn the_keys_parse_into_settings_and_their_mistakes_are_located() {
    let text = common::fleet::fleet_text(
        "brokers = [\"mqtt://10.0.0.1:1884\", \"mqtts://b.lan\"]\nprefix = \"site-a/robots\"\nqos = 0\n\
         clean_session = false\nsession_expiry_s = 60\nusername = \"u\"\npassword = \"p\"\n\
         ca_file = \"/etc/ca.pem\"\nkeep_alive_s = 30",
    );
    let fleet = hetcomm::parse_fleet(&text, "m.toml", None).expect("valid");
    let hetcomm::config::TransportSettings::Registered(s) = &fleet.transports[0].settings else {
        panic!("registered settings expected");
    };
    let b = |t: &str| Broker::parse(t).unwrap();
    assert_eq!(
        s.downcast_ref::<MqttSettings>(),
        Some(&MqttSettings {
            brokers: vec![b("mqtt://10.0.0.1:1884"), b("mqtts://b.lan:8883")],
            prefix: "site-a/robots".into(),
            qos: Qos::AtMostOnce,
            clean_session: false,
            session_expiry_s: 60,
            username: Some("u".into()),
            password: Some("p".into()),
            ca_file: Some("/etc/ca.pem".into()),
            keep_alive_s: 30,
            ..MqttSettings::default()
        })
    );

    let errors = |keys: &str| {
        hetcomm::parse_fleet(&common::fleet::fleet_text(keys), "m.toml", None)
            .unwrap_err()
            .to_string()
    };
    assert_eq!(
        errors("prefix = \"x\""),
        "m.toml:6:1: transport `m` (kind mqtt) is missing required setting `broker`\n  \
         help: add `broker = \"mqtt://127.0.0.1:1883\"`"
    );
    assert_eq!(
        errors("broker = \"ws://b:80\""),
        "m.toml:8:10: `ws://b:80`: unknown scheme `ws://` (this build speaks `mqtt://` and `mqtts://`)\n  \
         help: write the broker's address, e.g. \"mqtt://192.168.1.10:1883\" (or \"mqtts://…\" for TLS)"
    );
    assert_eq!(
        errors("broker = \"b\"\nqos = 2"),
        "m.toml:9:7: `transports.m.qos` must be from 0 to 1, found 2\n  \
         help: 0 (at most once) or 1 (at least once; the broker acknowledges each publish)"
    );
    assert_eq!(
        errors("broker = \"b\"\nprefix = \"a/+/b\""),
        "m.toml:9:10: `prefix` is not usable in MQTT topics: MQTT wildcards (`+`, `#`) cannot be part of a topic name\n  \
         help: use levels of letters, digits, `-`, `_` and `.` separated by `/`, e.g. \"hetcomm/site-a\""
    );
    assert_eq!(
        errors("broker = \"b\"\npassword = \"p\""),
        "m.toml:9:12: a `password` without a `username`\n  help: add `username = \"…\"`"
    );
    assert_eq!(
        errors("broker = \"b\"\nclient_cert_file = \"c.pem\""),
        "m.toml:9:20: `client_cert_file` without `client_key_file`\n  \
         help: add `client_key_file`: a client certificate needs its private key, and the other way round"
    );
    assert_eq!(
        errors("broker = \"b\"\nsession_expiry_s = 5"),
        "m.toml:9:20: `session_expiry_s` applies to persistent sessions only\n  \
         help: add `clean_session = false`, or leave `session_expiry_s` out"
    );
    assert_eq!(
        errors("broker = \"b\"\nkeep_alive_s = 1"),
        "m.toml:9:16: `transports.m.keep_alive_s` must be from 5 to 65535, found 1\n  \
         help: seconds; the broker declares a silent system gone after 1.5 times this"
    );
    let e = errors("broker = \"b\"\nbrokr = \"x\"");
    assert!(
        e.contains("m.toml:9:1")
            && e.contains("unknown key `brokr`")
            && e.contains("did you mean `broker`"),
        "{e}"
    );
}

#[test]
fn an_unreachable_broker_fails_the_open_within_seconds_naming_it() {
    let address = format!("127.0.0.1:{}", common::free_port());
    let keys = keys(&address, &unique_fleet(), "open_timeout_ms = 1000");
    let fleet = hetcomm::parse_fleet(&common::fleet::fleet_text(&keys), "m.toml", None).unwrap();
    let started = Instant::now();
    let Err(err) = hetcomm::Comm::open_fleet(&fleet, "A") else {
        panic!("no broker listens there: opening must fail");
    };
    let text = err.to_string();
    assert!(
        started.elapsed() < Duration::from_secs(3),
        "took {:?}",
        started.elapsed()
    );
    assert!(
        text.contains(&format!("mqtt://{address}")) && text.contains("within 1000 ms"),
        "{text}"
    );
}

fn delivers_acknowledged(qos: u8) {
    let (a, b) = open_pair(&keys(&broker(), &unique_fleet(), &format!("qos = {qos}")));
    let (from, to) = (a.module("M").unwrap(), b.module("M").unwrap());
    for i in 0..30u8 {
        let outcome = send(&from, i);
        assert!(matches!(outcome, Outcome::Delivered { .. }), "{outcome}");
        let got = to
            .recv_raw_timeout(Some(Duration::from_secs(5)))
            .expect("recv");
        assert_eq!(got.payload, [0x91, i]);
    }
}

#[test]
fn acknowledged_sends_are_delivered_at_qos_0_and_1() {
    delivers_acknowledged(0);
    delivers_acknowledged(1);
}

/// Unacknowledged: at QoS 0 every send ends *sent* (the broker confirms nothing); at QoS 1
/// *relayed*, the broker's PUBACK for that very publish having come (which is not a delivery);
/// every message arrives on loopback.
#[test]
fn unacknowledged_sends_are_sent_at_qos_0_and_relayed_at_qos_1() {
    for qos in [0, 1] {
        let more = format!("qos = {qos}\ndelivery = \"unacknowledged\"");
        let (a, b) = open_pair(&keys(&broker(), &unique_fleet(), &more));
        let (from, to) = (a.module("M").unwrap(), b.module("M").unwrap());
        for i in 0..50u8 {
            let outcome = send(&from, i);
            match qos {
                0 => assert_eq!(outcome, Outcome::Sent { attempts: 1 }, "{outcome}"),
                _ => assert_eq!(outcome, Outcome::Relayed { attempts: 1 }, "{outcome}"),
            }
        }
        // Sends in a burst, their receipts waiting together: each ends relayed (each
        // PUBACK matched to its own publish).
        let burst: Vec<_> = (50..100u8)
            .map(|i| {
                from.send_raw("B", "M", MessageType(7), &[0x91, i], SendOptions::default())
                    .expect("send")
            })
            .collect();
        for t in burst {
            let outcome = t.wait();
            match qos {
                0 => assert_eq!(outcome, Outcome::Sent { attempts: 1 }, "{outcome}"),
                _ => assert_eq!(outcome, Outcome::Relayed { attempts: 1 }, "{outcome}"),
            }
        }
        let mut got: Vec<u8> = (0..100)
            .map(|_| {
                to.recv_raw_timeout(Some(Duration::from_secs(5)))
                    .expect("recv")
                    .payload[1]
            })
            .collect();
        got.sort_unstable();
        assert_eq!(got, (0..100).collect::<Vec<u8>>());
        let sent = a.stats().links[0].1.frames_sent;
        assert_eq!(sent, 100, "qos {qos}");
    }
}

/// An unacknowledged broadcast on an unsecured transport is one publish on `@all` (one frame
/// for every destination): at QoS 1 the broker's PUBACK for it is every share's verdict, so
/// each share ends *relayed*; at QoS 0 each ends *sent*. Every destination gets the message.
#[test]
fn a_broadcasts_shares_are_relayed_at_qos_1_and_sent_at_qos_0() {
    for qos in [0, 1] {
        let more = format!("qos = {qos}\ndelivery = \"unacknowledged\"");
        let text = common::fleet::fleet_text(&keys(&broker(), &unique_fleet(), &more))
            .replace("B = 1\n", "B = 1\nC = 2\n")
            .replace(
                "columns = [\"A\", \"B\"]\nA = [\"X\", \"m\"]\nB = [\"m\", \"X\"]",
                "columns = [\"A\", \"B\", \"C\"]\nA = [\"X\", \"m\", \"m\"]\n\
                 B = [\"m\", \"X\", \"m\"]\nC = [\"m\", \"m\", \"X\"]",
            );
        let fleet = hetcomm::parse_fleet(&text, "m.toml", None).expect("valid fleet");
        let open = |s: &str| hetcomm::Comm::open_fleet(&fleet, s).expect("open");
        let (a, b, c) = (open("A"), open("B"), open("C"));
        let from = a.module("M").unwrap();
        for i in 0..20u8 {
            let shares = from
                .broadcast_raw("M", MessageType(7), &[0x91, i], SendOptions::default())
                .expect("broadcast")
                .wait();
            let names: Vec<&str> = shares.iter().map(|(n, _)| n.as_str()).collect();
            assert_eq!(names, ["B", "C"], "broadcast {i}");
            for (to, outcome) in shares {
                let expected = match qos {
                    0 => Outcome::Sent { attempts: 1 },
                    _ => Outcome::Relayed { attempts: 1 },
                };
                assert_eq!(outcome, expected, "broadcast {i} to {to}: {outcome}");
            }
            for sys in [&b, &c] {
                let got = sys
                    .module("M")
                    .unwrap()
                    .recv_raw_timeout(Some(Duration::from_secs(5)));
                assert_eq!(got.expect("the broadcast").payload, [0x91, i]);
            }
        }
        // One frame per broadcast: the native path, not a send per destination.
        assert_eq!(a.stats().links[0].1.frames_sent, 20, "qos {qos}");
    }
}

/// Secured (the default: frames sealed inside the publishes), unacknowledged at QoS 1: every
/// send ends *relayed*, the security layer passing the broker's receipt for the sealed frame up
/// to the outcome, the first one's too, which waited for the pair's handshake.
#[test]
fn secured_unacknowledged_sends_at_qos_1_are_relayed() {
    let more = "qos = 1\ndelivery = \"unacknowledged\"";
    let text = common::fleet::fleet_text(&keys(&broker(), &unique_fleet(), more))
        .replace("security = \"none\"\n", "");
    let fleet = hetcomm::parse_fleet(&text, "m.toml", None).expect("valid fleet");
    let local = hetcomm::LocalFleet::open(fleet).expect("open fleet");
    let (a, b) = (local.system("A").unwrap(), local.system("B").unwrap());
    let (from, to) = (a.module("M").unwrap(), b.module("M").unwrap());
    // The first frame waits in the security layer for the handshake: it has not left when the
    // send returns; the layer's receipt for it is kept with the broker's when it leaves.
    let first = send(&from, 0);
    assert_eq!(first, Outcome::Relayed { attempts: 1 }, "{first}");
    let got = to.recv_raw_timeout(Some(Duration::from_secs(10)));
    assert_eq!(got.expect("the first message").payload, [0x91, 0]);
    for i in 1..50u8 {
        let outcome = send(&from, i);
        assert_eq!(
            outcome,
            Outcome::Relayed { attempts: 1 },
            "message {i}: {outcome}"
        );
        let got = to
            .recv_raw_timeout(Some(Duration::from_secs(5)))
            .expect("recv");
        assert_eq!(got.payload, [0x91, i]);
    }
    let security = a.stats().links[0].1.security;
    assert!(
        security.enabled && security.handshakes >= 1,
        "not sealed: {security:?}"
    );
}

/// A secured unacknowledged send whose pair's handshake never completes: the frame waits in
/// the security layer, which gives up after 5 s, and the send ends *failed*, saying the frame
/// never left (not *sent*: nothing left that anyone could receive). A raw client stands in for
/// B: online, with keys in the fleet file, answering nothing.
#[test]
fn a_secured_send_whose_handshake_never_completes_fails_saying_it_never_left() {
    let fleet = unique_fleet();
    let dir = std::env::temp_dir().join(format!("hc-mqtt-keys-{}-{fleet}", std::process::id()));
    std::fs::create_dir_all(&dir).expect("key dir");
    for name in ["A", "B"] {
        let pair = hetcomm_security::Keypair::generate().expect("a key pair");
        pair.write(&dir, name).expect("writing keys");
    }
    let more = "qos = 1\ndelivery = \"unacknowledged\"";
    let text = common::fleet::fleet_text(&keys(&broker(), &fleet, more))
        .replace("security = \"none\"\n", "")
        + &format!("[security]\nkeys = \"{}\"\n", dir.display());
    let b = RawClient::connect(&broker(), &format!("raw-{fleet}-B"), None);
    b.publish(&presence_topic("hetcomm", &fleet, "B"), b"online", true);
    let parsed = hetcomm::parse_fleet(&text, "m.toml", None).expect("valid fleet");
    let a = hetcomm::Comm::open_fleet(&parsed, "A").expect("open A");
    // The retained `online` reaches A when it subscribes; give it that moment.
    std::thread::sleep(Duration::from_millis(300));
    let started = Instant::now();
    let outcome = a
        .module("M")
        .unwrap()
        .send_raw("B", "M", MessageType(7), &[0x91, 1], SendOptions::default())
        .expect("send")
        .wait_timeout(Duration::from_secs(20))
        .expect("an outcome once the layer gives up");
    let waited = started.elapsed();
    let Outcome::Failed { reason, .. } = &outcome else {
        panic!("a frame that never left ended {outcome}");
    };
    let text = reason.to_string();
    assert!(
        text.contains("no secure session with system 1") && text.contains("never left"),
        "{text}"
    );
    assert!(waited >= Duration::from_secs(4), "gave up after {waited:?}");
    assert_eq!(a.stats().links[0].1.security.handshake_timeouts, 1);
    b.disconnect();
    let _ = std::fs::remove_dir_all(&dir);
}

#[test]
fn a_closed_system_fails_at_once_saying_so() {
    let fleet = unique_fleet();
    let (a, b) = open_pair(&keys(&broker(), &fleet, ""));
    let from = a.module("M").unwrap();
    assert!(matches!(send(&from, 1), Outcome::Delivered { .. }));
    drop(b);
    let mut reason = String::new();
    eventually(10, "B seen closing", || {
        let started = Instant::now();
        match send(&from, 2) {
            Outcome::Failed { reason: r, .. } if r.to_string().contains("is offline") => {
                assert!(
                    started.elapsed() < Duration::from_millis(500),
                    "{:?}",
                    started.elapsed()
                );
                reason = r.to_string();
                true
            }
            Outcome::Delivered { .. } => panic!("delivered to a closed system"),
            _ => false,
        }
    });
    assert!(
        reason.contains(&format!("`hetcomm/{fleet}/@presence/B` says `offline`")),
        "{reason}"
    );
}

/// A system whose connection breaks without a goodbye: the broker publishes its last will
/// (`lost`), and sends to it fail at once, saying so. A raw client stands in for it.
#[test]
fn a_vanished_system_is_declared_lost_by_its_last_will() {
    let fleet = unique_fleet();
    let a = open(&keys(&broker(), &fleet, ""), "A");
    let topic = presence_topic("hetcomm", &fleet, "B");
    let will = LastWill::new(topic.clone(), "lost", QoS::AtLeastOnce, true, None);
    let b = RawClient::connect(&broker(), &format!("raw-{fleet}-B"), Some(will));
    b.publish(&topic, b"online", true);
    let from = a.module("M").unwrap();
    // B is online: A publishes to it (it never acknowledges: a raw client).
    eventually(10, "B seen online", || {
        matches!(send(&from, 1), Outcome::Unconfirmed { .. })
    });
    b.vanish();
    let mut reason = String::new();
    eventually(10, "B's last will seen", || match send(&from, 2) {
        Outcome::Failed { reason: r, .. } if r.to_string().contains("last will") => {
            reason = r.to_string();
            true
        }
        _ => false,
    });
    assert!(reason.contains("says `lost`"), "{reason}");
}

#[test]
fn a_malformed_frame_is_counted_and_dropped() {
    let fleet = unique_fleet();
    let (a, b) = open_pair(&keys(&broker(), &fleet, ""));
    let raw = RawClient::connect(&broker(), &format!("raw-{fleet}"), None);
    raw.publish(&data_topic("hetcomm", &fleet, "B"), b"not a frame", false);
    eventually(10, "the malformed frame counted", || {
        b.stats().router.malformed == 1
    });
    // B still takes real frames.
    let outcome = send(&a.module("M").unwrap(), 3);
    assert!(matches!(outcome, Outcome::Delivered { .. }), "{outcome}");
    raw.disconnect();
}

/// A retained message on a system's topic is replayed to it whenever it subscribes: the link
/// drops it (counted) and the system works as ever.
#[test]
fn a_retained_garbage_message_does_not_wedge_a_system() {
    let fleet = unique_fleet();
    let topic = data_topic("hetcomm", &fleet, "B");
    let raw = RawClient::connect(&broker(), &format!("raw-{fleet}"), None);
    raw.publish(&topic, b"\xff\xfe retained garbage", true);
    raw.publish(&data_topic("hetcomm", &fleet, "@all"), b"HC garbage", true);
    std::thread::sleep(Duration::from_millis(200));
    let (a, b) = open_pair(&keys(&broker(), &fleet, ""));
    eventually(10, "the retained messages dropped", || {
        b.stats().links[0].1.frames_dropped == 2
    });
    assert_eq!(
        b.stats().router.malformed,
        0,
        "retained frames never reach the router"
    );
    let from = a.module("M").unwrap();
    for i in 0..5 {
        assert!(matches!(send(&from, i), Outcome::Delivered { .. }));
    }
    // Clear them (an empty retained publish), as an operator would.
    raw.publish(&topic, b"", true);
    raw.publish(&data_topic("hetcomm", &fleet, "@all"), b"", true);
    raw.disconnect();
}

/// A broker with a Maximum Packet Size (mosquitto's `max_packet_size`, sent in its CONNACK):
/// the link's largest frame is what it leaves after the publish's own bytes, and a larger
/// message is refused at the send, before anything is published.
#[test]
fn an_oversized_message_is_refused_before_publishing_naming_the_brokers_limit() {
    let limit = 65536;
    let small = Mosquitto::start(&format!("max_packet_size {limit}"));
    let fleet = unique_fleet();
    let (a, _b) = open_pair(&keys(&small.address, &fleet, ""));
    let from = a.module("M").unwrap();
    // The longest topic of the fleet: `hetcomm/<fleet>/@all`.
    let overhead = hetcomm_link_mqtt::publish_overhead(&format!("hetcomm/{fleet}/@all"));
    let max = limit - overhead;
    let err = from
        .send_raw(
            "B",
            "M",
            MessageType(7),
            &bin(70_000),
            SendOptions::default(),
        )
        .map(|_| ())
        .expect_err("over the broker's limit");
    match &err {
        SendError::TooLarge { max: m, .. } => assert_eq!(*m, max, "{err}"),
        other => panic!("{other}"),
    }
    assert!(
        err.to_string().contains(&format!("limit of {max} bytes")),
        "{err}"
    );
    assert_eq!(a.stats().links[0].1.frames_sent, 0, "nothing was published");
    // A message that fits goes.
    let fits = bin(max - 48 - 5);
    let outcome = from
        .send_raw("B", "M", MessageType(7), &fits, SendOptions::default())
        .unwrap()
        .wait();
    assert!(matches!(outcome, Outcome::Delivered { .. }), "{outcome}");
}

/// MessagePack bin 32 of `len - 5` bytes: `len` bytes in all.
fn bin(len: usize) -> Vec<u8> {
    let mut v = vec![0xc6];
    v.extend_from_slice(&((len - 5) as u32).to_be_bytes());
    v.resize(len, 0xab);
    v
}

/// Two transports of one fleet on one broker under the same topics would each carry the
/// other's frames: opening refuses, naming both.
#[test]
fn two_transports_under_the_same_topics_are_refused() {
    let fleet_level = unique_fleet();
    let text = format!(
        "[systems]\nA = 0\nB = 1\n[modules]\nM = 0\n\
         [transports.m]\nkind = \"mqtt\"\nbroker = \"{b}\"\nfleet = \"{fleet_level}\"\nsecurity = \"none\"\n\
         [transports.n]\nkind = \"mqtt\"\nbroker = \"{b}\"\nfleet = \"{fleet_level}\"\nsecurity = \"none\"\n\
         [table]\ncolumns = [\"A\", \"B\"]\nA = [\"X\", \"m\"]\nB = [\"n\", \"X\"]\n",
        b = broker()
    );
    let fleet = hetcomm::parse_fleet(&text, "m.toml", None).expect("valid");
    let Err(e) = hetcomm::Comm::open_fleet(&fleet, "A") else {
        panic!("opening must fail");
    };
    let e = e.to_string();
    assert!(
        e.contains(&format!(
            "are both on mqtt://{} under `hetcomm/{fleet_level}`",
            broker()
        )),
        "{e}"
    );
}

/// The same system opened twice: the two clients share a client id and the broker keeps
/// closing one for the other. One of the links stops (rather than taking the id back for
/// ever) and says why; the other then works.
#[test]
fn a_system_opened_twice_stops_one_link_saying_why() {
    let keys = keys(&broker(), &unique_fleet(), "reconnect_wait_ms = 300");
    let (a, _b) = open_pair(&keys);
    let from = a.module("M").unwrap();
    assert!(matches!(send(&from, 1), Outcome::Delivered { .. }));
    let a2 = open(&keys, "A");
    let from2 = a2.module("M").unwrap();
    let mut stopped = None;
    eventually(15, "one A stopped", || {
        for (which, m) in [(1, &from), (2, &from2)] {
            if let Outcome::Failed { reason, .. } = send(m, 2) {
                if reason
                    .to_string()
                    .contains("another client connected with this system's client id")
                {
                    stopped = Some(which);
                    return true;
                }
            }
        }
        false
    });
    // The other works.
    let other = if stopped == Some(1) { &from2 } else { &from };
    eventually(10, "the other A delivers", || {
        matches!(send(other, 3), Outcome::Delivered { .. })
    });
}

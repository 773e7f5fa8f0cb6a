//! The `shm` kind through the facade: its fleet-file keys and their located errors, delivery
//! between two systems, and the security layer it gets: none by default (the kind declares
//! itself host-local through the registry), sealed frames with `[security] in_process = true`.

mod common;

use hetcomm::security::Keypair;
use hetcomm::{Comm, MessageType, Outcome, SendOptions};
use hetcomm_link_shm::ShmSettings;

fn fleet_text(fleet: &str, keys: &str, security: &str) -> String {
    format!(
        r#"name = "{fleet}"
[systems]
A = 0
B = 1
[modules]
M = 0
[transports.s]
kind = "shm"
{keys}
{security}
[table]
columns = ["A", "B"]
A = ["X", "s"]
B = ["s", "X"]
"#
    )
}

#[test]
fn the_keys_parse_into_settings_and_their_mistakes_are_located() {
    let text = fleet_text(
        "f",
        "prefix = \"site/a\"\nqueue_depth = 4\nmax_frame = 65536\nmax_publishers = 5\nsend_wait_ms = 0",
        "",
    );
    let fleet = hetcomm::parse_fleet(&text, "s.toml", None).expect("valid");
    let hetcomm::config::TransportSettings::Registered(s) = &fleet.transports[0].settings else {
        panic!("registered settings expected");
    };
    assert_eq!(
        s.downcast_ref::<ShmSettings>(),
        Some(&ShmSettings {
            prefix: "site/a".into(),
            queue_depth: 4,
            max_frame: 65536,
            // Not given: the default start, cut to `max_frame`.
            initial_frame: 65536,
            max_publishers: Some(5),
            send_wait_ms: 0,
            ..ShmSettings::default()
        })
    );
    let errors = |keys: &str| {
        hetcomm::parse_fleet(&fleet_text("f", keys, ""), "s.toml", None)
            .unwrap_err()
            .to_string()
    };
    let e = errors("queue_depth = 0");
    assert!(
        e.starts_with("s.toml:9:15: `transports.s.queue_depth` must be from 1 to 4096"),
        "{e}"
    );
    let e = errors("prefix = \"a//b\"");
    assert!(
        e.starts_with("s.toml:9:10: `prefix` `a//b`: a `/` may only separate"),
        "{e}"
    );
    let e = errors("initial_frame = 8192\nmax_frame = 4096");
    assert!(
        e.contains("`initial_frame` (8192) is larger than `max_frame` (4096)"),
        "{e}"
    );
    let e = errors("queue = 3");
    assert!(e.contains("queue"), "{e}");
}

fn send(comm: &Comm, i: u8) -> Outcome {
    comm.module("M")
        .unwrap()
        .send_raw("B", "M", MessageType(7), &[0x91, i], SendOptions::default())
        .expect("send")
        .wait()
}

/// No keys anywhere, the default `security = "keys"`: an `shm` transport opens unsealed (a
/// `udp` one would refuse without keys) and delivers.
#[test]
fn shm_is_unsealed_by_default_and_delivers() {
    let name = common::unique_fleet("facade");
    let fleet = hetcomm::parse_fleet(&fleet_text(&name, "", ""), "s.toml", None).unwrap();
    // What `hetcomm validate` says of it: not "secured" (the config crate alone would say so).
    assert_eq!(
        hetcomm::security_lines(&fleet),
        [
            "transport `s` (shm): host-local, not sealed: frames never leave this host and the \
          operating system's permissions guard them (`[security] in_process = true` seals them)"
        ]
    );
    let a = Comm::open_fleet(&fleet, "A").expect("open A without keys");
    let b = Comm::open_fleet(&fleet, "B").expect("open B without keys");
    for i in 0..5 {
        let outcome = send(&a, i);
        assert!(matches!(outcome, Outcome::Delivered { .. }), "{outcome:?}");
        let m = b
            .module("M")
            .unwrap()
            .recv_raw_timeout(Some(std::time::Duration::from_secs(10)))
            .expect("a message");
        assert_eq!(m.payload, vec![0x91, i]);
    }
    let links = a.stats().links;
    assert!(!links.is_empty());
    for (name, l) in &links {
        assert!(!l.security.enabled, "{name}: {l:?}");
        assert!(l.frames_sent >= 5, "{name}: {l:?}");
    }
}

/// `[security] in_process = true` seals `shm` too: without a key it refuses to open; with
/// the systems' keys every frame is sealed and delivered.
#[test]
fn in_process_security_seals_shm() {
    let name = common::unique_fleet("sealed");
    let text = fleet_text(&name, "", "[security]\nin_process = true");
    let mut fleet = hetcomm::parse_fleet(&text, "s.toml", None).unwrap();
    assert!(fleet.secure_in_process);
    assert!(
        hetcomm::security_lines(&fleet)[0].starts_with("transport `s` (shm): secured; "),
        "{:?}",
        hetcomm::security_lines(&fleet)
    );
    let refused = Comm::open_fleet(&fleet, "A")
        .err()
        .expect("no key: refused");
    assert!(refused.to_string().contains("key"), "{refused}");
    let pairs: Vec<Keypair> = (0..2).map(|_| Keypair::generate().unwrap()).collect();
    for (s, pair) in fleet.systems.iter_mut().zip(&pairs) {
        s.public_key = Some(pair.public.0);
    }
    let open = |system: &str, pair: &Keypair| {
        let options = hetcomm::OpenOptions::new().private_key(pair.private.clone());
        Comm::open_fleet_options(&fleet, system, options).expect("open with keys")
    };
    let a = open("A", &pairs[0]);
    let b = open("B", &pairs[1]);
    let outcome = send(&a, 1);
    assert!(matches!(outcome, Outcome::Delivered { .. }), "{outcome:?}");
    assert_eq!(
        b.module("M")
            .unwrap()
            .recv_raw_timeout(Some(std::time::Duration::from_secs(10)))
            .unwrap()
            .payload,
        vec![0x91, 1]
    );
    let (_, l) = &a.stats().links[0];
    assert!(l.security.enabled && l.security.handshakes >= 1, "{l:?}");
}

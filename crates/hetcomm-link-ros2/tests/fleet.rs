//! The `ros2` kind through the facade: fleet-file keys and their located errors, acknowledged
//! delivery between two systems opened one by one (each its own DDS participant), secured by
//! generated keys or with `security = "none"`, and a send to a system that is not running.

use std::time::Duration;

use hetcomm::{Comm, LocalFleet, Message, Outcome};
use hetcomm_link_ros2::{Reliability, Ros2Settings};
use serde::{Deserialize, Serialize};

#[derive(Serialize, Deserialize, Message, Debug, Clone, PartialEq)]
#[message(id = 40)]
struct Ping {
    n: u32,
    text: String,
}

/// A fleet of A and B on one ros2 transport `r` with `keys`.
fn fleet_text(keys: &str) -> String {
    format!(
        r#"[systems]
A = 0
B = 1
[modules]
M = 0
[transports.r]
kind = "ros2"
{keys}
[table]
columns = ["A", "B"]
A = ["X", "r"]
B = ["r", "X"]
"#
    )
}

fn namespace(tag: &str) -> String {
    format!("/fleet_{}_{tag}", std::process::id())
}

#[test]
fn the_keys_parse_into_settings_and_their_mistakes_are_located() {
    let text = fleet_text(
        "domain_id = 7\nnamespace = \"site_a/\"\nreliability = \"best_effort\"\nhistory_depth = 10\n\
         interface = \"127.0.0.1\"\nsame_host = false\nconnect_timeout_ms = 300",
    );
    let fleet = hetcomm::parse_fleet(&text, "r.toml", None).expect("valid");
    let hetcomm::config::TransportSettings::Registered(s) = &fleet.transports[0].settings else {
        panic!("registered settings expected");
    };
    assert_eq!(
        s.downcast_ref::<Ros2Settings>(),
        Some(&Ros2Settings {
            domain_id: 7,
            namespace: "/site_a".into(),
            reliability: Reliability::BestEffort,
            history_depth: 10,
            interface: Some("127.0.0.1".parse().unwrap()),
            same_host: false,
            connect_timeout_ms: 300,
        })
    );
    let defaults = hetcomm::parse_fleet(&fleet_text(""), "r.toml", None).expect("valid");
    let hetcomm::config::TransportSettings::Registered(s) = &defaults.transports[0].settings else {
        panic!("registered settings expected");
    };
    assert_eq!(
        s.downcast_ref::<Ros2Settings>(),
        Some(&Ros2Settings::default())
    );

    let errors = |keys: &str| {
        hetcomm::parse_fleet(&fleet_text(keys), "r.toml", None)
            .unwrap_err()
            .to_string()
    };
    assert_eq!(
        errors("domain_id = 300"),
        "r.toml:8:13: `transports.r.domain_id` must be from 0 to 232, found 300\n  help: a ROS_DOMAIN_ID, e.g. 0"
    );
    assert_eq!(
        errors("namespace = \"/a-b\""),
        "r.toml:8:13: `namespace` \"/a-b\" is not a ROS 2 namespace: only letters, digits, `_` and `/` are allowed\n  \
         help: use letters, digits and underscores between slashes, e.g. \"/fleet_a\""
    );
    let e = errors("reliability = \"reliabel\"");
    assert!(
        e.starts_with("r.toml:8:15: unknown reliability `reliabel`")
            && e.contains("did you mean `reliable`"),
        "{e}"
    );
    assert_eq!(
        errors("interface = \"eth0\""),
        "r.toml:8:13: `interface` \"eth0\" is not an IP address\n  help: write the address of a local interface, e.g. \"10.0.0.2\""
    );
    let e = errors("domian_id = 1");
    assert!(
        e.contains("unknown key `domian_id`") && e.contains("did you mean `domain_id`"),
        "{e}"
    );
}

/// Two processes' worth of systems (each opened on its own, as `hetcomm listen` would), with
/// `security = "none"`: a message arrives and its outcome is Delivered (the router's
/// acknowledgement came back over DDS).
#[test]
fn acknowledged_delivery_between_systems_opened_one_by_one() {
    let keys = format!(
        "domain_id = 63\nnamespace = \"{}\"\nsecurity = \"none\"",
        namespace("open")
    );
    let fleet = hetcomm::parse_fleet(&fleet_text(&keys), "r.toml", None).expect("valid fleet");
    let a = Comm::open_fleet(&fleet, "A").expect("open A");
    let b = Comm::open_fleet(&fleet, "B").expect("open B");
    let (ma, mb) = (a.module("M").unwrap(), b.module("M").unwrap());
    for n in 0..20 {
        let ping = Ping {
            n,
            text: "über DDS".into(),
        };
        let outcome = ma.send("B", "M", &ping).expect("send").wait();
        assert!(
            matches!(outcome, Outcome::Delivered { .. }),
            "send {n}: {outcome:?}"
        );
        let got = mb
            .recv_timeout::<Ping>(Duration::from_secs(5))
            .expect("receive");
        assert_eq!(got.message, ping);
    }
    let stats = a.stats();
    let (name, link) = &stats.links[0];
    assert_eq!(name, "r");
    assert!(
        link.frames_sent >= 20 && link.frames_received >= 20,
        "{link:?}"
    );
    assert_eq!(link.frames_dropped, 0, "{link:?}");
}

/// Without `security = "none"`, the transport leaves the process and is secured: a fleet
/// opened in one process gets generated keys, and messages still arrive, acknowledged.
#[test]
fn a_secured_ros2_fleet_delivers() {
    let keys = format!("domain_id = 64\nnamespace = \"{}\"", namespace("sec"));
    let fleet = hetcomm::parse_fleet(&fleet_text(&keys), "r.toml", None).expect("valid fleet");
    let local = LocalFleet::open(fleet).expect("open fleet");
    let (ma, mb) = (
        local.system("A").unwrap().module("M").unwrap(),
        local.system("B").unwrap().module("M").unwrap(),
    );
    let ping = Ping {
        n: 1,
        text: "secret".into(),
    };
    let outcome = ma.send("B", "M", &ping).expect("send").wait();
    assert!(matches!(outcome, Outcome::Delivered { .. }), "{outcome:?}");
    assert_eq!(
        mb.recv_timeout::<Ping>(Duration::from_secs(5))
            .unwrap()
            .message,
        ping
    );
}

/// A send to a system that is not running: no subscriber is ever matched, the link refuses
/// within `connect_timeout_ms`, and the outcome is Failed (nothing left this system).
#[test]
fn a_send_to_a_system_not_running_fails() {
    let keys = format!(
        "domain_id = 65\nnamespace = \"{}\"\nsecurity = \"none\"\nconnect_timeout_ms = 200",
        namespace("absent")
    );
    let fleet = hetcomm::parse_fleet(&fleet_text(&keys), "r.toml", None).expect("valid fleet");
    let a = Comm::open_fleet(&fleet, "A").expect("open A");
    let ma = a.module("M").unwrap();
    let outcome = ma
        .send(
            "B",
            "M",
            &Ping {
                n: 0,
                text: String::new(),
            },
        )
        .expect("send")
        .wait();
    assert!(
        matches!(
            outcome,
            Outcome::Failed { .. } | Outcome::Unconfirmed { .. }
        ),
        "{outcome:?}"
    );
}

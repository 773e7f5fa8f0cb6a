//! The `ros2` kind through the facade: fleet-file keys and their located errors, acknowledged
//! delivery between two systems opened one by one (each its own DDS participant), secured by
//! generated keys or with `security = "none"`, and a send to a system that is not running;
//! on rustdds, and with the `cyclone` feature on Cyclone DDS and between a system on each.

use std::time::Duration;

use hetcomm::{Comm, LocalFleet, Message, Outcome};
use hetcomm_link_ros2::{Backend, Reliability, Ros2Settings};
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
         interface = \"127.0.0.1\"\nsame_host = false\nconnect_timeout_ms = 300\ndds = \"rustdds\"",
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
            dds: Backend::RustDds,
            deliver_on_receive_thread: false,
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
    let e = errors("dds = \"fastdds\"");
    assert!(
        e.starts_with("r.toml:8:7: unknown DDS implementation `fastdds`"),
        "{e}"
    );
    assert_eq!(
        errors("deliver_on_receive_thread = true"),
        "r.toml:8:29: `deliver_on_receive_thread` needs `dds = \"cyclone\"` (rustdds has no \
         receive thread that could deliver)\n  help: add `dds = \"cyclone\"` to this transport, \
         or remove the key"
    );
    if cfg!(feature = "cyclone") {
        let fleet = hetcomm::parse_fleet(
            &fleet_text("dds = \"cyclone\"\ndeliver_on_receive_thread = true"),
            "r.toml",
            None,
        );
        let hetcomm::config::TransportSettings::Registered(s) =
            &fleet.expect("valid").transports[0].settings
        else {
            panic!("registered settings expected");
        };
        let s = s.downcast_ref::<Ros2Settings>().unwrap();
        assert_eq!(
            (s.dds, s.deliver_on_receive_thread),
            (Backend::Cyclone, true)
        );
    } else {
        assert_eq!(
            errors("dds = \"cyclone\""),
            "r.toml:8:7: `dds = \"cyclone\"` needs Cyclone DDS, which this build does not include\n  \
             help: rebuild with the cargo feature `ros2-cyclone` (of hetcomm, hetcomm-cli or \
             hetcomm-bench; `cyclone` of hetcomm-link-ros2), or use `dds = \"rustdds\"`"
        );
    }
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
    acknowledged_delivery("rustdds", "rustdds", 63);
}

/// The same on Cyclone DDS (both systems in Cyclone's one instance of the domain).
#[cfg(feature = "cyclone")]
#[test]
fn acknowledged_delivery_on_cyclone_dds() {
    acknowledged_delivery("cyclone", "cyclone", 75);
}

/// A system on Cyclone DDS and one on rustdds, over the network (loopback): the same topics
/// and bytes, both ways, so messages and their acknowledgements cross.
#[cfg(feature = "cyclone")]
#[test]
fn a_cyclone_system_and_a_rustdds_system_exchange_acknowledged_messages() {
    acknowledged_delivery("cyclone", "rustdds", 76);
    acknowledged_delivery("rustdds", "cyclone", 77);
}

/// Twenty acknowledged messages from A (on DDS implementation `dds_a`) to B (on `dds_b`).
fn acknowledged_delivery(dds_a: &str, dds_b: &str, domain: u16) {
    let keys = |dds: &str| {
        format!(
            "domain_id = {domain}\nnamespace = \"{}\"\nsecurity = \"none\"\ndds = \"{dds}\"",
            namespace("open")
        )
    };
    let parse = |dds: &str| {
        hetcomm::parse_fleet(&fleet_text(&keys(dds)), "r.toml", None).expect("valid fleet")
    };
    let a = Comm::open_fleet(&parse(dds_a), "A").expect("open A");
    let b = Comm::open_fleet(&parse(dds_b), "B").expect("open B");
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
    let stats = b.stats();
    assert_eq!(stats.links[0].1.frames_dropped, 0, "{:?}", stats.links[0]);
}

/// Without `security = "none"`, the transport leaves the process and is secured: a fleet
/// opened in one process gets generated keys, and messages still arrive, acknowledged.
#[test]
fn a_secured_ros2_fleet_delivers() {
    secured_fleet_delivers("rustdds", 64);
}

/// The same on Cyclone DDS.
#[cfg(feature = "cyclone")]
#[test]
fn a_secured_ros2_fleet_on_cyclone_dds_delivers() {
    secured_fleet_delivers("cyclone", 78);
}

fn secured_fleet_delivers(dds: &str, domain: u16) {
    let keys = format!(
        "domain_id = {domain}\nnamespace = \"{}\"\ndds = \"{dds}\"",
        namespace("sec")
    );
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
    send_to_a_system_not_running_fails("rustdds", 65);
}

/// The same on Cyclone DDS.
#[cfg(feature = "cyclone")]
#[test]
fn a_send_to_a_system_not_running_on_cyclone_dds_fails() {
    send_to_a_system_not_running_fails("cyclone", 79);
}

fn send_to_a_system_not_running_fails(dds: &str, domain: u16) {
    let keys = format!(
        "domain_id = {domain}\nnamespace = \"{}\"\nsecurity = \"none\"\nconnect_timeout_ms = 200\n\
         dds = \"{dds}\"",
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

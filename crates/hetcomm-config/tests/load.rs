//! Loading valid files: the thesis's tables (alone and through `[legacy]`), the example
//! fleet, and the values every key ends up as.

use std::path::Path;
use std::time::Duration;

use hetcomm_config::*;
use hetcomm_core::{ModuleId, SystemId};
use hetcomm_link::emulation::EmulatedSettings;
use hetcomm_link_bluetooth::BluetoothSettings;
use hetcomm_link_ip::IpSettings;
use hetcomm_link_ros1::Ros1Settings;

mod common;
use common::{load, load_legacy, parse_str};

fn fixture(name: &str) -> std::path::PathBuf {
    Path::new("tests/fixtures").join(name)
}

fn legacy(ids: &str, table: &str, bt: &str) -> Fleet {
    let bt = fixture(bt);
    match load_legacy(&fixture(ids), &fixture(table), Some(&bt)) {
        Ok(f) => f,
        Err(e) => panic!("{e}"),
    }
}

fn load_ok(path: &str) -> Fleet {
    match load(Path::new(path)) {
        Ok(f) => f,
        Err(e) => panic!("{e}"),
    }
}

fn expected_master() -> String {
    std::env::var("ROS_MASTER_URI")
        .ok()
        .filter(|s| !s.trim().is_empty())
        .unwrap_or_else(|| "http://localhost:11311".to_string())
}

/// The (src, dst) pairs routed over the transport named `name`.
fn pairs_of(f: &Fleet, name: &str) -> Vec<(u16, u16)> {
    f.table
        .iter()
        .filter(|(_, &i)| f.transports[i].name == name)
        .map(|(&(s, d), _)| (s.0, d.0))
        .collect()
}

#[test]
fn tables_1_2_3_load() {
    let f = legacy(
        "table01-ids.txt",
        "table02-table.txt",
        "table03-bluetooth.txt",
    );
    let names: Vec<&str> = f.systems.iter().map(|s| s.name.as_str()).collect();
    assert_eq!(
        names,
        [
            "Vehicle1",
            "Vehicle2",
            "Vehicle3",
            "Vehicle4",
            "Virtual Environment"
        ]
    );
    assert_eq!(f.table.len(), 20);
    assert_eq!(
        pairs_of(&f, "B"),
        [(1, 2), (1, 3), (2, 1), (2, 3), (3, 1), (3, 2)]
    );
    assert_eq!(pairs_of(&f, "R").len(), 14);
    let r = f.transport("R").expect("implicit R");
    assert_eq!((r.kind, r.tag, r.attempts), (TransportKind::Ros1, b'R', 3));
    assert_eq!(
        r.settings.registered(),
        Some(&Ros1Settings {
            master_uri: expected_master(),
            namespace: None,
            connect_timeout_ms: None
        })
    );
    let b = f.transport("B").expect("implicit B");
    assert_eq!(
        (b.kind, b.tag, b.delivery),
        (TransportKind::Bluetooth, b'B', DeliveryMode::Acknowledged)
    );
    let Some(bt) = b.settings.registered::<BluetoothSettings>() else {
        panic!("not bluetooth")
    };
    assert_eq!(bt.channel, 1);
    assert_eq!(bt.addresses.len(), 4);
    assert_eq!(bt.addresses[&SystemId(1)].to_string(), "68:A3:C4:4A:B3:BA");
    assert_eq!(
        f.modules
            .iter()
            .map(|m| m.name.as_str())
            .collect::<Vec<_>>(),
        ["Sense", "Plan", "Act", "World"]
    );
    assert!(f.route(SystemId(0), SystemId(0)).is_none());
}

#[test]
fn tables_6_7_8_load() {
    let f = legacy(
        "table06-ids.txt",
        "table07-table.txt",
        "table08-bluetooth.txt",
    );
    assert_eq!(f.systems.len(), 6);
    assert_eq!(
        f.system(SystemId(3)).map(|s| s.name.as_str()),
        Some("VirtualEnv")
    );
    assert_eq!(pairs_of(&f, "B"), [(1, 2), (2, 1)]);
    assert_eq!(
        pairs_of(&f, "R"),
        [
            (0, 1),
            (0, 3),
            (1, 0),
            (1, 4),
            (2, 5),
            (3, 0),
            (4, 1),
            (5, 2)
        ]
    );
    assert_eq!(f.summary(), "6 systems, 4 modules, 10 pairs (R: 8, B: 2)");
}

#[test]
fn tables_16_17_18_load_with_crlf_and_lower_case_addresses() {
    let f = legacy(
        "table16-ids.txt",
        "table17-table.txt",
        "table18-bluetooth.txt",
    );
    assert_eq!(
        f.system(SystemId(2)).map(|s| s.name.as_str()),
        Some("Delta")
    );
    assert_eq!(pairs_of(&f, "B"), [(0, 2), (1, 0), (2, 1)]);
    assert_eq!(pairs_of(&f, "R"), [(0, 1), (1, 2), (2, 0)]);
    let Some(bt) = f
        .transport("B")
        .expect("B")
        .settings
        .registered::<BluetoothSettings>()
    else {
        panic!()
    };
    assert_eq!(
        bt.addresses[&SystemId(0)],
        BdAddr([0x68, 0xA3, 0xC4, 0x4A, 0xB3, 0xBA])
    );
}

#[test]
fn legacy_sections_match_load_legacy() {
    for (toml, ids, table, bt) in [
        (
            "section-3.5.toml",
            "table01-ids.txt",
            "table02-table.txt",
            "table03-bluetooth.txt",
        ),
        (
            "section-5.1.1.toml",
            "table06-ids.txt",
            "table07-table.txt",
            "table08-bluetooth.txt",
        ),
    ] {
        let a = load_ok(&format!("tests/fixtures/{toml}"));
        let b = legacy(ids, table, bt);
        assert_eq!(a.systems, b.systems, "{toml}");
        assert_eq!(a.table, b.table, "{toml}");
        assert_eq!(a.transports, b.transports, "{toml}");
        assert_eq!(a.source.as_deref(), Some(fixture(toml).as_path()));
        assert!(a.name.as_deref().is_some_and(|n| n.starts_with("thesis-")));
    }
}

#[test]
fn legacy_section_with_explicit_ros_transport() {
    let f = load_ok("tests/fixtures/section-5.2.1.toml");
    let ros = f.transport("ros").expect("ros");
    assert_eq!(ros.tag, b'R');
    assert_eq!(
        ros.settings.registered(),
        Some(&Ros1Settings {
            master_uri: "http://10.0.0.1:11311".into(),
            namespace: Some("/reliability".into()),
            connect_timeout_ms: None
        })
    );
    assert!(
        f.transport("R").is_none(),
        "R resolves to `ros`, no implicit transport"
    );
    assert_eq!(pairs_of(&f, "ros"), [(0, 1), (1, 2), (2, 0)]);
    assert_eq!(pairs_of(&f, "B"), [(0, 2), (1, 0), (2, 1)]);
}

#[test]
fn letters_remap_legacy_tables() {
    let f = load_ok("tests/cases/valid/legacy-with-letters.toml");
    assert_eq!(f.transports.len(), 2);
    assert_eq!(f.transport("wired").map(|t| t.tag), Some(b'R'));
    let sim = f.transport("sim-bt").expect("sim-bt");
    assert_eq!(sim.tag, b'B');
    let e: &EmulatedSettings = sim.settings.registered().expect("emulated settings");
    assert_eq!(sim.over.as_deref(), Some("wired"));
    assert_eq!(e.profile.as_deref(), Some("bluetooth-classic"));
    assert_eq!(e.seed, 0);
    assert_eq!(pairs_of(&f, "sim-bt"), [(0, 2), (1, 0), (2, 1)]);
}

#[test]
fn every_key_reaches_the_model() {
    let f = load_ok("tests/cases/valid/all-kinds.toml");
    assert_eq!(f.name.as_deref(), Some("all kinds"));
    // Systems sorted by id, module lists resolved and sorted.
    let ids: Vec<u16> = f.systems.iter().map(|s| s.id.0).collect();
    assert_eq!(ids, [0, 1, 7]);
    assert_eq!(
        f.system_by_name("Bravo").and_then(|s| s.modules.clone()),
        Some(vec![ModuleId(1), ModuleId(2)])
    );
    assert_eq!(
        f.system_by_name("Alpha").map(|s| s.modules.clone()),
        Some(None)
    );
    // Modules: [inbox] defaults, the long form overrides.
    let plan = f.module_by_name("Plan").expect("Plan");
    assert_eq!(
        plan.inbox,
        InboxConfig {
            capacity: 16,
            overflow: OverflowPolicy::DropNewest
        }
    );
    let act = f.module(ModuleId(2)).expect("Act");
    assert_eq!(
        act.inbox,
        InboxConfig {
            capacity: 16,
            overflow: OverflowPolicy::Block {
                timeout: Duration::from_millis(250)
            }
        }
    );
    // Transports in file order.
    let names: Vec<&str> = f.transports.iter().map(|t| t.name.as_str()).collect();
    assert_eq!(
        names,
        ["wired", "lan", "ros", "radio", "sim", "z", "q", "d"]
    );
    let wired = &f.transports[0];
    assert_eq!(
        (
            wired.tag,
            wired.delivery,
            wired.attempts,
            wired.max_in_flight
        ),
        (b'w', DeliveryMode::Unacknowledged, 1, 64)
    );
    assert_eq!(f.transports[1].max_in_flight, DEFAULT_MAX_IN_FLIGHT);
    let ip: &IpSettings = f.transports[1].settings.registered().expect("udp settings");
    assert_eq!(ip.endpoints[&SystemId(7)], "10.0.0.7:7402");
    assert_eq!(ip.endpoints[&SystemId(1)], "[::1]:7401");
    assert_eq!(ip.max_message_bytes, None);
    assert_eq!(f.transports[2].tag, b'R');
    let radio = f.transport("radio").expect("radio");
    assert_eq!(radio.tag, b'B', "named by [letters] B");
    let Some(bt) = radio.settings.registered::<BluetoothSettings>() else {
        panic!()
    };
    assert_eq!(bt.channel, 3);
    assert_eq!(bt.addresses[&SystemId(0)].to_string(), "08:ED:B9:B2:12:7A");
    assert!(
        bt.addresses.contains_key(&SystemId(1)),
        "numeric key taken as an id"
    );
    let sim = f.transport("sim").expect("sim");
    let e: &EmulatedSettings = sim.settings.registered().expect("emulated settings");
    assert_eq!(e.seed, 42);
    assert_eq!(e.params.get("loss_percent"), Some(&1.0));
    assert_eq!(e.params.get("tx_power_dbm"), Some(&-3.5));
    assert_eq!(e.params.len(), 3);
    let TransportSettings::Raw(z) = &f.transport("z").expect("z").settings else {
        panic!()
    };
    assert_eq!(z.get("mode").map(String::as_str), Some("peer"));
    assert_eq!(
        z.get("connect").map(String::as_str),
        Some("[\"tcp/10.0.0.1:7447\"]")
    );
    assert_eq!(z.get("limits").map(String::as_str), Some("{ frames = 8 }"));
    assert!(!z.contains_key("kind"));
    assert_eq!(f.transport("d").map(|t| t.kind), Some(TransportKind::Dds));
    // The table.
    assert_eq!(
        f.route(SystemId(0), SystemId(1)).map(|t| t.name.as_str()),
        Some("radio")
    );
    assert_eq!(
        f.route(SystemId(1), SystemId(7)).map(|t| t.name.as_str()),
        Some("ros")
    );
    assert_eq!(
        f.route(SystemId(7), SystemId(0)).map(|t| t.name.as_str()),
        Some("lan")
    );
    assert_eq!(f.table.len(), 6);
}

#[test]
fn example_fleet_parses() {
    // The example reads its keys from `keys/` beside it: without them it says how to make them.
    let e = parse_str(
        EXAMPLE_FLEET,
        "fleet.toml",
        Some(Path::new("tests/no-such-dir")),
    )
    .unwrap_err()
    .to_string();
    assert_eq!(
        e,
        "fleet.toml:23:8: the keys directory `tests/no-such-dir/keys` does not exist\n  \
         help: run `hetcomm keygen --fleet fleet.toml --out tests/no-such-dir/keys` to write \
         every system's keys there, or correct the path"
    );
    // With a key directory (fake public keys: this crate does no cryptography).
    let dir = std::env::temp_dir().join(format!("hetcomm-example-{}", std::process::id()));
    std::fs::create_dir_all(dir.join("keys")).unwrap();
    for (i, name) in ["Alpha", "Charlie", "Tango", "VirtualEnv"]
        .iter()
        .enumerate()
    {
        let key = format!("{}{}=", i, "A".repeat(42));
        std::fs::write(dir.join("keys").join(format!("{name}.pub")), key).unwrap();
    }
    let parsed = parse_str(EXAMPLE_FLEET, "fleet.example.toml", Some(&dir));
    let _ = std::fs::remove_dir_all(&dir);
    let f = match parsed {
        Ok(f) => f,
        Err(e) => panic!("{e}"),
    };
    assert_eq!(f.keys_dir, Some(dir.join("keys")));
    assert!(f.systems.iter().all(|s| s.public_key.is_some()));
    assert!(f
        .transports
        .iter()
        .all(|t| t.security == SecurityMode::Keys));
    assert_eq!(f.name.as_deref(), Some("leader-follower"));
    assert_eq!(f.systems.len(), 4);
    assert_eq!(f.module_by_name("Act").map(|m| m.inbox.capacity), Some(64));
    assert_eq!(
        f.module_by_name("Plan").map(|m| m.inbox.overflow),
        Some(OverflowPolicy::DropOldest)
    );
    assert_eq!(f.transport("wired").map(|t| t.tag), Some(b'W'));
    assert_eq!(
        f.transport("sim-bt").map(|t| (t.kind, t.tag)),
        Some((TransportKind::Emulated, b'B'))
    );
    assert_eq!(
        f.route(SystemId(1), SystemId(2)).map(|t| t.name.as_str()),
        Some("sim-bt")
    );
    assert_eq!(
        f.route(SystemId(0), SystemId(1)).map(|t| t.name.as_str()),
        Some("lan")
    );
    assert_eq!(f.source, None);
    assert_eq!(
        f.summary(),
        "4 systems, 4 modules, 10 pairs (wired: 6, lan: 2, sim-bt: 2)"
    );
}

#[test]
fn example_fleet_is_the_file_on_disk() {
    let on_disk = std::fs::read_to_string("fleet.example.toml").expect("example file");
    assert_eq!(on_disk, EXAMPLE_FLEET);
}

#[test]
fn names_are_compared_in_nfc() {
    // `Café` declared with U+00E9 and referred to as `e` + U+0301; the transport declared with
    // `e` + U+0301 and referred to both ways: one name each, stored in NFC.
    let text = "[systems]\n\"Caf\u{e9}\" = 0\nBob = 1\n\n\
                [transports.\"re\u{301}seau\"]\nkind = \"udp\"\n\
                endpoints = { \"Cafe\u{301}\" = \"127.0.0.1:7400\", Bob = \"127.0.0.1:7401\" }\n\n\
                [table]\ncolumns = [\"Cafe\u{301}\", \"Bob\"]\n\
                \"Cafe\u{301}\" = [\"X\", \"re\u{301}seau\"]\nBob = [\"r\u{e9}seau\", \"X\"]\n";
    let f = parse_str(text, "nfc.toml", None).unwrap_or_else(|e| panic!("{e}"));
    assert_eq!(f.systems[0].name, "Caf\u{e9}");
    assert_eq!(
        f.system_by_name("Caf\u{e9}").map(|s| s.id),
        Some(SystemId(0))
    );
    assert_eq!(f.transports[0].name, "r\u{e9}seau");
    assert_eq!(pairs_of(&f, "r\u{e9}seau"), [(0, 1), (1, 0)]);
}

#[test]
fn a_cell_may_list_several_transports_in_order_of_preference() {
    let text = r#"
[systems]
Alpha = 0
Bravo = 1
Charlie = 2

[transports.wifi]
kind = "udp"
endpoints = { Alpha = "127.0.0.1:7000", Bravo = "127.0.0.1:7001", Charlie = "127.0.0.1:7002" }

[transports.bt]
kind = "tcp"
endpoints = { Alpha = "127.0.0.1:7100", Bravo = "127.0.0.1:7101", Charlie = "127.0.0.1:7102" }

[letters]
W = "wifi"
B = "bt"

[table]
columns = ["Alpha", "Bravo", "Charlie"]
Alpha = ["X", "wifi,bt", "W"]
Bravo = ["W, B", "X", "bt"]
Charlie = ["bt,W", "B", "X"]
"#;
    let f = parse_str(text, "list.toml", None).unwrap_or_else(|e| panic!("{e}"));
    let names = |s: u16, d: u16| -> Vec<&str> {
        f.transports_for(SystemId(s), SystemId(d))
            .into_iter()
            .map(|i| f.transports[i].name.as_str())
            .collect()
    };
    assert_eq!(names(0, 1), ["wifi", "bt"]);
    assert_eq!(names(1, 0), ["wifi", "bt"], "letters with a space");
    assert_eq!(names(2, 0), ["bt", "wifi"], "a name and a letter");
    assert_eq!(names(0, 2), ["wifi"], "a one-letter cell is one transport");
    assert_eq!(names(1, 2), ["bt"]);
    assert!(names(0, 0).is_empty(), "X");
    // The first choice stays in `table`, the rest only where a cell lists more.
    assert_eq!(f.table.len(), 6);
    assert_eq!(f.fallbacks.len(), 3);
    let (wifi, bt) = (0, 1);
    assert!(f.carries(SystemId(0), SystemId(1), bt));
    assert!(f.carries(SystemId(0), SystemId(1), wifi));
    assert!(!f.carries(SystemId(0), SystemId(2), bt));
    assert_eq!(f.table_entries().count(), 9);
}

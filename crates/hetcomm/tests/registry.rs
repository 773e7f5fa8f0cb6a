//! The kinds compiled into this build are the ones its registration lines name
//! (`registry()` in src/transports.rs), and a fleet is loaded knowing them.

use hetcomm::config::TransportKind;

#[test]
fn the_registry_holds_the_kinds_built_in() {
    let kinds: Vec<TransportKind> = hetcomm::registry().registered().collect();
    assert!(kinds.contains(&TransportKind::Udp), "{kinds:?}");
    assert!(kinds.contains(&TransportKind::Tcp), "{kinds:?}");
    assert_eq!(
        kinds.contains(&TransportKind::Bluetooth),
        cfg!(feature = "bluetooth"),
        "{kinds:?}"
    );
    assert_eq!(
        kinds.contains(&TransportKind::Ros1),
        cfg!(feature = "ros1"),
        "{kinds:?}"
    );
    // `inproc` and `emulated` register like every other kind (hetcomm-link's factories).
    for kind in [TransportKind::Inproc, TransportKind::Emulated] {
        assert!(kinds.contains(&kind), "{kind} has no factory: {kinds:?}");
    }
    // The fleet file's raw kinds have no factory.
    for kind in [
        TransportKind::Zenoh,
        TransportKind::Mqtt,
        TransportKind::Dds,
    ] {
        assert!(!kinds.contains(&kind), "{kind} has a factory: {kinds:?}");
    }
}

#[test]
fn a_fleet_loads_with_the_kinds_compiled_in_and_the_loader_alone_keeps_theirs_raw() {
    let text = r#"[systems]
Alpha = 0
Bravo = 1

[transports.lan]
kind = "udp"
endpoints = { Alpha = "127.0.0.1:0", Bravo = "127.0.0.1:0" }

[table]
columns = ["Alpha", "Bravo"]
Alpha = ["X", "lan"]
Bravo = ["lan", "X"]
"#;
    // `hetcomm::config`'s loaders are the registry's.
    let with_registry = hetcomm::parse_fleet(text, "f.toml", None).expect("valid");
    let through_config = hetcomm::config::parse_str(text, "f.toml", None).expect("valid");
    assert_eq!(with_registry, through_config);
    let ip: &hetcomm::config::IpSettings = with_registry.transports[0]
        .settings
        .registered()
        .expect("udp's settings, read by its crate's spec");
    assert_eq!(ip.endpoints.len(), 2);
    // The loader alone knows udp by name only: its keys are kept raw.
    let alone = hetcomm_config::parse_str(text, "f.toml", None).expect("valid");
    assert!(
        matches!(
            &alone.transports[0].settings,
            hetcomm::config::TransportSettings::Raw(keys) if keys.contains_key("endpoints")
        ),
        "{:?}",
        alone.transports[0].settings
    );
    // `inproc` registers like every other kind: its crate's spec says it has no keys and
    // that its frames stay in the process; the loader alone keeps it raw, as any kind.
    let inproc = text.replace("\"udp\"", "\"inproc\"").replace(
        "endpoints = { Alpha = \"127.0.0.1:0\", Bravo = \"127.0.0.1:0\" }\n",
        "",
    );
    let with_registry = hetcomm::parse_fleet(&inproc, "f.toml", None).expect("valid");
    let t = &with_registry.transports[0];
    assert!(t
        .settings
        .registered::<hetcomm::link::inproc::InprocSettings>()
        .is_some());
    assert!(!with_registry.leaves_process(t));
    let alone = hetcomm_config::parse_str(&inproc, "f.toml", None).expect("valid");
    assert!(
        matches!(
            &alone.transports[0].settings,
            hetcomm::config::TransportSettings::Raw(keys) if keys.is_empty()
        ),
        "{:?}",
        alone.transports[0].settings
    );
    assert_eq!(with_registry.table, alone.table);

    let bad = text.replace("udp", "udpp");
    let with_registry = hetcomm::parse_fleet(&bad, "f.toml", None)
        .unwrap_err()
        .to_string();
    let alone = hetcomm_config::parse_str(&bad, "f.toml", None)
        .unwrap_err()
        .to_string();
    // The same error; the registry's help also names the kinds of link crates (compiled in
    // or not: `ros1_bridge`, `ros2`, `ros2_bridge`, `mqtt_bridge` and `shm` are known by
    // name either way).
    for e in [&with_registry, &alone] {
        assert!(
            e.starts_with("f.toml:6:8: unknown transport kind `udpp`"),
            "{e}"
        );
    }
    assert_eq!(
        with_registry
            .replace(", ros1_bridge", "")
            .replace(", ros2, ros2_bridge", "")
            .replace(", mqtt_bridge", "")
            .replace(", shm", ""),
        alone,
        "{with_registry}"
    );
}

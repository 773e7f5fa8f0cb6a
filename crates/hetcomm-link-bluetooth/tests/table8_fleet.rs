//! The fleet file that reproduces the thesis's Table 8 set-up on real hardware
//! (`examples/table8-fleet.toml`, described in docs/bluetooth.md) loads, and its Bluetooth
//! transport is one this crate accepts.

use std::path::Path;

use hetcomm_config::TransportKind;
use hetcomm_core::SystemId;
use hetcomm_link::registry::Registry;
use hetcomm_link_bluetooth::{validate, BdAddr, BluetoothSettings};

#[test]
fn table8_fleet_file_loads_and_maps_b_to_bluetooth() {
    let path = Path::new(env!("CARGO_MANIFEST_DIR")).join("examples/table8-fleet.toml");
    // Loaded as a program with this kind compiled in loads it.
    let mut registry = Registry::new();
    hetcomm_link_ip::register_transports(&mut registry);
    hetcomm_link_bluetooth::register_transports(&mut registry);
    let fleet = match hetcomm_config::load_with(&path, registry.kinds()) {
        Ok(f) => f,
        Err(e) => panic!("{e}"),
    };
    assert_eq!(fleet.systems.len(), 6);
    let (charlie, tango) = (SystemId(1), SystemId(2));
    assert_eq!(
        fleet.system(charlie).map(|s| s.name.as_str()),
        Some("Charlie")
    );
    assert_eq!(fleet.system(tango).map(|s| s.name.as_str()), Some("Tango"));

    // Table 7: Charlie <-> Tango is `B`, and nothing else is.
    let bt = fleet
        .route(charlie, tango)
        .expect("Charlie -> Tango is routed");
    assert_eq!(bt.kind, TransportKind::Bluetooth);
    assert_eq!(bt.tag, b'B');
    assert_eq!(bt.attempts, 3);
    assert_eq!(
        fleet.route(tango, charlie).map(|t| t.name.as_str()),
        Some(bt.name.as_str())
    );
    let bt_pairs = fleet
        .table
        .iter()
        .filter(|(_, &i)| fleet.transports[i].kind == TransportKind::Bluetooth)
        .count();
    assert_eq!(bt_pairs, 2);
    assert_eq!(fleet.table.len(), 10, "Table 7 has ten non-X cells");

    // Table 8's addresses, on the default channel.
    let Some(settings) = bt.settings.registered::<BluetoothSettings>() else {
        panic!(
            "bluetooth transport without bluetooth settings: {:?}",
            bt.settings
        );
    };
    assert_eq!(settings.channel, 1);
    assert_eq!(
        settings.addresses.get(&charlie),
        Some(&BdAddr([0x68, 0xA3, 0xC4, 0x4A, 0xB3, 0xBA]))
    );
    assert_eq!(
        settings.addresses.get(&tango),
        Some(&BdAddr([0xE4, 0xB3, 0x18, 0x09, 0x09, 0x06]))
    );
    assert_eq!(settings.addresses.len(), 2);
    // Both rovers can open it; the others have no Bluetooth address, as in Table 8.
    assert!(validate(charlie, settings).is_ok());
    assert!(validate(tango, settings).is_ok());
    assert!(validate(SystemId(0), settings).is_err());
}

//! The real RFCOMM family on this machine: settings checks that come before any socket, and
//! the error on a kernel without Bluetooth (or success where Bluetooth exists).

use std::time::{Duration, Instant};

use hetcomm_core::SystemId;
use hetcomm_link::conformance::CollectSink;
use hetcomm_link_bluetooth::{validate, BluetoothLink, BluetoothOpenError, Rfcomm};
use hetcomm_link_bluetooth::{BdAddr, BluetoothSettings};

const CHARLIE: BdAddr = BdAddr([0x68, 0xA3, 0xC4, 0x4A, 0xB3, 0xBA]);
const TANGO: BdAddr = BdAddr([0xE4, 0xB3, 0x18, 0x09, 0x09, 0x06]);

fn table8(channel: u8) -> BluetoothSettings {
    BluetoothSettings {
        channel,
        addresses: [(SystemId(1), CHARLIE), (SystemId(2), TANGO)].into(),
        addresses_file: None,
    }
}

fn open(local: SystemId, s: &BluetoothSettings) -> Result<BluetoothLink, BluetoothOpenError> {
    BluetoothLink::open(
        local,
        s,
        CollectSink::new(),
        BluetoothLink::default_config(),
    )
}

#[test]
fn opening_without_kernel_support_fails_at_once_with_advice() {
    // Detect support the way the link does: by creating an RFCOMM socket.
    let supported = Rfcomm::probe();
    let start = Instant::now();
    // Channel 29: unlikely to be taken by a BlueZ profile on a machine that has Bluetooth.
    let result = open(SystemId(1), &table8(29));
    let took = start.elapsed();
    match (supported, result) {
        (Err(probe), Err(e)) => {
            assert_eq!(
                probe.raw_os_error(),
                Some(libc_eafnosupport()),
                "unexpected probe error: {probe}"
            );
            assert!(
                matches!(e, BluetoothOpenError::NoKernelSupport { .. }),
                "{e:?}"
            );
            let msg = e.to_string();
            eprintln!("open on this machine: {msg}");
            assert!(msg.contains("no Bluetooth (AF_BLUETOOTH) support"), "{msg}");
            assert!(msg.contains("`emulated`"), "{msg}");
            assert!(msg.contains("profile = \"bluetooth-classic\""), "{msg}");
            assert!(took < Duration::from_secs(1), "took {took:?}");
        }
        (Ok(()), Ok(link)) => {
            // A machine with Bluetooth: the listener is up on the requested channel.
            assert_eq!(link.channel(), 29);
            assert_eq!(link.device(), CHARLIE);
        }
        (Ok(()), Err(e)) => {
            // Bluetooth exists but this open failed for a local reason (channel taken, …):
            // acceptable, but never the "no kernel support" answer.
            assert!(
                !matches!(e, BluetoothOpenError::NoKernelSupport { .. }),
                "{e}"
            );
        }
        (Err(probe), Ok(_)) => panic!("probe failed ({probe}) but open succeeded"),
    }
}

/// EAFNOSUPPORT on Linux.
fn libc_eafnosupport() -> i32 {
    97
}

#[test]
fn channel_must_be_1_to_30() {
    for bad in [0u8, 31, 255] {
        let e = open(SystemId(1), &table8(bad)).err().expect("bad channel");
        match &e {
            BluetoothOpenError::BadConfig { field, reason } => {
                assert_eq!(*field, "channel");
                assert!(reason.contains("1 to 30"), "{reason}");
            }
            other => panic!("channel {bad}: expected BadConfig, got {other:?}"),
        }
    }
    for good in [1u8, 30] {
        assert!(validate(SystemId(1), &table8(good)).is_ok());
    }
}

#[test]
fn settings_are_checked_before_any_socket() {
    // No address for the system being opened.
    let e = open(SystemId(0), &table8(1))
        .err()
        .expect("no local address");
    assert!(matches!(e, BluetoothOpenError::NoLocalAddress { system } if system == SystemId(0)));

    // The same address for two systems: connections from it could not be attributed.
    let mut dup = table8(1);
    dup.addresses.insert(SystemId(3), CHARLIE);
    match open(SystemId(1), &dup).err().expect("duplicate") {
        BluetoothOpenError::BadConfig { field, reason } => {
            assert_eq!(field, "addresses");
            assert!(reason.contains("68:A3:C4:4A:B3:BA"), "{reason}");
        }
        other => panic!("expected BadConfig, got {other:?}"),
    }

    // Reserved addresses no adapter has.
    for reserved in [[0u8; 6], [0, 0, 0, 0xFF, 0xFF, 0xFF], [0xFF; 6]] {
        let mut s = table8(1);
        s.addresses.insert(SystemId(2), BdAddr(reserved));
        assert!(
            matches!(
                validate(SystemId(1), &s),
                Err(BluetoothOpenError::BadConfig {
                    field: "addresses",
                    ..
                })
            ),
            "{reserved:?} accepted"
        );
    }
}

//! The Bluetooth link with everything but the address family: [`BluetoothLink`] over a
//! Unix-socket stand-in for RFCOMM (see `common`), where socket paths carry device addresses.

mod common;

use std::io::Write;
use std::time::{Duration, Instant};

use common::{
    settings, wait_until, TempDir, UnixBtHarness, UnixFamily, CHARLIE, DEADLINE, STRANGER, TANGO,
};
use hetcomm_core::SystemId;
use hetcomm_link::conformance::{self, CollectSink, Layered};
use hetcomm_link::{Link, LinkError, Peer};
use hetcomm_link_bluetooth::{BluetoothLink, BluetoothOpenError};
use hetcomm_link_ip::stream::{StreamConfig, RECORD_HEADER_LEN, RECORD_MAGIC, STREAM_VERSION};

const A: SystemId = SystemId(1);
const B: SystemId = SystemId(2);

/// One record as the stream layer frames it (no hello: identity is by address).
fn record(frame: &[u8]) -> Vec<u8> {
    let mut r = Vec::with_capacity(RECORD_HEADER_LEN + frame.len());
    r.extend_from_slice(&RECORD_MAGIC);
    r.push(STREAM_VERSION);
    r.push(0);
    r.extend_from_slice(&(frame.len() as u32).to_le_bytes());
    r.extend_from_slice(frame);
    r
}

#[test]
fn bluetooth_link_passes_conformance_over_unix_sockets() {
    conformance::run_all(&mut UnixBtHarness::new(StreamConfig::default()));
}

#[test]
fn bluetooth_link_passes_conformance_with_bluetooth_timeouts() {
    let config = BluetoothLink::default_config();
    conformance::run_all(&mut UnixBtHarness::new(config));
}

/// The link inside an emulation layer (a model that changes nothing), as an `emulated`
/// transport over `bluetooth` opens it.
#[test]
fn bluetooth_link_wrapped_in_emulation_passes_conformance() {
    let config = BluetoothLink::default_config();
    conformance::run_all(&mut Layered::emulated(UnixBtHarness::new(config)));
}

/// With a driven receive side (read through `Link::readable`, by the suite), bare and
/// wrapped in emulation.
#[test]
fn driven_bluetooth_link_passes_conformance_bare_and_wrapped() {
    let config = StreamConfig {
        driven: true,
        ..BluetoothLink::default_config()
    };
    conformance::run_all(&mut UnixBtHarness::new(config.clone()));
    conformance::run_all(&mut Layered::emulated(UnixBtHarness::new(config)));
}

#[test]
fn sender_is_identified_by_its_address_without_a_hello() {
    let mut h = UnixBtHarness::new(StreamConfig::default());
    let sink_b = CollectSink::new();
    let a = h.open_bt(A, CollectSink::new());
    let b = h.open_bt(B, sink_b.clone());
    assert_eq!(a.device(), CHARLIE);
    assert_eq!(b.channel(), 1);
    a.send(B, b"from Charlie").unwrap();
    assert_eq!(sink_b.wait_for(1, DEADLINE), 1);
    assert_eq!(sink_b.frames()[0].from, Peer::System(A));
    assert_eq!(sink_b.frames()[0].bytes, b"from Charlie");

    // A raw connection from Charlie's address is attributed to Charlie with no hello at all:
    // the first bytes on the connection are already a record.
    let mut raw = h.family.raw_connect(Some(CHARLIE), TANGO, 1);
    raw.write_all(&record(b"raw from Charlie")).unwrap();
    assert_eq!(sink_b.wait_for(2, DEADLINE), 2);
    assert_eq!(sink_b.frames()[1].from, Peer::System(A));
    assert_eq!(sink_b.frames()[1].bytes, b"raw from Charlie");
    assert_eq!(b.stream_stats().rejected_connections, 0);
}

#[test]
fn frames_from_an_address_outside_the_fleet_are_dropped_and_counted() {
    let mut h = UnixBtHarness::new(StreamConfig::default());
    let sink_b = CollectSink::new();
    let b = h.open_bt(B, sink_b.clone());
    let mut raw = h.family.raw_connect(Some(STRANGER), TANGO, 1);
    // The write may fail once the link has closed the connection; either way nothing arrives.
    let _ = raw.write_all(&record(b"from a stranger"));
    wait_until("the stranger's connection to be rejected", DEADLINE, || {
        b.stream_stats().rejected_connections == 1
    });
    assert_eq!(b.stats().frames_dropped, 1);
    assert_eq!(b.stats().frames_received, 0);

    // A connection with no address at all is refused the same way.
    let mut anonymous = h.family.raw_connect(None, TANGO, 1);
    let _ = anonymous.write_all(&record(b"from nobody"));
    wait_until("the anonymous connection to be rejected", DEADLINE, || {
        b.stream_stats().rejected_connections == 2
    });
    assert_eq!(b.stats().frames_dropped, 2);
    assert!(sink_b.frames().is_empty());
}

#[test]
fn a_system_with_no_address_is_refused_and_cannot_be_sent_to() {
    let dir = TempDir::new("no-address");
    let family = UnixFamily::new(&dir.0);
    // System 3 is in the fleet but not on this transport (Table 8 leaves the virtual
    // environments out).
    let s = settings(1, &[(A, CHARLIE), (B, TANGO)]);
    let a = BluetoothLink::open_with_family(
        family.clone(),
        A,
        &s,
        CollectSink::new(),
        StreamConfig::default(),
    )
    .unwrap();
    match a.send(SystemId(3), b"x") {
        Err(LinkError::Unreachable { reason, .. }) => {
            assert!(
                reason.contains("no endpoint on this bluetooth link"),
                "{reason}"
            )
        }
        other => panic!("expected Unreachable, got {other:?}"),
    }
    let e = BluetoothLink::open_with_family(
        family,
        SystemId(3),
        &s,
        CollectSink::new(),
        StreamConfig::default(),
    )
    .err()
    .expect("system 3 has no address");
    assert!(matches!(e, BluetoothOpenError::NoLocalAddress { system } if system == SystemId(3)));
    assert!(e.to_string().contains("bluetoothctl show"), "{e}");
}

#[test]
fn ends_on_different_channels_do_not_meet() {
    let dir = TempDir::new("channels");
    let family = UnixFamily::new(&dir.0);
    let pairs = [(A, CHARLIE), (B, TANGO)];
    let sink_b = CollectSink::new();
    let _b = BluetoothLink::open_with_family(
        family.clone(),
        B,
        &settings(2, &pairs),
        sink_b.clone(),
        StreamConfig::default(),
    )
    .unwrap();
    let a = BluetoothLink::open_with_family(
        family,
        A,
        &settings(3, &pairs),
        CollectSink::new(),
        // A backoff no loaded machine outlasts before the second send below.
        StreamConfig {
            backoff_initial: std::time::Duration::from_secs(30),
            ..StreamConfig::default()
        },
    )
    .unwrap();
    // The send queues behind a connector; its connect fails, and the next send reports why.
    a.send(B, b"wrong channel").expect("queued");
    let deadline = std::time::Instant::now() + std::time::Duration::from_secs(10);
    while a.stream_stats().frames_lost_connecting < 1 {
        assert!(std::time::Instant::now() < deadline, "connect never failed");
        std::thread::sleep(std::time::Duration::from_millis(1));
    }
    match a.send(B, b"wrong channel") {
        Err(LinkError::Unreachable { reason, .. }) => {
            assert!(reason.contains("[E4:B3:18:09:09:06]:3"), "{reason}")
        }
        other => panic!("expected Unreachable, got {other:?}"),
    }
    assert!(sink_b.frames().is_empty());
}

#[test]
fn a_busy_channel_is_reported() {
    let mut h = UnixBtHarness::new(StreamConfig::default());
    let _b = h.open_bt(B, CollectSink::new());
    let e = BluetoothLink::open_with_family(
        h.family.clone(),
        B,
        &h.settings,
        CollectSink::new(),
        StreamConfig::default(),
    )
    .err()
    .expect("the channel is taken");
    assert!(
        matches!(e, BluetoothOpenError::ChannelBusy { channel: 1, .. }),
        "{e:?}"
    );
    assert!(e.to_string().contains("already in use"), "{e}");
}

#[test]
fn dropping_a_link_wakes_its_listener_promptly() {
    let mut h = UnixBtHarness::new(StreamConfig::default());
    let sink_b = CollectSink::new();
    let a = h.open_bt(A, CollectSink::new());
    let b = h.open_bt(B, sink_b.clone());
    a.send(B, b"one").unwrap();
    assert_eq!(sink_b.wait_for(1, DEADLINE), 1);
    // The listener is blocked in poll and a reader in read: both must return at once.
    let t = Instant::now();
    drop(b);
    drop(a);
    assert!(
        t.elapsed() < Duration::from_secs(2),
        "shutdown took {:?}",
        t.elapsed()
    );
}

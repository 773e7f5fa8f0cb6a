//! Recording real fleets and reading the files back: every send, receipt and outcome is in
//! the file with its payload; damaged and truncated files are read as far as they go and the
//! damage is reported, never a panic; a replay into a simulation sends exactly what was
//! recorded.

use std::path::PathBuf;
use std::time::Duration;

use hetcomm::sim::{SimFleet, SimOptions};
use hetcomm::{LocalFleet, Message, Outcome};
use hetcomm_record::format::Event;
use hetcomm_record::replay::replay_sim;
use hetcomm_record::{Encoding, RecordOptions, Recorder, ReplayFilter};
use serde::{Deserialize, Serialize};

#[derive(Serialize, Deserialize, Message, Debug, Clone, PartialEq)]
#[message(id = 7)]
struct Reading {
    n: u32,
    value: f64,
    label: String,
}

fn fleet(kind: &str) -> hetcomm::config::Fleet {
    let text = format!(
        r#"
        name = "rec-test"
        [systems]
        A = 0
        B = 1
        [modules]
        Plan = 0
        Act = 1
        [transports.net]
        kind = "{kind}"
        {extra}
        [table]
        columns = ["A", "B"]
        A = ["X", "net"]
        B = ["net", "X"]
    "#,
        extra = if kind == "udp" {
            format!(
                "security = \"none\"\nendpoints = {{ A = \"127.0.0.1:{}\", B = \"127.0.0.1:{}\" }}",
                free_udp_port(),
                free_udp_port()
            )
        } else {
            String::new()
        }
    );
    hetcomm::config::parse_str(&text, "rec-test.toml", None).unwrap()
}

fn free_udp_port() -> u16 {
    let s = std::net::UdpSocket::bind("127.0.0.1:0").unwrap();
    s.local_addr().unwrap().port()
}

fn tmp(name: &str) -> PathBuf {
    let dir = PathBuf::from(env!("CARGO_TARGET_TMPDIR")).join("hetcomm-record");
    std::fs::create_dir_all(&dir).unwrap();
    dir.join(name)
}

fn reading(n: u32) -> Reading {
    Reading {
        n,
        value: n as f64 * 0.5,
        label: format!("r{n}"),
    }
}

/// Records `count` acknowledged sends A → B in one process and returns the file.
fn record_local(kind: &str, encoding: Encoding, count: u32, name: &str) -> PathBuf {
    let fleet = LocalFleet::open(fleet(kind)).unwrap();
    let a = fleet.system("A").unwrap();
    let b = fleet.system("B").unwrap();
    let path = tmp(name);
    let recorder = Recorder::create(
        &path,
        a.fleet(),
        RecordOptions {
            encoding,
            ..RecordOptions::default()
        },
    )
    .unwrap();
    let _ha = recorder.attach(&a);
    let _hb = recorder.attach(&b);
    let plan = a.module("Plan").unwrap();
    let act = b.module("Act").unwrap();
    for n in 0..count {
        let t = plan.send("B", "Act", &reading(n)).unwrap();
        assert!(matches!(t.wait(), Outcome::Delivered { .. }));
        assert_eq!(act.recv::<Reading>().unwrap().message, reading(n));
    }
    let summary = recorder.finish().unwrap();
    assert_eq!(summary.outcomes, count as u64);
    assert_eq!(summary.receipts, count as u64);
    assert_eq!(summary.lost, 0);
    path
}

#[test]
fn every_send_receipt_and_outcome_of_a_udp_fleet_is_recorded_with_its_payload() {
    for encoding in [Encoding::Json, Encoding::MsgPack] {
        let path = record_local("udp", encoding, 50, &format!("udp-{encoding:?}.mcap"));
        let (events, report) = hetcomm_record::read(&path).unwrap();
        assert!(report.problem.is_none(), "{}", report.describe());
        assert_eq!(report.skipped, 0);
        assert_eq!(
            report.metadata.get("encoding").map(String::as_str),
            Some(encoding.mcap_name())
        );
        let mut sends = Vec::new();
        let mut receipts = Vec::new();
        let mut outcomes = Vec::new();
        for e in events {
            match e {
                Event::Send(s) if s.attempt == 1 => sends.push(s),
                Event::Send(_) => {}
                Event::Receipt(r) => receipts.push(r),
                Event::Outcome(o) => outcomes.push(o),
                Event::PathSwitch(_) => {}
            }
        }
        assert_eq!(sends.len(), 50);
        for (n, s) in sends.iter().enumerate() {
            let payload: Reading =
                hetcomm::payload::decode(&s.message.payload_bytes().unwrap()).unwrap();
            assert_eq!(payload, reading(n as u32));
            assert_eq!(s.message.source.system, "A");
            assert_eq!(s.message.destination.module, "Act");
            assert_eq!(s.message.message_type, 7);
            assert_eq!(s.message.transport_name.as_deref(), Some("net"));
            // The JSON view shows the fields by name in either encoding.
            assert_eq!(s.message.payload_value().unwrap()["label"], format!("r{n}"));
            assert!(s.message.payload_b64.is_none() || encoding == Encoding::MsgPack);
            // Its receipt and outcome: same source and sequence number.
            let r = receipts
                .iter()
                .find(|r| r.message.seq == s.message.seq)
                .unwrap();
            assert_eq!(r.status, "delivered");
            assert_eq!(r.message.payload_value(), s.message.payload_value());
            let o = outcomes.iter().find(|o| o.seq == s.message.seq).unwrap();
            assert_eq!(
                (o.outcome.as_str(), o.source_system.as_str()),
                ("delivered", "A")
            );
            assert!(o.latency_us.is_some());
        }
    }
}

#[test]
fn truncated_files_are_read_up_to_the_cut_and_the_cut_is_reported() {
    let path = record_local("inproc", Encoding::Json, 300, "cut.mcap");
    let bytes = std::fs::read(&path).unwrap();
    let (all, _) = hetcomm_record::read(&path).unwrap();
    let mut seen_partial = false;
    let step = (bytes.len() / 97).max(1);
    for cut in (8..bytes.len()).step_by(step).chain([bytes.len() - 1]) {
        let mut events = 0u64;
        let report = hetcomm_record::reader::read_bytes(&bytes[..cut], |_| events += 1)
            .unwrap_or_else(|e| panic!("cut at {cut}: {e}"));
        assert_eq!(report.events, events);
        assert!(events <= all.len() as u64);
        // A cut file is never taken for a complete one.
        assert!(
            report.problem.is_some(),
            "cut at {cut}/{} read as complete ({events} events)",
            bytes.len()
        );
        assert!(report.describe().contains("cut short"));
        seen_partial |= events > 0 && events < all.len() as u64;
    }
    assert!(seen_partial, "some cut kept part of the events");
    // Less than the magic: not an MCAP file at all.
    assert!(hetcomm_record::reader::read_bytes(&bytes[..4], |_| {}).is_err());
    assert!(hetcomm_record::reader::read_bytes(b"{\"not\": \"mcap\"}", |_| {}).is_err());
}

#[test]
fn corrupt_bytes_never_panic_and_never_invent_events() {
    let path = record_local("inproc", Encoding::Json, 100, "corrupt.mcap");
    let bytes = std::fs::read(&path).unwrap();
    let (all, _) = hetcomm_record::read(&path).unwrap();
    // A deterministic spread of single-byte corruptions over the whole file.
    let mut damaged_reports = 0;
    for k in 0..400usize {
        let at = 8 + (k * 7919) % (bytes.len() - 8);
        let mut b = bytes.clone();
        b[at] ^= 0x5a;
        match hetcomm_record::reader::read_bytes(&b, |_| {}) {
            Ok(report) => {
                assert!(
                    report.events <= all.len() as u64,
                    "corruption at {at}/{}: {} events of {}: {}",
                    b.len(),
                    report.events,
                    all.len(),
                    report.describe()
                );
                if report.problem.is_some() || report.skipped > 0 {
                    damaged_reports += 1;
                }
            }
            Err(e) => assert!(e.contains("MCAP"), "{e}"),
        }
    }
    assert!(damaged_reports > 0);
}

#[test]
fn a_replay_into_a_simulation_sends_what_was_recorded_at_the_recorded_times() {
    // Record a simulated run: A sends a reading every 100 ms of virtual time.
    let sim = SimFleet::open(fleet("inproc"), SimOptions::default()).unwrap();
    let a = sim.system("A").unwrap();
    let path = tmp("sim.mcap");
    let recorder = Recorder::create(
        &path,
        a.fleet(),
        RecordOptions {
            origin: sim.now(),
            ..RecordOptions::default()
        },
    )
    .unwrap();
    let handle = recorder.attach(&a);
    let plan = a.module("Plan").unwrap();
    let start = sim.now();
    for n in 0..20u32 {
        sim.run_until(start + Duration::from_millis(100 * n as u64));
        plan.send("B", "Act", &reading(n)).unwrap();
    }
    sim.run_idle(sim.now() + Duration::from_secs(5));
    drop(handle);
    recorder.finish().unwrap();

    // Replay it (A's sends only) into a fresh simulation, recording B's receipts there.
    let sim2 = SimFleet::open(fleet("inproc"), SimOptions::default()).unwrap();
    let b = sim2.system("B").unwrap();
    let again = tmp("sim-again.mcap");
    let recorder2 = Recorder::create(
        &again,
        b.fleet(),
        RecordOptions {
            origin: sim2.now(),
            ..RecordOptions::default()
        },
    )
    .unwrap();
    let hb = recorder2.attach(&b);
    let filter = ReplayFilter {
        systems: vec!["A".into()],
        modules: vec![],
        receipts: false,
    };
    let report = replay_sim(&path, &sim2, &filter, 1.0).unwrap();
    assert_eq!(report.stats.sent, 20, "{report:?}");
    assert_eq!(report.stats.delivered, 20);
    assert!((report.recorded_s - 1.9).abs() < 1e-9);
    drop(hb);
    recorder2.finish().unwrap();
    let (events, _) = hetcomm_record::read(&again).unwrap();
    let received: Vec<(u64, Reading)> = events
        .into_iter()
        .filter_map(|e| match e {
            Event::Receipt(r) => Some((
                r.time_us,
                hetcomm::payload::decode(&r.message.payload_bytes().unwrap()).unwrap(),
            )),
            _ => None,
        })
        .collect();
    let want: Vec<(u64, Reading)> = (0..20u32)
        .map(|n| (start.as_micros() + 100_000 * n as u64, reading(n)))
        .collect();
    assert_eq!(received, want);
}

/// Messages another crate writes beside the events (the demo's poses for Foxglove) get their
/// own channel and schema, are counted, and are left aside by the event reader, which says so.
#[test]
fn other_channels_are_written_beside_the_events_and_left_aside_when_reading() {
    let fleet = LocalFleet::open(fleet("inproc")).unwrap();
    let a = fleet.system("A").unwrap();
    let b = fleet.system("B").unwrap();
    let path = tmp("others.mcap");
    let recorder = Recorder::create(&path, a.fleet(), RecordOptions::default()).unwrap();
    let _ha = recorder.attach(&a);
    let _hb = recorder.attach(&b);
    let channel = hetcomm_record::OtherChannel {
        topic: "/poses".into(),
        message_encoding: "json".into(),
        schema_name: "test.Pose".into(),
        schema_encoding: "jsonschema".into(),
        schema: br#"{"type": "object"}"#.to_vec(),
    };
    let start = hetcomm::Time::now_mono();
    for i in 0..3u64 {
        recorder.write_other(
            &channel,
            start + Duration::from_millis(100 * i),
            format!(r#"{{"x": {i}}}"#).as_bytes(),
        );
    }
    let t = a
        .module("Plan")
        .unwrap()
        .send("B", "Act", &reading(1))
        .unwrap();
    assert!(matches!(t.wait(), Outcome::Delivered { .. }));
    let summary = recorder.finish().unwrap();
    assert_eq!((summary.others, summary.lost), (3, 0));
    let (events, report) = hetcomm_record::read(&path).unwrap();
    assert_eq!((report.others, report.skipped), (3, 0));
    assert_eq!(report.events, events.len() as u64);
    assert!(report
        .describe()
        .contains("3 messages on other channels left aside"));
    // The channel is a standard MCAP channel with its schema and log times.
    let bytes = std::fs::read(&path).unwrap();
    let mut seen = Vec::new();
    for m in mcap::MessageStream::new(&bytes).unwrap() {
        let m = m.unwrap();
        if m.channel.topic == "/poses" {
            let schema = m.channel.schema.as_ref().unwrap();
            assert_eq!(
                (schema.name.as_str(), schema.encoding.as_str()),
                ("test.Pose", "jsonschema")
            );
            seen.push((m.log_time, String::from_utf8(m.data.to_vec()).unwrap()));
        }
    }
    let t0 = start.as_micros() * 1000;
    assert_eq!(
        seen,
        [
            (t0, r#"{"x": 0}"#.to_string()),
            (t0 + 100_000_000, r#"{"x": 1}"#.to_string()),
            (t0 + 200_000_000, r#"{"x": 2}"#.to_string()),
        ]
    );
}

/// A path switch is in the recording, in both encodings: the system, the destination, both
/// transports and the switch's number.
#[test]
fn path_switches_are_recorded() {
    for encoding in [Encoding::Json, Encoding::MsgPack] {
        let (u1, u2, u3, u4) = (
            free_udp_port(),
            free_udp_port(),
            free_udp_port(),
            free_udp_port(),
        );
        let text = format!(
            "[systems]\nA = 0\nB = 1\n[modules]\nPlan = 0\nAct = 1\n\
             [transports.wifi]\nkind = \"udp\"\nsecurity = \"none\"\n\
             endpoints = {{ A = \"127.0.0.1:{u1}\", B = \"127.0.0.1:{u2}\" }}\n\
             [transports.radio]\nkind = \"udp\"\nsecurity = \"none\"\n\
             endpoints = {{ A = \"127.0.0.1:{u3}\", B = \"127.0.0.1:{u4}\" }}\n\
             [table]\ncolumns = [\"A\", \"B\"]\nA = [\"X\", \"wifi,radio\"]\nB = [\"wifi,radio\", \"X\"]\n"
        );
        let fleet =
            LocalFleet::open(hetcomm::config::parse_str(&text, "p.toml", None).unwrap()).unwrap();
        let a = fleet.system("A").unwrap();
        let path = tmp(&format!("switch-{encoding:?}.mcap"));
        let recorder = Recorder::create(
            &path,
            a.fleet(),
            RecordOptions {
                encoding,
                ..RecordOptions::default()
            },
        )
        .unwrap();
        let _h = recorder.attach(&a);
        a.set_transports("B", &["radio"]).unwrap();
        a.set_transports("B", &["wifi", "radio"]).unwrap();
        recorder.finish().unwrap();
        let (events, report) = hetcomm_record::reader::read(&path).unwrap();
        assert_eq!((report.skipped, report.others), (0, 0), "{report:?}");
        let switches: Vec<_> = events
            .into_iter()
            .filter_map(|e| match e {
                Event::PathSwitch(s) => Some((
                    s.source_system,
                    s.destination_system,
                    s.from,
                    s.to,
                    s.number,
                )),
                _ => None,
            })
            .collect();
        let expected = [
            ("A", "B", "wifi", "radio", 1),
            ("A", "B", "radio", "wifi", 2),
        ]
        .map(|(a, b, c, d, n)| (a.into(), b.into(), c.into(), d.into(), n));
        assert_eq!(switches, expected, "{encoding:?}");
    }
}

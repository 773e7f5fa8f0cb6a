//! The `mqtt_bridge` kind against a real mosquitto and a plain MQTT JSON client: the Python
//! AGV `examples/mqtt/agv.py` (paho-mqtt, VDA 5050-shaped messages) on the fleet file
//! `examples/mqtt/agv.toml`, both ways; bad input from it counted and named; the fleet file's
//! mistakes, a declared type that does not fit and a send that does not convert refused,
//! naming the field.

mod common;

use std::path::{Path, PathBuf};
use std::process::{Child, Command, Stdio};
use std::sync::{Arc, Mutex};
use std::time::{Duration, Instant};

use common::fleet::{eventually, RawClient};
use common::{broker, unique_fleet};
use hetcomm::config::{Fleet, TransportSettings};
use hetcomm::{Comm, Message, MessageType, OpenOptions, Outcome, SendOptions};
use hetcomm_core::SystemId;
use hetcomm_link::shape::NO_SHAPES;
use hetcomm_link::{FrameSink, Link, Peer};
use hetcomm_link_mqtt::bridge::{BridgeSettings, MqttBridge};
use serde::{Deserialize, Serialize};

/// VDA 5050 `order`, the fields the example maps.
#[derive(Serialize, Deserialize, Message, Debug, Clone, PartialEq)]
#[message(id = 50)]
#[serde(rename_all = "camelCase")]
struct Order {
    header_id: u32,
    timestamp: String,
    version: String,
    manufacturer: String,
    serial_number: String,
    order_id: String,
    order_update_id: u32,
    nodes: Vec<Node>,
    edges: Vec<Edge>,
}

#[derive(Serialize, Deserialize, Debug, Clone, PartialEq)]
#[serde(rename_all = "camelCase")]
struct Node {
    node_id: String,
    sequence_id: u32,
    released: bool,
}

#[derive(Serialize, Deserialize, Debug, Clone, PartialEq)]
#[serde(rename_all = "camelCase")]
struct Edge {
    edge_id: String,
    sequence_id: u32,
    released: bool,
    start_node_id: String,
    end_node_id: String,
}

/// VDA 5050 `instantActions`.
#[derive(Serialize, Deserialize, Message, Debug, Clone, PartialEq)]
#[message(id = 51)]
#[serde(rename_all = "camelCase")]
struct InstantActions {
    header_id: u32,
    timestamp: String,
    version: String,
    manufacturer: String,
    serial_number: String,
    actions: Vec<Action>,
}

#[derive(Serialize, Deserialize, Debug, Clone, PartialEq)]
#[serde(rename_all = "camelCase")]
struct Action {
    action_id: String,
    action_type: String,
    blocking_type: String,
}

/// VDA 5050 `state`: the fields this master control reads.
#[derive(Serialize, Deserialize, Message, Debug, Clone, PartialEq)]
#[message(id = 52)]
#[serde(rename_all = "camelCase")]
struct State {
    header_id: u32,
    order_id: String,
    order_update_id: u32,
    last_node_id: String,
    driving: bool,
    action_states: Vec<ActionState>,
    battery_state: BatteryState,
    operating_mode: String,
    agv_position: Option<AgvPosition>,
}

#[derive(Serialize, Deserialize, Debug, Clone, PartialEq)]
#[serde(rename_all = "camelCase")]
struct ActionState {
    action_id: String,
    action_status: String,
}

#[derive(Serialize, Deserialize, Debug, Clone, PartialEq)]
#[serde(rename_all = "camelCase")]
struct BatteryState {
    battery_charge: f64,
    charging: bool,
}

#[derive(Serialize, Deserialize, Debug, Clone, PartialEq)]
#[serde(rename_all = "camelCase")]
struct AgvPosition {
    x: f64,
    y: f64,
    theta: f64,
    map_id: String,
}

/// VDA 5050 `connection`; `serialNumber` comes from the topic's `+` level.
#[derive(Serialize, Deserialize, Message, Debug, Clone, PartialEq)]
#[message(id = 53)]
#[serde(rename_all = "camelCase")]
struct Connection {
    header_id: u32,
    manufacturer: String,
    serial_number: String,
    connection_state: String,
}

/// A `state` whose `driving` does not fit the mapping's `driving:bool`.
#[derive(Serialize, Deserialize, Message, Debug, Clone, PartialEq)]
#[message(id = 52)]
struct BadState {
    driving: String,
}

fn repo() -> PathBuf {
    Path::new(env!("CARGO_MANIFEST_DIR")).join("../..")
}

/// The example fleet file with `broker` and a manufacturer of its own (`manufacturer`).
fn fleet_text(broker: &str, manufacturer: &str) -> String {
    std::fs::read_to_string(repo().join("examples/mqtt/agv.toml"))
        .expect("examples/mqtt/agv.toml")
        .replace("mqtt://127.0.0.1:1883", &format!("mqtt://{broker}"))
        .replace("uagv/v2/acme/", &format!("uagv/v2/{manufacturer}/"))
}

fn fleet(manufacturer: &str) -> Fleet {
    hetcomm::parse_fleet(&fleet_text(&broker(), manufacturer), "agv.toml", None)
        .expect("valid fleet")
}

fn declared() -> OpenOptions {
    OpenOptions::new()
        .message::<Order>()
        .message::<InstantActions>()
        .message::<State>()
        .message::<Connection>()
}

/// The Python AGV, killed when dropped.
struct Agv(Child);

impl Agv {
    fn start(manufacturer: &str, more: &[&str]) -> Agv {
        let python = std::env::var("HETCOMM_PYTHON")
            .map(PathBuf::from)
            .unwrap_or_else(|_| repo().join("target/py-venv/bin/python"));
        let child = Command::new(&python)
            .arg(repo().join("examples/mqtt/agv.py"))
            .args(["--broker", &broker(), "--manufacturer", manufacturer])
            .args(["--serial", "tango", "--period", "0.2", "--seconds", "30"])
            // Later arguments win (argparse).
            .args(more)
            .stdout(Stdio::inherit())
            .spawn()
            .unwrap_or_else(|e| {
                panic!(
                    "cannot run {} ({e}): run `bash scripts/install.sh python` or set HETCOMM_PYTHON",
                    python.display()
                )
            });
        Agv(child)
    }
}

impl Drop for Agv {
    fn drop(&mut self) {
        let _ = self.0.kill();
        let _ = self.0.wait();
    }
}

/// The next message of type `M` in `module`'s inbox within `secs`, skipping the others (the
/// AGV's states keep coming), with its source system.
fn next<M: Message + serde::de::DeserializeOwned>(
    module: &hetcomm::Module,
    secs: u64,
) -> (M, &'static str) {
    let deadline = Instant::now() + Duration::from_secs(secs);
    loop {
        let left = deadline.saturating_duration_since(Instant::now());
        let raw = module
            .recv_raw_timeout(Some(left))
            .unwrap_or_else(|e| panic!("no {} within {secs} s: {e}", M::NAME));
        if raw.envelope.header.message_type == M::TYPE {
            let m = hetcomm_core::payload::decode(&raw.payload).expect("decodes");
            return (m, raw.envelope.source_system);
        }
    }
}

fn order(manufacturer: &str, id: &str) -> Order {
    let node = |n: &str, seq| Node {
        node_id: n.into(),
        sequence_id: seq,
        released: true,
    };
    Order {
        header_id: 1,
        timestamp: "2026-12-02T12:00:00.000Z".into(),
        version: "2.0.0".into(),
        manufacturer: manufacturer.into(),
        serial_number: "tango".into(),
        order_id: id.into(),
        order_update_id: 0,
        nodes: vec![node("n1", 0), node("n2", 2)],
        edges: vec![Edge {
            edge_id: "e1".into(),
            sequence_id: 1,
            released: true,
            start_node_id: "n1".into(),
            end_node_id: "n2".into(),
        }],
    }
}

#[test]
fn the_python_agv_exchanges_orders_actions_and_states_both_ways() {
    let manufacturer = format!("acme-{}", unique_fleet());
    let alpha = Comm::open_fleet_options(&fleet(&manufacturer), "Alpha", declared())
        .expect("Alpha opens with its declared types");
    let (drive, world) = (
        alpha.module("Drive").unwrap(),
        alpha.module("World").unwrap(),
    );
    let mut agv = Agv::start(&manufacturer, &[]);

    // Its retained `connection`, the serial number taken from the topic's `+` level.
    let (c, from) = next::<Connection>(&world, 15);
    assert_eq!(c.connection_state, "ONLINE");
    assert_eq!(c.serial_number, "tango");
    assert_eq!(c.manufacturer, manufacturer);
    assert_eq!(from, "Tango");

    let outcome = drive
        .send("Tango", "Drive", &order(&manufacturer, "o-1"))
        .expect("send")
        .wait();
    // QoS 1: the broker confirmed it has the order (the AGV subscribes to it), not that the
    // AGV got it; its state says that.
    assert_eq!(outcome, Outcome::Relayed { attempts: 1 }, "{outcome}");
    let deadline = Instant::now() + Duration::from_secs(10);
    let state = loop {
        let (s, _) = next::<State>(&world, 5);
        if s.order_id == "o-1" {
            break s;
        }
        assert!(Instant::now() < deadline, "no state with the order");
    };
    assert_eq!(state.last_node_id, "n1");
    assert!(state.driving);
    assert_eq!(state.battery_state.battery_charge, 87.5);
    assert_eq!(state.agv_position.map(|p| p.map_id), Some("floor-1".into()));

    let actions = InstantActions {
        header_id: 2,
        timestamp: "2026-12-02T12:00:01.000Z".into(),
        version: "2.0.0".into(),
        manufacturer: manufacturer.clone(),
        serial_number: "tango".into(),
        actions: vec![Action {
            action_id: "a-1".into(),
            action_type: "startPause".into(),
            blocking_type: "HARD".into(),
        }],
    };
    let outcome = drive.send("Tango", "Drive", &actions).expect("send").wait();
    assert_eq!(outcome, Outcome::Relayed { attempts: 1 }, "{outcome}");
    let deadline = Instant::now() + Duration::from_secs(10);
    loop {
        let s = world
            .recv_timeout::<State>(Duration::from_secs(5))
            .expect("the AGV's state");
        if let Some(a) = s
            .message
            .action_states
            .iter()
            .find(|a| a.action_id == "a-1")
        {
            assert_eq!(a.action_status, "FINISHED");
            break;
        }
        assert!(Instant::now() < deadline, "no state with the action");
    }
    let link = &alpha.stats().links[0].1;
    assert!(
        link.frames_sent >= 2 && link.frames_received >= 3,
        "{link:?}"
    );
    assert_eq!(link.frames_dropped, 0, "{link:?}");

    // It crashes: the broker publishes its last will on its connection topic.
    let _ = agv.0.kill();
    let _ = agv.0.wait();
    let states = |want: &str| {
        let (c, _) = next::<Connection>(&world, 10);
        assert_eq!(c.connection_state, want);
    };
    states("CONNECTIONBROKEN");
    // Back for a second, then it leaves saying so.
    let mut again = Agv::start(&manufacturer, &["--seconds", "1"]);
    states("ONLINE");
    states("OFFLINE");
    assert!(again.0.wait().expect("the AGV exits").success());
    let raw = RawClient::connect(&broker(), &format!("raw-{manufacturer}"), None);
    raw.publish(
        &format!("uagv/v2/{manufacturer}/tango/connection"),
        b"",
        true,
    );
    raw.disconnect();
}

/// Frames a bridge hands its system.
#[derive(Default)]
struct Frames(Mutex<Vec<Vec<u8>>>);

impl FrameSink for Frames {
    fn on_frame(&self, frame: &[u8], _from: Peer) {
        self.0.lock().unwrap().push(frame.to_vec());
    }
}

fn bridge_settings(fleet: &Fleet) -> &BridgeSettings {
    let TransportSettings::Registered(s) = &fleet.transports[0].settings else {
        panic!("registered settings expected");
    };
    s.downcast_ref().expect("mqtt_bridge settings")
}

#[test]
fn payloads_that_are_not_json_or_do_not_fit_are_counted_and_named() {
    let manufacturer = format!("acme-{}", unique_fleet());
    let fleet = fleet(&manufacturer);
    // Retained garbage on a mapped topic (replayed to every new subscriber).
    let raw = RawClient::connect(&broker(), &format!("raw-{manufacturer}"), None);
    let connection = format!("uagv/v2/{manufacturer}/tango/connection");
    raw.publish(&connection, b"\x00retained garbage", true);
    std::thread::sleep(Duration::from_millis(200));
    let frames = Arc::new(Frames::default());
    let bridge = MqttBridge::open(
        &fleet,
        SystemId(0),
        bridge_settings(&fleet),
        &NO_SHAPES,
        frames.clone(),
    )
    .expect("the bridge opens");
    let _agv = Agv::start(&manufacturer, &["--garbage"]);
    eventually(
        15,
        "the bad states and the retained garbage dropped, good ones delivered",
        || bridge.stats().frames_dropped >= 3 && frames.0.lock().unwrap().len() >= 3,
    );
    let problems = bridge.problems().join("\n");
    assert!(
        problems.contains(&format!("a message on {connection} is not JSON: ")),
        "{problems}"
    );
    let state = format!("uagv/v2/{manufacturer}/tango/state");
    assert!(
        problems.contains(&format!("a message on {state} is not JSON: ")),
        "{problems}"
    );
    assert!(
        problems.contains(&format!(
            "a message on {state} does not fit message type 52 for World: field `driving` is \
             a string, the mapping says bool (dropped)"
        )),
        "{problems}"
    );
    // A state without a field the mapping requires, and a JSON array.
    raw.publish(&state, br#"{"headerId": 1}"#, false);
    raw.publish(&state, b"[1, 2]", false);
    eventually(10, "two more dropped", || bridge.problems().len() >= 4);
    let problems = bridge.problems().join("\n");
    assert!(
        problems.contains("field `timestamp` is missing (dropped)"),
        "{problems}"
    );
    assert!(
        problems.contains(&format!(
            "a message on {state} is not a JSON object, message type 52 is (dropped)"
        )),
        "{problems}"
    );
    raw.publish(&connection, b"", true);
    raw.disconnect();
}

/// A broker with a Maximum Packet Size: a JSON publish larger than it leaves for the payload
/// is refused at the send, nothing published.
#[test]
fn an_oversized_json_publish_is_refused_before_publishing() {
    let small = common::Mosquitto::start("max_packet_size 2048");
    let manufacturer = format!("acme-{}", unique_fleet());
    let text = fleet_text(&small.address, &manufacturer);
    let fleet = hetcomm::parse_fleet(&text, "agv.toml", None).expect("valid");
    let alpha = Comm::open_fleet(&fleet, "Alpha").expect("opens");
    let drive = alpha.module("Drive").unwrap();
    let mut big = order(&manufacturer, "o-big");
    big.nodes = (0..100)
        .map(|i| Node {
            node_id: format!("node-{i}"),
            sequence_id: i * 2,
            released: true,
        })
        .collect();
    let outcome = drive.send("Tango", "Drive", &big).expect("send").wait();
    let Outcome::Failed { reason, .. } = &outcome else {
        panic!("{outcome}");
    };
    let topic = format!("uagv/v2/{manufacturer}/tango/order");
    let max = 2048 - hetcomm_link_mqtt::publish_overhead(&topic);
    assert!(reason.to_string().contains(&max.to_string()), "{reason}");
    assert_eq!(alpha.stats().links[0].1.frames_sent, 0, "nothing published");
    // One that fits goes; nobody subscribes to the order topic here, and the broker's
    // PUBACK says so: the send fails, saying nobody received it (not *sent*).
    let outcome = drive
        .send("Tango", "Drive", &order(&manufacturer, "o-1"))
        .expect("send")
        .wait();
    let Outcome::Failed {
        reason: hetcomm::FailReason::Relay(why),
        attempts: 1,
    } = &outcome
    else {
        panic!("{outcome}");
    };
    assert!(why.contains("no subscriber"), "{why}");
    assert_eq!(alpha.stats().links[0].1.frames_sent, 1, "the one that fits");
}

#[test]
fn sends_that_do_not_convert_fail_naming_the_field() {
    let manufacturer = format!("acme-{}", unique_fleet());
    let alpha = Comm::open_fleet(&fleet(&manufacturer), "Alpha").expect("Alpha opens");
    let drive = alpha.module("Drive").unwrap();
    // An undeclared type 50 (MessagePack {"orderId": "o"}): the mapping's other fields are
    // missing.
    let mut payload = vec![0x81, 0xa7];
    payload.extend_from_slice(b"orderId");
    payload.extend_from_slice(&[0xa1, b'o']);
    let outcome = drive
        .send_raw(
            "Tango",
            "Drive",
            MessageType(50),
            &payload,
            SendOptions::default(),
        )
        .expect("send")
        .wait();
    // Refused by the link: failed at once (one attempt), not "unreachable", not retried.
    let Outcome::Failed {
        reason: reason @ hetcomm::FailReason::Refused(_),
        attempts: 1,
    } = &outcome
    else {
        panic!("{outcome}");
    };
    let reason = reason.to_string();
    assert!(
        reason.contains(&format!(
            "message type 50 for Drive does not convert to the JSON of topic \
             uagv/v2/{manufacturer}/tango/order: field `headerId` is missing"
        )),
        "{reason}"
    );
    // Bytes have no JSON counterpart.
    let mut payload = vec![0x81, 0xa4];
    payload.extend_from_slice(b"blob");
    payload.extend_from_slice(&[0xc4, 1, 7]);
    let outcome = drive
        .send_raw(
            "Tango",
            "Drive",
            MessageType(51),
            &payload,
            SendOptions::default(),
        )
        .expect("send")
        .wait();
    assert!(
        outcome
            .to_string()
            .contains("field `blob` is bytes, which JSON cannot carry"),
        "{outcome}"
    );
    // A type no topic is mapped for.
    let outcome = drive
        .send_raw(
            "Tango",
            "Drive",
            MessageType(99),
            &[0x80],
            SendOptions::default(),
        )
        .expect("send")
        .wait();
    assert!(
        outcome
            .to_string()
            .contains("no MQTT topic is mapped for message type 99"),
        "{outcome}"
    );
    assert_eq!(alpha.stats().links[0].1.frames_sent, 0, "nothing published");
}

#[test]
fn declared_types_that_do_not_fit_refuse_to_open() {
    let fleet = fleet(&format!("acme-{}", unique_fleet()));
    Comm::open_fleet_options(&fleet, "Alpha", declared()).expect("the example's types fit");
    let e = Comm::open_fleet_options(&fleet, "Alpha", OpenOptions::new().message::<BadState>())
        .map(drop)
        .unwrap_err()
        .to_string();
    assert!(
        e.contains(
            "does not convert to message type 52 (BadState): field `driving` is a string in \
             BadState, the mapping says bool"
        ),
        "{e}"
    );
}

#[test]
fn the_fleet_files_mistakes_are_located() {
    let good = fleet_text("127.0.0.1:1", "acme");
    hetcomm::parse_fleet(&good, "agv.toml", None).expect("the example is valid");
    let fleet = hetcomm::parse_fleet(&good, "agv.toml", None).unwrap();
    let b = bridge_settings(&fleet);
    assert_eq!(b.robot, "Tango");
    assert_eq!(b.publish.len(), 2);
    assert_eq!(b.subscribe[0].captures, Vec::<String>::new());
    let connection = b
        .subscribe
        .iter()
        .find(|m| m.topic.ends_with("/connection"))
        .unwrap();
    assert_eq!(connection.captures, vec!["serialNumber".to_string()]);
    assert_eq!(connection.message, 53);

    let errors = |text: String| {
        hetcomm::parse_fleet(&text, "agv.toml", None)
            .unwrap_err()
            .to_string()
    };
    let e = errors(good.replace("driving:bool", "driving:text"));
    assert!(
        e.contains(
            "mapping of `uagv/v2/acme/tango/state`: `text` in `driving:text` is not a JSON type \
             (string, number, integer, bool, object, array, any)"
        ),
        "{e}"
    );
    assert!(e.starts_with("agv.toml:2"), "located: {e}");
    let e = errors(good.replace("uagv/v2/acme/tango/order", "uagv/v2/acme/+/order"));
    assert!(
        e.contains("a published topic has no wildcards (`+`, `#`)"),
        "{e}"
    );
    let e = errors(good.replace("+serialNumber", "+serialNumber +extra"));
    assert!(
        e.contains("names 2 captures, but the topic has 1 `+` level(s)"),
        "{e}"
    );
    let e = errors(good.replace("\"Drive 50 ", "\"Drive x50 "));
    assert!(e.contains("`x50` is not a message type id"), "{e}");
    let e = errors(good.replace("delivery = \"unacknowledged\"", ""));
    assert!(
        e.contains("(kind mqtt_bridge) carries plain JSON publishes, which nobody acknowledges"),
        "{e}"
    );
    let e = errors(good.replace("security = \"none\"", ""));
    assert!(e.contains("add `security = \"none\"`"), "{e}");
    let e = errors(good.replace("robot = \"Tango\"", ""));
    assert!(e.contains("missing required setting `robot`"), "{e}");
    let e = errors(good.replace("qos = 1", "qos = 2"));
    assert!(e.contains("must be from 0 to 1, found 2"), "{e}");
    let e = errors(good.replace("qos = 1", "prefix = \"x\""));
    assert!(e.contains("unknown"), "{e}");
}

#[test]
fn an_unreachable_broker_fails_the_open_naming_it() {
    let port = common::free_port();
    let text = fleet_text(&format!("127.0.0.1:{port}"), "acme")
        .replace("qos = 1", "qos = 1\nopen_timeout_ms = 1500");
    let fleet = hetcomm::parse_fleet(&text, "agv.toml", None).unwrap();
    let started = Instant::now();
    let e = Comm::open_fleet(&fleet, "Alpha")
        .map(drop)
        .unwrap_err()
        .to_string();
    assert!(
        started.elapsed() < Duration::from_secs(4),
        "{:?}",
        started.elapsed()
    );
    assert!(
        e.contains(&format!(
            "cannot reach the MQTT broker mqtt://127.0.0.1:{port} within 1500 ms"
        )),
        "{e}"
    );
}

/// The broker going away: a send fails after `reconnect_wait_ms`, naming it; when it is back
/// the bridge reconnects and subscribes again, and messages go and come.
#[test]
fn a_broker_restart_fails_sends_while_it_is_gone_then_traffic_resumes() {
    let mut own = common::Mosquitto::start("");
    let manufacturer = format!("acme-{}", unique_fleet());
    let text = fleet_text(&own.address, &manufacturer)
        .replace("qos = 1", "qos = 1\nreconnect_wait_ms = 300");
    let fleet = hetcomm::parse_fleet(&text, "agv.toml", None).expect("valid");
    let alpha = Comm::open_fleet_options(&fleet, "Alpha", declared()).expect("opens");
    let (drive, world) = (
        alpha.module("Drive").unwrap(),
        alpha.module("World").unwrap(),
    );
    own.kill();
    // Until the client sees the connection gone, a send is queued for it, and the broker
    // never answers it: unconfirmed. Then sends fail, each after `reconnect_wait_ms`.
    let deadline = Instant::now() + Duration::from_secs(5);
    let (outcome, started) = loop {
        let started = Instant::now();
        let outcome = drive
            .send("Tango", "Drive", &order(&manufacturer, "o-1"))
            .expect("send")
            .wait();
        if outcome.is_failed() {
            break (outcome, started);
        }
        assert!(matches!(outcome, Outcome::Unconfirmed { .. }), "{outcome}");
        assert!(
            Instant::now() < deadline,
            "no send failed with the broker gone"
        );
        std::thread::sleep(Duration::from_millis(50));
    };
    let Outcome::Failed { reason, .. } = &outcome else {
        panic!("{outcome}");
    };
    assert!(
        reason.to_string().contains(&format!(
            "the MQTT broker mqtt://{} is unreachable",
            own.address
        )),
        "{reason}"
    );
    assert!(
        started.elapsed() < Duration::from_secs(3),
        "{:?}",
        started.elapsed()
    );
    own.restart();
    // Subscribed again: a state published now arrives.
    let raw = RawClient::connect(&own.address, &format!("raw-{manufacturer}"), None);
    let state = format!("uagv/v2/{manufacturer}/tango/state");
    let body = br#"{"headerId": 1, "timestamp": "t", "orderId": "o-2", "orderUpdateId": 0,
        "lastNodeId": "n1", "driving": false, "actionStates": [], "errors": [],
        "batteryState": {"batteryCharge": 50.0, "charging": true}, "operatingMode": "MANUAL"}"#;
    let deadline = Instant::now() + Duration::from_secs(10);
    let got = loop {
        raw.publish(&state, body, false);
        if let Ok(r) = world.recv_timeout::<State>(Duration::from_millis(300)) {
            break r.message;
        }
        assert!(Instant::now() < deadline, "no state after the restart");
    };
    assert_eq!(got.order_id, "o-2");
    assert!(got.agv_position.is_none());
    // And orders leave again: once a subscriber (the raw client standing in for the AGV) is
    // there, the broker confirms them.
    raw.subscribe(&format!("uagv/v2/{manufacturer}/tango/order"));
    common::fleet::eventually(10, "an order relayed after the restart", || {
        let outcome = drive
            .send("Tango", "Drive", &order(&manufacturer, "o-3"))
            .expect("send")
            .wait();
        outcome == Outcome::Relayed { attempts: 1 }
    });
    raw.disconnect();
}

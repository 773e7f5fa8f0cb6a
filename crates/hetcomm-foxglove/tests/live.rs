//! A live view of two in-process systems read back by a WebSocket client: the message and
//! outcome topics carry the observed traffic as JSON, named by the fleet.

use std::net::TcpStream;
use std::sync::atomic::{AtomicBool, Ordering};
use std::sync::Arc;
use std::time::{Duration, Instant};

use hetcomm::{LocalFleet, MessageType, SendOptions};
use hetcomm_foxglove::{message_topic, outcome_topic, FoxgloveView, SERVER_TOPIC};
use serde_json::{json, Value};
use tungstenite::client::IntoClientRequest;
use tungstenite::stream::MaybeTlsStream;
use tungstenite::{Message, WebSocket};

const FLEET: &str = r#"
name = "two"
[systems]
A = 0
B = 1
[modules]
M = 0
[letters]
R = "local"
[transports.local]
kind = "inproc"
[table]
columns = ["A", "B"]
A = ["X", "R"]
B = ["R", "X"]
"#;

type Socket = WebSocket<MaybeTlsStream<TcpStream>>;

fn connect(port: u16) -> Socket {
    let mut request = format!("ws://127.0.0.1:{port}")
        .into_client_request()
        .unwrap();
    request
        .headers_mut()
        .insert("Sec-WebSocket-Protocol", "foxglove.sdk.v1".parse().unwrap());
    let (socket, response) = tungstenite::connect(request).unwrap();
    assert_eq!(
        response.headers()["Sec-WebSocket-Protocol"],
        "foxglove.sdk.v1"
    );
    if let MaybeTlsStream::Plain(s) = socket.get_ref() {
        s.set_read_timeout(Some(Duration::from_millis(200)))
            .unwrap();
    }
    socket
}

#[test]
fn messages_and_outcomes_are_served_as_json_on_their_topics() {
    let fleet = LocalFleet::open(hetcomm::parse_fleet(FLEET, "<test>", None).unwrap()).unwrap();
    let view = FoxgloveView::start("127.0.0.1:0", "hetcomm test").unwrap();
    let watch = view.watch(fleet.systems()).unwrap();
    let mut ws = connect(view.port());
    let first = ws.read().unwrap();
    let info: Value = serde_json::from_str(first.to_text().unwrap()).unwrap();
    assert_eq!(info["op"], "serverInfo");
    assert_eq!(info["name"], "hetcomm test");

    // A sends to B until the test has what it needs: channels are advertised with their first
    // message, so the client subscribes after that and sees the later ones.
    let a = fleet.system("A").unwrap().module("M").unwrap();
    let stop = Arc::new(AtomicBool::new(false));
    let sender = {
        let stop = stop.clone();
        std::thread::spawn(move || {
            let mut n = 0u8;
            while !stop.load(Ordering::Relaxed) && n < 120 {
                // MessagePack {"x": n}
                let payload = [0x81, 0xa1, b'x', n & 0x7f];
                let ticket = a
                    .send_raw("B", "M", MessageType(7), &payload, SendOptions::default())
                    .unwrap();
                ticket.wait_timeout(Duration::from_secs(5));
                n += 1;
                std::thread::sleep(Duration::from_millis(20));
            }
        })
    };
    let topics = [
        message_topic("B", "M", 7),
        outcome_topic("A", "B"),
        SERVER_TOPIC.to_string(),
    ];
    let mut subscribed: Vec<(u32, String)> = Vec::new();
    // (subscription id, channel id)
    let mut channel_ids: Vec<(u32, u64)> = Vec::new();
    let mut got: Vec<(String, u64, Value)> = Vec::new();
    let deadline = Instant::now() + Duration::from_secs(20);
    let complete = |got: &Vec<(String, u64, Value)>| {
        topics
            .iter()
            .all(|t| got.iter().filter(|(topic, _, _)| topic == t).count() >= 2)
    };
    while !complete(&got) {
        assert!(
            Instant::now() < deadline,
            "deadline: subscribed {subscribed:?}, counters {:?}, got {} messages",
            watch.counters(),
            got.len(),
        );
        let msg = match ws.read() {
            Ok(m) => m,
            Err(tungstenite::Error::Io(e))
                if matches!(
                    e.kind(),
                    std::io::ErrorKind::WouldBlock | std::io::ErrorKind::TimedOut
                ) =>
            {
                continue
            }
            Err(e) => panic!("{e}"),
        };
        match msg {
            Message::Text(text) => {
                let op: Value = serde_json::from_str(&text).unwrap();
                // The SDK's server sends an advertisement before it records the channel as
                // advertised: a subscription made the instant it arrives can be refused as
                // an unknown channel. Ask again.
                if op["op"] == "status" {
                    let refused = op["message"]
                        .as_str()
                        .and_then(|m| m.strip_prefix("Unknown channel ID: "))
                        .and_then(|id| id.parse::<u64>().ok());
                    let ours = channel_ids.iter().find(|(_, c)| Some(*c) == refused);
                    if let Some((id, channel)) = ours {
                        std::thread::sleep(Duration::from_millis(20));
                        let op = json!({"op": "subscribe",
                                        "subscriptions": [{"id": id, "channelId": channel}]});
                        ws.send(Message::text(op.to_string())).unwrap();
                    }
                    continue;
                }
                if op["op"] != "advertise" {
                    continue;
                }
                let mut new = Vec::new();
                for ch in op["channels"].as_array().unwrap() {
                    let topic = ch["topic"].as_str().unwrap().to_string();
                    if topics.contains(&topic) && !subscribed.iter().any(|(_, t)| *t == topic) {
                        assert_eq!(ch["encoding"], "json", "{ch}");
                        let schema: Value =
                            serde_json::from_str(ch["schema"].as_str().unwrap()).unwrap();
                        assert_eq!(schema["type"], "object", "{ch}");
                        let id = subscribed.len() as u32 + 1;
                        subscribed.push((id, topic));
                        channel_ids.push((id, ch["id"].as_u64().unwrap()));
                        new.push(json!({"id": id, "channelId": ch["id"]}));
                    }
                }
                if !new.is_empty() {
                    let op = json!({"op": "subscribe", "subscriptions": new});
                    ws.send(Message::text(op.to_string())).unwrap();
                }
            }
            Message::Binary(frame) => {
                assert_eq!(frame[0], 1, "message data opcode");
                let sid = u32::from_le_bytes(frame[1..5].try_into().unwrap());
                let log_time = u64::from_le_bytes(frame[5..13].try_into().unwrap());
                let topic = subscribed
                    .iter()
                    .find(|(id, _)| *id == sid)
                    .unwrap()
                    .1
                    .clone();
                got.push((
                    topic,
                    log_time,
                    serde_json::from_slice(&frame[13..]).unwrap(),
                ));
            }
            _ => {}
        }
    }
    stop.store(true, Ordering::Relaxed);
    sender.join().unwrap();
    let on = |t: &String| {
        let t = t.clone();
        got.iter().filter(move |(topic, _, _)| *topic == t)
    };
    for (_, log_time, m) in on(&topics[0]) {
        // Received by B (a watched system): shown once, as it arrived.
        assert_eq!(m["event"], "receipt", "{m}");
        assert_eq!(m["status"], "delivered", "{m}");
        assert_eq!(m["source"], json!({"system": "A", "module": "M"}), "{m}");
        assert_eq!(
            m["destination"],
            json!({"system": "B", "module": "M"}),
            "{m}"
        );
        assert_eq!(m["message_type"], 7, "{m}");
        assert_eq!(m["transport_name"], "local", "{m}");
        assert!(m["payload"]["x"].is_u64(), "{m}");
        // Log times are the wall clock (the viewer may be elsewhere).
        assert!(*log_time > 1_577_836_800_000_000_000, "{log_time}");
    }
    for (_, _, o) in on(&topics[1]) {
        assert_eq!(o["event"], "outcome", "{o}");
        assert_eq!(o["outcome"], "delivered", "{o}");
        assert_eq!(
            (
                o["source_system"].as_str(),
                o["destination_system"].as_str()
            ),
            (Some("A"), Some("B"))
        );
    }
    let server = &on(&topics[2]).next_back().unwrap().2;
    assert_eq!(server["dropped"], 0, "{server}");
    let counters = watch.finish();
    assert_eq!(counters.dropped, 0);
    assert_eq!(counters.unpublishable, 0);
    // Each send: one receipt and one outcome, all published.
    assert_eq!(counters.observed, counters.published);
    assert!(counters.published >= 4, "{counters:?}");
}

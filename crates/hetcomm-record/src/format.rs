//! What a recording holds: one [`Event`] per MCAP message, its topic and its JSON Schema.
//!
//! Topics (every one a standard MCAP channel; `Src`, `Dst`, `Module` are the fleet's names):
//!
//! | topic | what | schema |
//! |---|---|---|
//! | `/send/Src/SrcModule/Dst/DstModule` | every attempt of a send (`attempt` 1 is the send) | `hetcomm.Send.type<N>` |
//! | `/receipt/Dst/DstModule` | every message handed to an inbox of a recorded system | `hetcomm.Receipt.type<N>` |
//! | `/outcome/Src/Dst` | how each send of a recorded system ended | `hetcomm.Outcome` |
//! | `/path_switch/Src/Dst` | each time a recorded system's sends to Dst moved to another transport (docs/failover.md) | `hetcomm.PathSwitch` |
//!
//! A send and its outcome share (`source.system`, `destination.system`, `seq`); a receipt
//! carries the same source system and `seq`. In JSON recordings the payload is the decoded
//! MessagePack value (`payload`); when that value would not encode back to the very same bytes
//! (binary strings, 32-bit floats, extension types, non-string map keys, a payload that is
//! not MessagePack) the bytes are kept too, base64 (`payload_b64`), so a replay sends exactly
//! what was recorded.

use base64::Engine as _;
use serde::{Deserialize, Serialize};
use serde_json::value::RawValue;
use serde_json::{json, Value};

/// Whether `topic` is one of the events' channels (the table above); a recording may hold
/// other channels beside them (`hetcomm demo --record` writes the rovers' poses for Foxglove).
pub fn is_event_topic(topic: &str) -> bool {
    ["/send/", "/receipt/", "/outcome/", "/path_switch/"]
        .iter()
        .any(|p| topic.starts_with(p))
}

/// Name of the MCAP metadata record that describes a recording.
pub const METADATA_NAME: &str = "hetcomm";
/// MCAP profile written into the header.
pub const PROFILE: &str = "hetcomm";

/// A system and module by name.
#[derive(Clone, Debug, PartialEq, Eq, Serialize, Deserialize)]
pub struct Addr {
    /// System name (or `#id` when the fleet does not name it).
    pub system: String,
    /// Module name (or `#id`).
    pub module: String,
}

/// One recorded event. Serialized as one flat JSON object whose `event` field says which.
#[derive(Clone, Debug)]
pub enum Event {
    /// One attempt of a send leaving a recorded system.
    Send(SendEvent),
    /// A message handed to an inbox of a recorded system (or refused by it).
    Receipt(ReceiptEvent),
    /// A send of a recorded system ended.
    Outcome(OutcomeEvent),
    /// A recorded system's sends to a destination moved to another transport
    /// (docs/failover.md).
    PathSwitch(PathSwitchEvent),
}

impl Event {
    /// When it happened, microseconds on the recorded system's clock.
    pub fn time_us(&self) -> u64 {
        match self {
            Event::Send(e) => e.time_us,
            Event::Receipt(e) => e.time_us,
            Event::Outcome(e) => e.time_us,
            Event::PathSwitch(e) => e.time_us,
        }
    }
}

/// The envelope and payload of a message, as sent and as received.
#[derive(Clone, Debug, Serialize, Deserialize)]
pub struct Envelope {
    /// Sending system and module.
    pub source: Addr,
    /// Destination system and module.
    pub destination: Addr,
    /// The sender's sequence number towards this destination.
    pub seq: u64,
    /// Message type id.
    pub message_type: u32,
    /// Receive priority.
    pub priority: u8,
    /// The transport's one-byte tag (the table letter), as a character.
    pub transport: String,
    /// The transport's name in the fleet (when the tag names one).
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub transport_name: Option<String>,
    /// The sender asked for an acknowledgement.
    pub ack_requested: bool,
    /// Part of a broadcast.
    pub broadcast: bool,
    /// The sender's timestamp, microseconds.
    pub timestamp_us: u64,
    /// Payload length in bytes.
    pub size: usize,
    /// The payload decoded, as JSON text (map keys in the order they were sent; absent when
    /// it is not MessagePack).
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub payload: Option<Box<RawValue>>,
    /// The payload's bytes, base64, when `payload` does not give them back exactly (and always
    /// in MessagePack recordings' JSON view).
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub payload_b64: Option<String>,
}

impl Envelope {
    /// The decoded payload as a JSON value (None when it is not MessagePack).
    pub fn payload_value(&self) -> Option<Value> {
        serde_json::from_str(self.payload.as_ref()?.get()).ok()
    }

    /// The payload's bytes as they were sent.
    pub fn payload_bytes(&self) -> Result<Vec<u8>, String> {
        if let Some(b) = &self.payload_b64 {
            return base64::engine::general_purpose::STANDARD
                .decode(b)
                .map_err(|e| format!("payload_b64: {e}"));
        }
        match &self.payload {
            Some(raw) => {
                let v: rmpv::Value =
                    serde_json::from_str(raw.get()).map_err(|e| format!("payload: {e}"))?;
                let mut out = Vec::new();
                rmpv::encode::write_value(&mut out, &v).map_err(|e| e.to_string())?;
                Ok(out)
            }
            None => Err("neither payload nor payload_b64".into()),
        }
    }
}

/// One attempt of a send.
#[derive(Clone, Debug)]
pub struct SendEvent {
    /// When the attempt left, microseconds on the sender's clock.
    pub time_us: u64,
    /// Envelope and payload.
    pub message: Envelope,
    /// 1 for the send, 2 and more for retransmissions.
    pub attempt: u32,
    /// `routed`, `unqueued` or `direct`.
    pub route: String,
    /// The link index it was handed to.
    pub link: Option<usize>,
}

/// A message handed to an inbox.
#[derive(Clone, Debug)]
pub struct ReceiptEvent {
    /// When, microseconds on the receiver's clock.
    pub time_us: u64,
    /// Envelope and payload.
    pub message: Envelope,
    /// `delivered`, `inbox_full` or `unknown_module`.
    pub status: String,
    /// The link index it came on (absent: handed over directly in process).
    pub link: Option<usize>,
}

/// How a send ended.
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
pub struct OutcomeEvent {
    /// When, microseconds on the sender's clock.
    pub time_us: u64,
    /// The sending system.
    pub source_system: String,
    /// The destination system.
    pub destination_system: String,
    /// The send's sequence number.
    pub seq: u64,
    /// `delivered`, `sent`, `unconfirmed` or `failed`.
    pub outcome: String,
    /// Transmissions it took.
    pub attempts: u32,
    /// From the first transmission to the acknowledgement (delivered only), microseconds.
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub latency_us: Option<u64>,
    /// Why it was not delivered (unconfirmed and failed only).
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub reason: Option<String>,
}

/// A system's sends to a destination moved from one transport to another.
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
pub struct PathSwitchEvent {
    /// When the router decided it, microseconds on the sending system's clock.
    pub time_us: u64,
    /// The sending system.
    pub source_system: String,
    /// The destination system.
    pub destination_system: String,
    /// The transport its sends took until then.
    pub from: String,
    /// The transport they take from then on.
    pub to: String,
    /// The system's switches so far, this one included.
    pub number: u64,
}

/// The one JSON object every event is written as (serde's flattening and internal tags
/// buffer values, which a [`RawValue`] payload does not survive).
#[derive(Serialize, Deserialize)]
struct Flat {
    event: String,
    time_us: u64,
    #[serde(default, skip_serializing_if = "Option::is_none")]
    source: Option<Addr>,
    #[serde(default, skip_serializing_if = "Option::is_none")]
    destination: Option<Addr>,
    #[serde(default, skip_serializing_if = "Option::is_none")]
    message_type: Option<u32>,
    #[serde(default, skip_serializing_if = "Option::is_none")]
    priority: Option<u8>,
    #[serde(default, skip_serializing_if = "Option::is_none")]
    transport: Option<String>,
    #[serde(default, skip_serializing_if = "Option::is_none")]
    transport_name: Option<String>,
    #[serde(default, skip_serializing_if = "Option::is_none")]
    ack_requested: Option<bool>,
    #[serde(default, skip_serializing_if = "Option::is_none")]
    broadcast: Option<bool>,
    #[serde(default, skip_serializing_if = "Option::is_none")]
    timestamp_us: Option<u64>,
    #[serde(default, skip_serializing_if = "Option::is_none")]
    size: Option<usize>,
    #[serde(default, skip_serializing_if = "Option::is_none")]
    payload_b64: Option<String>,
    #[serde(default, skip_serializing_if = "Option::is_none")]
    attempt: Option<u32>,
    #[serde(default, skip_serializing_if = "Option::is_none")]
    route: Option<String>,
    #[serde(default, skip_serializing_if = "Option::is_none")]
    status: Option<String>,
    #[serde(default, skip_serializing_if = "Option::is_none")]
    link: Option<usize>,
    #[serde(default, skip_serializing_if = "Option::is_none")]
    source_system: Option<String>,
    #[serde(default, skip_serializing_if = "Option::is_none")]
    destination_system: Option<String>,
    #[serde(default, skip_serializing_if = "Option::is_none")]
    seq: Option<u64>,
    #[serde(default, skip_serializing_if = "Option::is_none")]
    outcome: Option<String>,
    #[serde(default, skip_serializing_if = "Option::is_none")]
    attempts: Option<u32>,
    #[serde(default, skip_serializing_if = "Option::is_none")]
    latency_us: Option<u64>,
    #[serde(default, skip_serializing_if = "Option::is_none")]
    reason: Option<String>,
    #[serde(default, skip_serializing_if = "Option::is_none")]
    from: Option<String>,
    #[serde(default, skip_serializing_if = "Option::is_none")]
    to: Option<String>,
    #[serde(default, skip_serializing_if = "Option::is_none")]
    number: Option<u64>,
    #[serde(default, skip_serializing_if = "Option::is_none")]
    payload: Option<Box<RawValue>>,
}

impl Serialize for Event {
    fn serialize<S: serde::Serializer>(&self, s: S) -> Result<S::Ok, S::Error> {
        let mut f = Flat {
            event: String::new(),
            time_us: self.time_us(),
            source: None,
            destination: None,
            message_type: None,
            priority: None,
            transport: None,
            transport_name: None,
            ack_requested: None,
            broadcast: None,
            timestamp_us: None,
            size: None,
            payload_b64: None,
            attempt: None,
            route: None,
            status: None,
            link: None,
            source_system: None,
            destination_system: None,
            seq: None,
            outcome: None,
            attempts: None,
            latency_us: None,
            reason: None,
            from: None,
            to: None,
            number: None,
            payload: None,
        };
        let mut env = |m: &Envelope| {
            f.source = Some(m.source.clone());
            f.destination = Some(m.destination.clone());
            f.message_type = Some(m.message_type);
            f.priority = Some(m.priority);
            f.transport = Some(m.transport.clone());
            f.transport_name = m.transport_name.clone();
            f.ack_requested = Some(m.ack_requested);
            f.broadcast = Some(m.broadcast);
            f.timestamp_us = Some(m.timestamp_us);
            f.size = Some(m.size);
            f.payload_b64 = m.payload_b64.clone();
            f.seq = Some(m.seq);
            f.payload = m.payload.clone();
        };
        match self {
            Event::Send(e) => {
                env(&e.message);
                f.event = "send".into();
                f.attempt = Some(e.attempt);
                f.route = Some(e.route.clone());
                f.link = e.link;
            }
            Event::Receipt(e) => {
                env(&e.message);
                f.event = "receipt".into();
                f.status = Some(e.status.clone());
                f.link = e.link;
            }
            Event::Outcome(e) => {
                f.event = "outcome".into();
                f.source_system = Some(e.source_system.clone());
                f.destination_system = Some(e.destination_system.clone());
                f.seq = Some(e.seq);
                f.outcome = Some(e.outcome.clone());
                f.attempts = Some(e.attempts);
                f.latency_us = e.latency_us;
                f.reason = e.reason.clone();
            }
            Event::PathSwitch(e) => {
                f.event = "path_switch".into();
                f.source_system = Some(e.source_system.clone());
                f.destination_system = Some(e.destination_system.clone());
                f.from = Some(e.from.clone());
                f.to = Some(e.to.clone());
                f.number = Some(e.number);
            }
        }
        f.serialize(s)
    }
}

impl<'de> Deserialize<'de> for Event {
    fn deserialize<D: serde::Deserializer<'de>>(d: D) -> Result<Self, D::Error> {
        use serde::de::Error;
        let f = Flat::deserialize(d)?;
        let missing = |field: &str| D::Error::custom(format!("{} without {field}", f.event));
        let envelope = |payload: Option<Box<RawValue>>| -> Result<Envelope, D::Error> {
            Ok(Envelope {
                source: f.source.clone().ok_or_else(|| missing("source"))?,
                destination: f
                    .destination
                    .clone()
                    .ok_or_else(|| missing("destination"))?,
                seq: f.seq.ok_or_else(|| missing("seq"))?,
                message_type: f.message_type.ok_or_else(|| missing("message_type"))?,
                priority: f.priority.unwrap_or_default(),
                transport: f.transport.clone().unwrap_or_default(),
                transport_name: f.transport_name.clone(),
                ack_requested: f.ack_requested.unwrap_or_default(),
                broadcast: f.broadcast.unwrap_or_default(),
                timestamp_us: f.timestamp_us.unwrap_or_default(),
                size: f.size.unwrap_or_default(),
                payload,
                payload_b64: f.payload_b64.clone(),
            })
        };
        Ok(match f.event.as_str() {
            "send" => Event::Send(SendEvent {
                time_us: f.time_us,
                message: envelope(f.payload.clone())?,
                attempt: f.attempt.ok_or_else(|| missing("attempt"))?,
                route: f.route.clone().unwrap_or_default(),
                link: f.link,
            }),
            "receipt" => Event::Receipt(ReceiptEvent {
                time_us: f.time_us,
                message: envelope(f.payload.clone())?,
                status: f.status.clone().ok_or_else(|| missing("status"))?,
                link: f.link,
            }),
            "outcome" => Event::Outcome(OutcomeEvent {
                time_us: f.time_us,
                source_system: f
                    .source_system
                    .clone()
                    .ok_or_else(|| missing("source_system"))?,
                destination_system: f
                    .destination_system
                    .clone()
                    .ok_or_else(|| missing("destination_system"))?,
                seq: f.seq.ok_or_else(|| missing("seq"))?,
                outcome: f.outcome.clone().ok_or_else(|| missing("outcome"))?,
                attempts: f.attempts.unwrap_or_default(),
                latency_us: f.latency_us,
                reason: f.reason.clone(),
            }),
            "path_switch" => Event::PathSwitch(PathSwitchEvent {
                time_us: f.time_us,
                source_system: f
                    .source_system
                    .clone()
                    .ok_or_else(|| missing("source_system"))?,
                destination_system: f
                    .destination_system
                    .clone()
                    .ok_or_else(|| missing("destination_system"))?,
                from: f.from.clone().ok_or_else(|| missing("from"))?,
                to: f.to.clone().ok_or_else(|| missing("to"))?,
                number: f.number.unwrap_or_default(),
            }),
            other => return Err(D::Error::custom(format!("unknown event {other:?}"))),
        })
    }
}

/// The outcome as (name, attempts, latency µs, reason).
pub fn outcome_parts(o: &hetcomm::Outcome) -> (&'static str, u32, Option<u64>, Option<String>) {
    match o {
        hetcomm::Outcome::Delivered { attempts, latency } => (
            "delivered",
            *attempts,
            Some(latency.as_micros() as u64),
            None,
        ),
        hetcomm::Outcome::Sent { attempts } => ("sent", *attempts, None, None),
        hetcomm::Outcome::Relayed { attempts } => ("relayed", *attempts, None, None),
        hetcomm::Outcome::Unconfirmed { reason, attempts } => {
            ("unconfirmed", *attempts, None, Some(format!("{reason:?}")))
        }
        hetcomm::Outcome::Failed { reason, attempts } => {
            ("failed", *attempts, None, Some(format!("{reason:?}")))
        }
    }
}

/// Decodes a payload for a JSON recording: (value, bytes when the value does not give them
/// back exactly).
pub fn payload_json(bytes: &[u8]) -> (Option<Box<RawValue>>, Option<String>) {
    let b64 = || Some(base64::engine::general_purpose::STANDARD.encode(bytes));
    let mut cursor = std::io::Cursor::new(bytes);
    let Ok(value) = rmpv::decode::read_value(&mut cursor) else {
        return (None, b64());
    };
    if cursor.position() as usize != bytes.len() {
        return (None, b64());
    }
    // serde_json writes maps in the order given (rmpv's Serialize keeps the wire order), and
    // reads them back into rmpv in the order written.
    let Some(raw) = serde_json::to_string(&value)
        .ok()
        .and_then(|t| RawValue::from_string(t).ok())
    else {
        return (None, b64());
    };
    let exact = serde_json::from_str::<rmpv::Value>(raw.get())
        .ok()
        .and_then(|v| {
            let mut again = Vec::with_capacity(bytes.len());
            rmpv::encode::write_value(&mut again, &v).ok()?;
            Some(again == bytes)
        })
        .unwrap_or(false);
    (Some(raw), if exact { None } else { b64() })
}

/// A MessagePack value as JSON (binary as an array of bytes, extension types as
/// `{"ext": type, "data": [bytes]}`, non-string map keys as their JSON text).
pub fn msgpack_to_json(v: &rmpv::Value) -> Value {
    use rmpv::Value as M;
    match v {
        M::Nil => Value::Null,
        M::Boolean(b) => Value::Bool(*b),
        M::Integer(i) => {
            if let Some(u) = i.as_u64() {
                json!(u)
            } else {
                json!(i.as_i64().unwrap_or_default())
            }
        }
        M::F32(f) => json!(*f as f64),
        M::F64(f) => json!(f),
        M::String(s) => match s.as_str() {
            Some(s) => Value::String(s.to_string()),
            None => json!(s.as_bytes()),
        },
        M::Binary(b) => json!(b),
        M::Array(a) => Value::Array(a.iter().map(msgpack_to_json).collect()),
        M::Map(m) => Value::Object(
            m.iter()
                .map(|(k, v)| {
                    let key = match k {
                        M::String(s) if s.as_str().is_some() => s.as_str().unwrap_or("").into(),
                        other => msgpack_to_json(other).to_string(),
                    };
                    (key, msgpack_to_json(v))
                })
                .collect(),
        ),
        M::Ext(t, d) => json!({"ext": t, "data": d}),
    }
}

/// JSON as the MessagePack value hetcomm's encoder would write for it.
pub fn json_to_msgpack(v: &Value) -> rmpv::Value {
    use rmpv::Value as M;
    match v {
        Value::Null => M::Nil,
        Value::Bool(b) => M::Boolean(*b),
        Value::Number(n) => {
            if let Some(u) = n.as_u64() {
                M::from(u)
            } else if let Some(i) = n.as_i64() {
                M::from(i)
            } else {
                M::F64(n.as_f64().unwrap_or(f64::NAN))
            }
        }
        Value::String(s) => M::from(s.as_str()),
        Value::Array(a) => M::Array(a.iter().map(json_to_msgpack).collect()),
        Value::Object(o) => M::Map(
            o.iter()
                .map(|(k, v)| (M::from(k.as_str()), json_to_msgpack(v)))
                .collect(),
        ),
    }
}

/// A JSON Schema describing `value` (its shape: types, object properties, array items).
pub fn infer_schema(value: &Value) -> Value {
    match value {
        Value::Null => json!({"type": "null"}),
        Value::Bool(_) => json!({"type": "boolean"}),
        Value::Number(n) if n.is_f64() => json!({"type": "number"}),
        Value::Number(_) => json!({"type": "integer"}),
        Value::String(_) => json!({"type": "string"}),
        Value::Array(a) => match a.first() {
            Some(first) => json!({"type": "array", "items": infer_schema(first)}),
            None => json!({"type": "array"}),
        },
        Value::Object(o) => {
            let props: serde_json::Map<String, Value> = o
                .iter()
                .map(|(k, v)| (k.clone(), infer_schema(v)))
                .collect();
            json!({"type": "object", "properties": props})
        }
    }
}

fn envelope_properties(payload: Value) -> serde_json::Map<String, Value> {
    let addr = json!({"type": "object", "properties": {
        "system": {"type": "string"}, "module": {"type": "string"}}});
    let int = json!({"type": "integer"});
    let mut p = serde_json::Map::new();
    p.insert("event".into(), json!({"type": "string"}));
    p.insert("time_us".into(), int.clone());
    p.insert("source".into(), addr.clone());
    p.insert("destination".into(), addr);
    for k in ["seq", "message_type", "priority", "timestamp_us", "size"] {
        p.insert(k.into(), int.clone());
    }
    p.insert("transport".into(), json!({"type": "string"}));
    p.insert("transport_name".into(), json!({"type": "string"}));
    p.insert("ack_requested".into(), json!({"type": "boolean"}));
    p.insert("broadcast".into(), json!({"type": "boolean"}));
    p.insert("payload".into(), payload);
    p.insert(
        "payload_b64".into(),
        json!({"type": "string", "contentEncoding": "base64"}),
    );
    p
}

/// The JSON Schema of a send or receipt of message type `message_type` whose first payload
/// was `sample` (its shape becomes the `payload` property's schema).
pub fn message_schema(kind: &str, message_type: u32, sample: Option<&Value>) -> Value {
    let payload = sample.map(infer_schema).unwrap_or_else(|| json!({}));
    let mut p = envelope_properties(payload);
    if kind == "send" {
        p.insert("attempt".into(), json!({"type": "integer"}));
        p.insert("route".into(), json!({"type": "string"}));
        p.insert("link".into(), json!({"type": ["integer", "null"]}));
    } else {
        p.insert("status".into(), json!({"type": "string"}));
        p.insert("link".into(), json!({"type": ["integer", "null"]}));
    }
    json!({
        "$schema": "https://json-schema.org/draft/2020-12/schema",
        "title": format!("hetcomm {kind} of message type {message_type}"),
        "type": "object",
        "properties": p,
    })
}

/// The JSON Schema of an outcome.
pub fn outcome_schema() -> Value {
    json!({
        "$schema": "https://json-schema.org/draft/2020-12/schema",
        "title": "hetcomm send outcome",
        "type": "object",
        "properties": {
            "event": {"type": "string"},
            "time_us": {"type": "integer"},
            "source_system": {"type": "string"},
            "destination_system": {"type": "string"},
            "seq": {"type": "integer"},
            "outcome": {"type": "string", "enum": ["delivered", "sent", "relayed", "unconfirmed", "failed"]},
            "attempts": {"type": "integer"},
            "latency_us": {"type": "integer"},
            "reason": {"type": "string"}
        }
    })
}

/// The JSON Schema of a path switch event.
pub fn path_switch_schema() -> Value {
    json!({
        "$schema": "https://json-schema.org/draft/2020-12/schema",
        "title": "hetcomm path switch",
        "type": "object",
        "properties": {
            "event": {"type": "string"},
            "time_us": {"type": "integer"},
            "source_system": {"type": "string"},
            "destination_system": {"type": "string"},
            "from": {"type": "string"},
            "to": {"type": "string"},
            "number": {"type": "integer"}
        }
    })
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn payloads_that_json_gives_back_exactly_carry_no_bytes() {
        #[derive(Serialize)]
        struct W {
            left: f64,
            right: f64,
            code: u8,
        }
        let bytes = hetcomm::payload::encode(&W {
            left: 1.0,
            right: -10.0,
            code: 3,
        })
        .unwrap();
        let (v, b64) = payload_json(&bytes);
        assert_eq!(
            v.as_ref().map(|r| r.get()),
            Some(r#"{"left":1.0,"right":-10.0,"code":3}"#)
        );
        assert_eq!(b64, None);
        let env = Envelope {
            source: Addr {
                system: "A".into(),
                module: "P".into(),
            },
            destination: Addr {
                system: "B".into(),
                module: "P".into(),
            },
            seq: 1,
            message_type: 1,
            priority: 100,
            transport: "R".into(),
            transport_name: None,
            ack_requested: true,
            broadcast: false,
            timestamp_us: 0,
            size: bytes.len(),
            payload: v,
            payload_b64: b64,
        };
        assert_eq!(env.payload_bytes().unwrap(), bytes);
    }

    #[test]
    fn other_payloads_keep_their_bytes() {
        for bytes in [
            vec![0xc4, 2, 1, 2],          // binary
            vec![0xca, 0x3f, 0x80, 0, 0], // f32 1.0
            vec![0xc1],                   // never used: not MessagePack
            vec![0x01, 0x02],             // trailing bytes
            vec![0x81, 0x01, 0x02],       // integer key
        ] {
            let (_, b64) = payload_json(&bytes);
            let b64 = b64.unwrap_or_else(|| panic!("{bytes:?} kept no bytes"));
            let back = base64::engine::general_purpose::STANDARD
                .decode(b64)
                .unwrap();
            assert_eq!(back, bytes);
        }
    }

    #[test]
    fn schemas_describe_the_payload_shape() {
        let s = message_schema("send", 1, Some(&json!({"left": 1.0, "n": [1, 2]})));
        assert_eq!(
            s["properties"]["payload"],
            json!({"type": "object", "properties": {
                "left": {"type": "number"},
                "n": {"type": "array", "items": {"type": "integer"}}}})
        );
        assert_eq!(s["properties"]["attempt"]["type"], "integer");
    }
}

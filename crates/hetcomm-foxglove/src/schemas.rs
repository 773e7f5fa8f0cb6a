//! The JSON schemas of the JSON channels (docs/foxglove.md lists the fields).

use serde_json::{json, Value};

/// One pair's row (the fields of `hetcomm_record::stats::PairRow`).
pub(crate) const PAIR_ROW: &str = r#"{
  "type": "object",
  "properties": {
    "source": {"type": "string"},
    "destination": {"type": "string"},
    "transport": {"type": "string"},
    "sends": {"type": "integer"},
    "retransmissions": {"type": "integer"},
    "delivered": {"type": "integer"},
    "sent": {"type": "integer"},
    "unconfirmed": {"type": "integer"},
    "failed": {"type": "integer"},
    "received": {"type": "integer"},
    "latency_p50_us": {"type": ["integer", "null"]},
    "latency_p99_us": {"type": ["integer", "null"]},
    "rate": {"type": "number"}
  }
}"#;

/// `/hetcomm/systems`.
pub(crate) const SYSTEMS: &str = r#"{
  "type": "object",
  "properties": {
    "systems": {"type": "array", "items": {
      "type": "object",
      "properties": {
        "system": {"type": "string"},
        "age_s": {"type": "number"},
        "inboxes": {"type": "array", "items": {
          "type": "object",
          "properties": {
            "module": {"type": "string"},
            "depth": {"type": "integer"},
            "capacity": {"type": "integer"},
            "dropped": {"type": "integer"}
          }
        }}
      }
    }}
  }
}"#;

/// `/hetcomm/pairs`: an array of pair rows.
pub(crate) fn pairs() -> String {
    format!(
        r#"{{"type": "object", "properties": {{"pairs": {{"type": "array", "items": {PAIR_ROW}}}}}}}"#
    )
}

/// A message topic's: the recording's receipt event (docs/record-replay.md) with the send
/// event's fields too, since a message to a system of another process is shown as it left.
pub(crate) fn message(message_type: u32, sample: Option<&Value>) -> String {
    let mut schema = hetcomm_record::format::message_schema("receipt", message_type, sample);
    let send = hetcomm_record::format::message_schema("send", message_type, sample);
    if let (Some(p), Some(s)) = (
        schema["properties"].as_object_mut(),
        send["properties"].as_object(),
    ) {
        for (k, v) in s {
            p.entry(k.clone()).or_insert_with(|| v.clone());
        }
    }
    schema["title"] = json!(format!("hetcomm message of type {message_type}"));
    schema.to_string()
}

/// An outcome topic's: the recording's outcome event.
pub(crate) fn outcome() -> String {
    hetcomm_record::format::outcome_schema().to_string()
}

fn counters(title: &str, names: &[&str], extra: Value) -> String {
    let mut p = serde_json::Map::new();
    p.insert("system".into(), json!({"type": "string"}));
    for n in names {
        p.insert((*n).into(), json!({"type": "integer"}));
    }
    if let Value::Object(extra) = extra {
        p.extend(extra);
    }
    json!({"title": title, "type": "object", "properties": p}).to_string()
}

/// `/hetcomm/security/<system>`.
pub(crate) fn security() -> String {
    counters(
        "hetcomm security counters (cumulative, summed over the system's links)",
        &SECURITY_COUNTERS,
        json!({"enabled": {"type": "boolean"}, "rejected": {"type": "integer"},
               "rejected_since_last": {"type": "integer"}}),
    )
}

/// The security counters published, by their names in docs/security.md.
pub(crate) const SECURITY_COUNTERS: [&str; 7] = [
    "rejected_auth",
    "rejected_replay",
    "rejected_table",
    "rejected_unknown_sender",
    "rejected_no_session",
    "handshake_timeouts",
    "handshakes",
];

/// `/hetcomm/paths/<system>`: the counter, or one switch.
pub(crate) fn paths() -> String {
    counters(
        "hetcomm path switches",
        &["path_changes"],
        json!({"destination": {"type": "string"}, "from": {"type": "string"},
               "to": {"type": "string"}}),
    )
}

/// `/hetcomm/foxglove`.
pub(crate) fn server() -> String {
    counters(
        "what this Foxglove server observed, published and dropped",
        &["observed", "published", "dropped", "unpublishable"],
        json!({}),
    )
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn schemas_are_json() {
        let v: Value = serde_json::from_str(&pairs()).unwrap();
        assert_eq!(v["properties"]["pairs"]["type"], "array");
        let v: Value = serde_json::from_str(SYSTEMS).unwrap();
        assert_eq!(v["properties"]["systems"]["type"], "array");
        let v: Value = serde_json::from_str(&message(1, Some(&json!({"left": 1.0})))).unwrap();
        // Both a receipt's and a send's fields, and the payload's shape.
        assert_eq!(v["properties"]["status"]["type"], "string");
        assert_eq!(v["properties"]["attempt"]["type"], "integer");
        assert_eq!(
            v["properties"]["payload"]["properties"]["left"]["type"],
            "number"
        );
        for s in [security(), paths(), server(), outcome()] {
            let v: Value = serde_json::from_str(&s).unwrap();
            assert_eq!(v["type"], "object", "{s}");
        }
    }
}

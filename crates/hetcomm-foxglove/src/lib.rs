//! A live view of a hetcomm fleet in Foxglove (or Lichtblick): the per-pair statistics that
//! `hetcomm monitor` shows, served over the Foxglove WebSocket protocol (subprotocol
//! `foxglove.sdk.v1`) by the official Foxglove SDK.
//!
//! Topics (JSON messages, each channel advertised with a JSON schema):
//!
//! * `/hetcomm/pairs` — every pair's row (`{"pairs": [...]}`), once per refresh;
//! * `/hetcomm/pair/<source>/<destination>/<transport>` — one pair's row, so a Plot panel can
//!   follow a single counter (`.delivered`, `.rate`, `.latency_p99_us`);
//! * `/hetcomm/systems` — every reporting system's inboxes and report age.
//!
//! See docs/foxglove.md for opening the view and how it is tested.

use std::collections::HashMap;
use std::net::SocketAddr;
use std::sync::Arc;

use anyhow::Context as _;
use foxglove::{
    ChannelBuilder, Context, RawChannel, Schema, WebSocketServer, WebSocketServerHandle,
};
use hetcomm_record::stats::{PairRow, SystemRow};

/// Topic carrying every pair's row.
pub const PAIRS_TOPIC: &str = "/hetcomm/pairs";
/// Prefix of the per-pair topics (`<prefix>/<source>/<destination>/<transport>`).
pub const PAIR_TOPIC_PREFIX: &str = "/hetcomm/pair";
/// Topic carrying every reporting system's inboxes.
pub const SYSTEMS_TOPIC: &str = "/hetcomm/systems";

/// JSON schema of one pair's row (the fields of `hetcomm_record::stats::PairRow`).
const PAIR_ROW_SCHEMA: &str = r#"{
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

/// JSON schema of `/hetcomm/systems`.
const SYSTEMS_SCHEMA: &str = r#"{
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

/// A running Foxglove WebSocket server publishing a fleet's statistics.
pub struct FoxgloveView {
    // A context of our own, not the SDK's global one: two views in one process (tests) must
    // not share channels.
    context: Arc<Context>,
    server: Option<WebSocketServerHandle>,
    pairs: Arc<RawChannel>,
    systems: Arc<RawChannel>,
    per_pair: HashMap<(String, String, String), Arc<RawChannel>>,
}

impl FoxgloveView {
    /// Starts serving on `addr` (`host:port`; port 0 picks a free one, see
    /// [`FoxgloveView::port`]).
    pub fn start(addr: &str, name: &str) -> anyhow::Result<FoxgloveView> {
        let sock: SocketAddr = addr
            .parse()
            .with_context(|| format!("--foxglove {addr}: expected host:port"))?;
        let context = Context::new();
        let pairs = json_channel(&context, PAIRS_TOPIC, "hetcomm.Pairs", &pairs_schema())?;
        let systems = json_channel(&context, SYSTEMS_TOPIC, "hetcomm.Systems", SYSTEMS_SCHEMA)?;
        let server = WebSocketServer::new()
            .name(name)
            .bind(sock.ip().to_string(), sock.port())
            .context(&context)
            .start_blocking()
            .map_err(|e| anyhow::anyhow!("--foxglove {addr}: {e}"))?;
        Ok(FoxgloveView {
            context,
            server: Some(server),
            pairs,
            systems,
            per_pair: HashMap::new(),
        })
    }

    /// The port the server listens on.
    pub fn port(&self) -> u16 {
        self.server.as_ref().map_or(0, |s| s.port())
    }

    /// Publishes one refresh of the monitor: the pairs table, one message per pair on its own
    /// topic, and the systems' inboxes.
    pub fn publish(&mut self, pairs: &[PairRow], systems: &[SystemRow]) -> anyhow::Result<()> {
        self.pairs
            .log(&serde_json::to_vec(&serde_json::json!({ "pairs": pairs }))?);
        for row in pairs {
            let c = &row.counters;
            let key = (c.source.clone(), c.destination.clone(), c.transport.clone());
            let channel = match self.per_pair.get(&key) {
                Some(ch) => ch.clone(),
                None => {
                    let topic = pair_topic(&c.source, &c.destination, &c.transport);
                    let ch =
                        json_channel(&self.context, &topic, "hetcomm.PairRow", PAIR_ROW_SCHEMA)?;
                    self.per_pair.insert(key, ch.clone());
                    ch
                }
            };
            channel.log(&serde_json::to_vec(row)?);
        }
        self.systems.log(&serde_json::to_vec(
            &serde_json::json!({ "systems": systems }),
        )?);
        Ok(())
    }
}

impl Drop for FoxgloveView {
    fn drop(&mut self) {
        if let Some(server) = self.server.take() {
            // Waiting closes client connections cleanly before the process exits.
            server.stop().wait_blocking();
        }
    }
}

/// The topic of one pair's row.
pub fn pair_topic(source: &str, destination: &str, transport: &str) -> String {
    format!("{PAIR_TOPIC_PREFIX}/{source}/{destination}/{transport}")
}

/// `/hetcomm/pairs`' schema: an array of pair rows.
fn pairs_schema() -> String {
    format!(
        r#"{{"type": "object", "properties": {{"pairs": {{"type": "array", "items": {PAIR_ROW_SCHEMA}}}}}}}"#
    )
}

fn json_channel(
    context: &Arc<Context>,
    topic: &str,
    schema_name: &str,
    schema: &str,
) -> anyhow::Result<Arc<RawChannel>> {
    ChannelBuilder::new(topic)
        .message_encoding("json")
        .schema(Schema::new(
            schema_name,
            "jsonschema",
            schema.as_bytes().to_vec(),
        ))
        .context(context)
        .build_raw()
        .map_err(|e| anyhow::anyhow!("foxglove channel {topic}: {e}"))
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn schemas_are_json() {
        let v: serde_json::Value = serde_json::from_str(&pairs_schema()).unwrap();
        assert_eq!(v["properties"]["pairs"]["type"], "array");
        let v: serde_json::Value = serde_json::from_str(SYSTEMS_SCHEMA).unwrap();
        assert_eq!(v["properties"]["systems"]["type"], "array");
        assert_eq!(pair_topic("a", "b", "udp"), "/hetcomm/pair/a/b/udp");
    }
}

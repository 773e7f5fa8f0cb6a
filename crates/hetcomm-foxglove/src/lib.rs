//! A live view of a hetcomm fleet in Foxglove (or Lichtblick), served over the Foxglove
//! WebSocket protocol (subprotocol `foxglove.sdk.v1`) by the official Foxglove SDK, and the
//! rovers' poses as Foxglove well-known schemas for recordings.
//!
//! One server ([`FoxgloveView`]) for every command: `hetcomm monitor` publishes what its
//! reports say ([`FoxgloveView::publish`]); `hetcomm demo --realtime`, `listen` and `replay`
//! hand it their open systems ([`FoxgloveView::watch`]), whose traffic it observes through the
//! one observation point ([`hetcomm::Observer`]) and whose counters it reads once a second;
//! the demo adds its rovers' poses ([`FoxgloveView::publish_poses`]).
//!
//! Topics (JSON messages with a JSON schema unless said otherwise):
//!
//! | topic | schema | what |
//! |---|---|---|
//! | `/hetcomm/pairs` | `hetcomm.Pairs` | every pair's row, once a second |
//! | `/hetcomm/pair/<source>/<destination>/<transport>` | `hetcomm.PairRow` | one pair's row |
//! | `/hetcomm/systems` | `hetcomm.Systems` | every system's inboxes |
//! | `/hetcomm/message/<destination>/<module>/type<N>` | `hetcomm.Message.type<N>` | every message, as received (or as sent, to a system of another process) |
//! | `/hetcomm/outcome/<source>/<destination>` | `hetcomm.Outcome` | how each send ended |
//! | `/hetcomm/security/<system>` | `hetcomm.Security` | the security layers' rejection counters, once a second |
//! | `/hetcomm/paths/<system>` | `hetcomm.Paths` | how often a destination's sends moved to another path |
//! | `/hetcomm/foxglove` | `hetcomm.FoxgloveServer` | what this server observed, published and dropped |
//! | `/tf` | `foxglove.FrameTransforms` (protobuf) | `world` → each rover's frame |
//! | `/hetcomm/rovers` | `foxglove.SceneUpdate` (protobuf) | a box, heading arrow and label per rover |
//!
//! It does not authenticate viewers (serve on a local or trusted address), count the messages
//! the SDK drops for a client that reads too slowly (the message topics' `seq` shows the
//! gaps), or serve a simulation (virtual time runs far faster than anyone watches: record it).
//!
//! ```no_run
//! # fn main() -> anyhow::Result<()> {
//! let fleet = hetcomm::LocalFleet::open_file("fleet.toml")?;
//! let view = hetcomm_foxglove::FoxgloveView::start("127.0.0.1:8765", "my robots")?;
//! let watch = view.watch(fleet.systems())?;
//! // … run; in Foxglove: Open connection, Foxglove WebSocket, ws://127.0.0.1:8765 …
//! let counts = watch.finish();
//! println!("{} published, {} dropped", counts.published, counts.dropped);
//! # Ok(()) }
//! ```
//!
//! See docs/foxglove.md for opening the view and how it is tested.

use parking_lot::Mutex;
use std::collections::HashMap;
use std::net::SocketAddr;
use std::sync::{Arc, OnceLock};

use anyhow::Context as _;
use foxglove::{
    ChannelBuilder, Context, RawChannel, Schema, WebSocketServer, WebSocketServerHandle,
};
use hetcomm_record::stats::{PairRow, SystemRow};

mod poses;
mod schemas;
mod traffic;

pub use poses::{PoseRecording, RoverPose, SCENE_TOPIC, TF_TOPIC, WORLD_FRAME};
pub use traffic::{Watch, WatchCounters};

/// Topic carrying every pair's row.
pub const PAIRS_TOPIC: &str = "/hetcomm/pairs";
/// Prefix of the per-pair topics (`<prefix>/<source>/<destination>/<transport>`).
pub const PAIR_TOPIC_PREFIX: &str = "/hetcomm/pair";
/// Topic carrying every reporting system's inboxes.
pub const SYSTEMS_TOPIC: &str = "/hetcomm/systems";
/// Prefix of the message topics (`<prefix>/<destination>/<module>/type<N>`).
pub const MESSAGE_TOPIC_PREFIX: &str = "/hetcomm/message";
/// Prefix of the outcome topics (`<prefix>/<source>/<destination>`).
pub const OUTCOME_TOPIC_PREFIX: &str = "/hetcomm/outcome";
/// Prefix of the security counters' topics (`<prefix>/<system>`).
pub const SECURITY_TOPIC_PREFIX: &str = "/hetcomm/security";
/// Prefix of the path counters' topics (`<prefix>/<system>`).
pub const PATHS_TOPIC_PREFIX: &str = "/hetcomm/paths";
/// Topic of this server's own counters.
pub const SERVER_TOPIC: &str = "/hetcomm/foxglove";

/// A running Foxglove WebSocket server publishing a fleet.
pub struct FoxgloveView {
    channels: Arc<Channels>,
    server: Option<WebSocketServerHandle>,
}

/// The server's channels, shared with the threads that publish on them.
pub(crate) struct Channels {
    // A context of our own, not the SDK's global one: two views in one process (tests) must
    // not share channels.
    context: Arc<Context>,
    /// JSON channels by topic, made on first use.
    json: Mutex<HashMap<String, Arc<RawChannel>>>,
    /// Made with the first poses: only the demo has any, and a channel that never carries a
    /// message would only clutter a viewer's topic list.
    poses: OnceLock<poses::PoseChannels>,
}

impl Channels {
    /// The JSON channel of `topic`, advertised (with the schema `schema` makes) the first
    /// time it is asked for.
    pub(crate) fn json(
        &self,
        topic: &str,
        schema_name: &str,
        schema: impl FnOnce() -> String,
    ) -> anyhow::Result<Arc<RawChannel>> {
        let mut channels = self.json.lock();
        if let Some(c) = channels.get(topic) {
            return Ok(c.clone());
        }
        let channel = ChannelBuilder::new(topic)
            .message_encoding("json")
            .schema(Schema::new(
                schema_name,
                "jsonschema",
                schema().into_bytes(),
            ))
            .context(&self.context)
            .build_raw()
            .map_err(|e| anyhow::anyhow!("foxglove channel {topic}: {e}"))?;
        channels.insert(topic.to_string(), channel.clone());
        Ok(channel)
    }

    /// Publishes one refresh of the statistics: the pairs table, one message per pair on its
    /// own topic, and the systems' inboxes.
    pub(crate) fn publish_stats(
        &self,
        pairs: &[PairRow],
        systems: &[SystemRow],
    ) -> anyhow::Result<()> {
        self.json(PAIRS_TOPIC, "hetcomm.Pairs", schemas::pairs)?
            .log(&serde_json::to_vec(&serde_json::json!({ "pairs": pairs }))?);
        for row in pairs {
            let c = &row.counters;
            let topic = pair_topic(&c.source, &c.destination, &c.transport);
            self.json(&topic, "hetcomm.PairRow", || schemas::PAIR_ROW.to_string())?
                .log(&serde_json::to_vec(row)?);
        }
        self.json(SYSTEMS_TOPIC, "hetcomm.Systems", || {
            schemas::SYSTEMS.to_string()
        })?
        .log(&serde_json::to_vec(
            &serde_json::json!({ "systems": systems }),
        )?);
        Ok(())
    }
}

impl FoxgloveView {
    /// Starts serving on `addr` (`host:port`; port 0 picks a free one, see
    /// [`FoxgloveView::port`]); `name` is the server's name clients are shown.
    pub fn start(addr: &str, name: &str) -> anyhow::Result<FoxgloveView> {
        let sock: SocketAddr = addr
            .parse()
            .with_context(|| format!("--foxglove {addr}: expected host:port"))?;
        let context = Context::new();
        let channels = Arc::new(Channels {
            poses: OnceLock::new(),
            context: context.clone(),
            json: Mutex::new(HashMap::new()),
        });
        // The statistics' channels exist from the start, as the monitor's always did.
        channels.json(PAIRS_TOPIC, "hetcomm.Pairs", schemas::pairs)?;
        channels.json(SYSTEMS_TOPIC, "hetcomm.Systems", || {
            schemas::SYSTEMS.to_string()
        })?;
        let server = WebSocketServer::new()
            .name(name)
            .bind(sock.ip().to_string(), sock.port())
            .context(&context)
            .start_blocking()
            .map_err(|e| anyhow::anyhow!("--foxglove {addr}: {e}"))?;
        Ok(FoxgloveView {
            channels,
            server: Some(server),
        })
    }

    /// The port the server listens on.
    pub fn port(&self) -> u16 {
        self.server.as_ref().map_or(0, |s| s.port())
    }

    /// Publishes one refresh of the monitor: the pairs table, one message per pair on its own
    /// topic, and the systems' inboxes.
    pub fn publish(&self, pairs: &[PairRow], systems: &[SystemRow]) -> anyhow::Result<()> {
        self.channels.publish_stats(pairs, systems)
    }

    /// Publishes the rovers' poses now (log time and stamps: the wall clock, since the viewer
    /// may run on another host): `/tf` and `/hetcomm/rovers`.
    pub fn publish_poses(&self, rovers: &[RoverPose<'_>]) {
        let channels = &self.channels;
        channels
            .poses
            .get_or_init(|| poses::PoseChannels::new(&channels.context))
            .publish(rovers);
    }

    /// Observes `systems` (open in this process) until the returned [`Watch`] is dropped:
    /// their messages, outcomes, statistics, security and path counters are published.
    pub fn watch(&self, systems: &[hetcomm::Comm]) -> anyhow::Result<Watch> {
        traffic::Watch::start(self.channels.clone(), systems)
    }

    /// Publishes one path switch: a JSON message on `/hetcomm/paths/<system>` naming the
    /// destination and both paths. [`FoxgloveView::watch`] does this for every switch of
    /// the systems it watches (the observation point reports each); the counter of switches
    /// is published there once a second too.
    pub fn publish_path_switch(
        &self,
        system: &str,
        destination: &str,
        from: &str,
        to: &str,
    ) -> anyhow::Result<()> {
        traffic::publish_path_switch(&self.channels, system, destination, from, to)
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

/// The topic of the messages of type `message_type` for `module` of `destination`.
pub fn message_topic(destination: &str, module: &str, message_type: u32) -> String {
    format!("{MESSAGE_TOPIC_PREFIX}/{destination}/{module}/type{message_type}")
}

/// The topic of the outcomes of `source`'s sends to `destination`.
pub fn outcome_topic(source: &str, destination: &str) -> String {
    format!("{OUTCOME_TOPIC_PREFIX}/{source}/{destination}")
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn topics_are_named_by_the_fleet() {
        assert_eq!(pair_topic("a", "b", "udp"), "/hetcomm/pair/a/b/udp");
        assert_eq!(
            message_topic("Charlie", "Plan", 0),
            "/hetcomm/message/Charlie/Plan/type0"
        );
        assert_eq!(
            outcome_topic("Alpha", "Charlie"),
            "/hetcomm/outcome/Alpha/Charlie"
        );
    }
}

//! The `mqtt_bridge` transport kind: a system that is a plain MQTT client speaking JSON (an
//! AGV or a fleet manager in the VDA 5050 style, a dashboard) in the fleet, without running
//! hetcomm, as the ROS bridges do for ROS robots (`docs/mqtt.md`, "Plain MQTT JSON clients").
//!
//! The bridge is a link between this system and the `robot`; its table maps MQTT topics to
//! (module, message type) both ways ([`BridgeSettings`]):
//!
//! * **publish** (hetcomm → MQTT): a message of type `TYPE_ID` sent to (robot, `MODULE`) is
//!   converted field by field from its MessagePack payload to a JSON object (its serde field
//!   names are the JSON members), checked against the mapping's declared fields, and
//!   published on the topic. Nobody acknowledges it: the transport must say
//!   `delivery = "unacknowledged"`. At QoS 0 the outcome is *sent*; at QoS 1 the send's
//!   outcome waits for the broker's PUBACK to that publish (a receipt,
//!   [`hetcomm_link::relay`], as on the `mqtt` link): *relayed* (the broker has it, not that
//!   the robot got it), failed when the broker had no subscriber for it, unconfirmed when it
//!   said nothing within `reconnect_wait_ms`; PUBACKs are also counted
//!   ([`MqttBridge::broker_stats`]). A message that does not convert is refused
//!   ([`LinkError::Refused`]: its send fails at once, naming the field, and is not retried).
//! * **subscribe** (MQTT → hetcomm): a JSON publish on the topic (a filter: `+` levels may be
//!   captured into string fields, `+serialNumber`) arrives in this system's `MODULE` as a
//!   message of type `TYPE_ID` from the robot, after checking it against the mapping's fields
//!   and, when the program declared the type, against the type. A payload that is not JSON,
//!   not an object, or does not fit is dropped, counted in the link's `frames_dropped` and
//!   described in [`MqttBridge::problems`] (each problem printed once to stderr), naming the
//!   field.
//!
//! Declared message types (`OpenOptions::message`) are compared with the mappings' fields when
//! the bridge opens ([`json::check_declared`]). Plain MQTT publishes are unauthenticated: the
//! transport must say `security = "none"`.

pub mod json;
mod settings;

use parking_lot::{Condvar, Mutex};
use std::collections::HashMap;
use std::sync::atomic::{AtomicBool, AtomicU64, Ordering};
use std::sync::Arc;
use std::thread::JoinHandle;
use std::time::{Duration, Instant};

use hetcomm_config::TransportKind;
use hetcomm_config::{Fleet, KindSpec, RegisteredSettings, SettingsReader, TransportDef};
use hetcomm_core::wire::{self, FrameKind};
use hetcomm_core::{MessageType, ModuleId, SystemId};
use hetcomm_link::bridge::{hosts, module_id, robot_id, FrameMaker, Tally};
use hetcomm_link::registry::{OpenFailure, OpenRequest, Opened, TransportFactory};
use hetcomm_link::relay::{RelayPromise, RelayReceipt, RelayVerdict};
use hetcomm_link::shape::{MessageShape, MessageShapes};
use hetcomm_link::{FrameSink, Link, LinkCaps, LinkError, LinkStats, Peer};
use rumqttc::v5::mqttbytes::v5::{Filter, Packet, PubAckReason, Publish, SubscribeReasonCode};
use rumqttc::v5::{Client, Connection, Event};
use rumqttc::Outgoing;
use serde_json::Value as Js;

pub use settings::{check_topic, BridgeSettings, JsonMapping, KEYS};

use crate::receipts::{self, Receipts};
use crate::IN_EVENT_LOOP;
use crate::{
    event_loop, factory, overhead, queue_publish, wait_until, BrokerStats, Conn, MqttOpenError,
};

/// The kind's name in fleet files.
pub const NAME: &str = "mqtt_bridge";

/// The kind: `kind = "mqtt_bridge"`.
pub fn kind() -> TransportKind {
    TransportKind::new(NAME)
}

/// Requests the client's queue holds.
const QUEUE: usize = 1024;

/// A subscribe mapping as the receiving thread sees it.
struct Inbound {
    mapping: JsonMapping,
    module: ModuleId,
    /// The program's declared type for it, if any.
    declared: Option<MessageShape>,
}

/// What the bridge's thread and its send side share.
struct Shared {
    conn: Mutex<Conn>,
    changed: Condvar,
    closing: AtomicBool,
    tally: Tally,
    connects: AtomicU64,
    broker_acks: AtomicU64,
    no_subscribers: AtomicU64,
    broker_refusals: AtomicU64,
    /// What the broker said about each QoS 1 publish, for the sends that wait on it.
    receipts: Receipts,
}

impl Shared {
    fn lock(&self) -> parking_lot::MutexGuard<'_, Conn> {
        self.conn.lock()
    }

    fn set(&self, f: impl FnOnce(&mut Conn)) {
        f(&mut self.lock());
        self.changed.notify_all();
    }

    /// Waits until `settled` answers, or `deadline` (then the state as it is).
    fn wait_for<T>(
        &self,
        deadline: Instant,
        settled: impl FnMut(&Conn) -> Option<T>,
    ) -> Result<T, parking_lot::MutexGuard<'_, Conn>> {
        wait_until(&self.conn, &self.changed, deadline, settled)
    }
}

/// A link to a plain MQTT client speaking JSON, through a broker. See the module docs.
pub struct MqttBridge {
    shared: Arc<Shared>,
    client: Client,
    thread: Mutex<Option<JoinHandle<()>>>,
    robot: SystemId,
    robot_name: String,
    outbound: HashMap<(ModuleId, MessageType), JsonMapping>,
    settings: BridgeSettings,
}

impl MqttBridge {
    /// Opens the bridge on system `local` of `fleet`: connects to the broker, subscribes to
    /// every subscribe mapping whose module `local` hosts (received messages go to `sink`),
    /// after checking each mapping of a type in `shapes` against it.
    pub fn open(
        fleet: &Fleet,
        local: SystemId,
        settings: &BridgeSettings,
        shapes: &MessageShapes,
        sink: Arc<dyn FrameSink>,
    ) -> Result<MqttBridge, OpenFailure> {
        let robot = robot_id(fleet, local, &settings.robot, "plain MQTT")?;
        let local_name = fleet
            .systems
            .iter()
            .find(|s| s.id == local)
            .map(|s| s.name.clone())
            .ok_or_else(|| format!("system {local} is not in the fleet"))?;
        let mut outbound = HashMap::new();
        for m in &settings.publish {
            let module = module_id(fleet, &m.module, &m.topic)?;
            if let Some(d) = shapes.get(m.message) {
                json::check_declared(&d.shape, &m.fields, &[], true).map_err(|why| {
                    format!(
                        "message type {} ({}) does not convert to the JSON of topic {}: {why}",
                        m.message, d.name, m.topic
                    )
                })?;
            }
            outbound.insert((module, MessageType(m.message)), m.clone());
        }
        let mut inbound = Vec::new();
        for m in &settings.subscribe {
            let module = module_id(fleet, &m.module, &m.topic)?;
            if !hosts(fleet, local, module) {
                continue;
            }
            let declared = shapes.get(m.message).cloned();
            if let Some(d) = &declared {
                json::check_declared(&d.shape, &m.fields, &m.captures, false).map_err(|why| {
                    format!(
                        "the JSON of topic {} does not convert to message type {} ({}): {why}",
                        m.topic, m.message, d.name
                    )
                })?;
            }
            inbound.push(Inbound {
                mapping: m.clone(),
                module,
                declared,
            });
        }
        let mut connection = settings.connection.clone();
        factory::resolve_files(&mut connection, fleet);
        // Unique per open: the bridge keeps no session (clean starts, no will), and two
        // bridges with one id (the same names in two fleets on one broker, or one system
        // opened twice) would push each other off the broker for ever.
        let client_id = format!(
            "{}bridge-{}-{local_name}-{}-{:04x}",
            connection.client_id_prefix,
            settings.robot,
            std::process::id(),
            rand::random::<u16>()
        )
        .replace(['/', '+', '#'], "-");
        let options = event_loop::connect_options(&connection, &client_id, None)?;
        let filters: Vec<Filter> = inbound
            .iter()
            .map(|i| {
                let mut f = Filter::new(i.mapping.topic.clone(), connection.qos.mqtt());
                // Not this bridge's own publishes, where a topic is mapped both ways.
                f.nolocal = true;
                f
            })
            .collect();
        let shared = Arc::new(Shared {
            conn: Mutex::new(Conn {
                broker: connection.brokers[0].to_string(),
                ..Conn::default()
            }),
            changed: Condvar::new(),
            closing: AtomicBool::new(false),
            tally: Tally::new(NAME),
            connects: AtomicU64::new(0),
            broker_acks: AtomicU64::new(0),
            no_subscribers: AtomicU64::new(0),
            broker_refusals: AtomicU64::new(0),
            receipts: Receipts::new(
                Duration::from_millis(connection.reconnect_wait_ms as u64),
                connection.brokers[0].to_string(),
            ),
        });
        let (client, conn) = Client::new(options[0].clone(), QUEUE);
        let receiver = Receiver {
            shared: shared.clone(),
            inbound,
            maker: FrameMaker::new(local, robot),
            robot,
            sink,
        };
        let thread = {
            let (client, brokers) = (client.clone(), connection.brokers.clone());
            std::thread::Builder::new()
                .name(format!("mqtt-bridge-{}", settings.robot))
                .spawn(move || run(receiver, client, conn, options, brokers, filters))
                .map_err(|e| format!("cannot start a thread: {e}"))?
        };
        {
            // Ends the broker's receipts that wait past their bound.
            let shared = shared.clone();
            std::thread::Builder::new()
                .name(format!("mqtt-bridge-receipts-{}", settings.robot))
                .spawn(move || shared.receipts.run_expiry())
                .map_err(|e| format!("cannot start a thread: {e}"))?;
        }
        let bridge = MqttBridge {
            shared,
            client,
            thread: Mutex::new(Some(thread)),
            robot,
            robot_name: settings.robot.clone(),
            outbound,
            settings: BridgeSettings {
                connection,
                ..settings.clone()
            },
        };
        bridge.wait_open()
    }

    fn wait_open(self) -> Result<MqttBridge, OpenFailure> {
        let s = &self.settings.connection;
        let deadline = Instant::now() + Duration::from_millis(s.open_timeout_ms as u64);
        let shared = self.shared.clone();
        let settled = shared.wait_for(deadline, |c| match c.ready {
            true => Some(Ok(())),
            false => c.refused.clone().map(|reason| {
                Err(MqttOpenError::Refused {
                    broker: c.broker.clone(),
                    reason,
                })
            }),
        });
        let result = match settled {
            Ok(r) => r,
            Err(conn) => Err(MqttOpenError::Unreachable {
                brokers: s.broker_list(),
                timeout_ms: s.open_timeout_ms,
                reason: conn
                    .last_error
                    .clone()
                    .unwrap_or_else(|| "no answer".into()),
            }),
        };
        match result {
            Ok(()) => Ok(self),
            Err(e) => {
                self.shared.closing.store(true, Ordering::SeqCst);
                let _ = self.client.try_disconnect();
                self.thread.lock().take();
                Err(e.into())
            }
        }
    }

    /// The problems seen with input from MQTT (payloads that are not JSON or do not fit their
    /// mapping), each once.
    pub fn problems(&self) -> Vec<String> {
        self.shared.tally.problems()
    }

    /// What the broker confirmed of the bridge's QoS 1 publishes: the broker taking a
    /// publish, never the robot getting it.
    pub fn broker_stats(&self) -> BrokerStats {
        let s = &self.shared;
        BrokerStats {
            acknowledged: s.broker_acks.load(Ordering::Relaxed),
            no_subscribers: s.no_subscribers.load(Ordering::Relaxed),
            refused: s.broker_refusals.load(Ordering::Relaxed),
            connects: s.connects.load(Ordering::Relaxed),
        }
    }

    /// Whether the client is connected and subscribed now.
    pub fn connected(&self) -> bool {
        self.shared.lock().ready
    }

    /// The JSON publish of `frame` for `to`, and its topic; None for frames that are not
    /// data (nobody on the MQTT side takes acknowledgements).
    /// A frame that cannot be converted is refused ([`LinkError::Refused`]): a retry would
    /// be refused the same way.
    fn convert(&self, to: SystemId, frame: &[u8]) -> Result<Option<(&str, Vec<u8>)>, LinkError> {
        if to != self.robot {
            let name = &self.robot_name;
            return Err(LinkError::Unreachable {
                peer: to,
                reason: format!("this {NAME} reaches only {name}"),
            });
        }
        let refused = |reason: String| LinkError::Refused { peer: to, reason };
        let f = wire::decode(frame).map_err(|e| refused(format!("not a frame: {e}")))?;
        if f.header.kind != FrameKind::Data {
            return Ok(None);
        }
        let key = (f.header.destination.module, f.header.message_type);
        let Some(m) = self.outbound.get(&key) else {
            return Err(refused(format!(
                "no MQTT topic is mapped for message type {} to {}'s module {}",
                key.1 .0, self.robot_name, key.0 .0
            )));
        };
        let refuse = |why: String| {
            refused(format!(
                "message type {} for {} does not convert to the JSON of topic {}: {why}",
                m.message, m.module, m.topic
            ))
        };
        let value = rmpv::decode::read_value(&mut &f.payload[..])
            .map_err(|e| refuse(format!("the payload is not MessagePack: {e}")))?;
        let js = json::to_json(&value, "").map_err(refuse)?;
        let Js::Object(object) = &js else {
            return Err(refuse(
                "the message is not a struct (a JSON payload is an object)".into(),
            ));
        };
        json::check_fields(object, &m.fields).map_err(refuse)?;
        let body = serde_json::to_vec(&js).map_err(|e| refuse(e.to_string()))?;
        Ok(Some((&m.topic, body)))
    }

    /// Waits (up to `reconnect_wait_ms`, not at all on the bridge's thread) for the
    /// connection.
    fn connected_or_wait(&self, to: SystemId) -> Result<(), LinkError> {
        let in_loop = IN_EVENT_LOOP.with(|c| c.get());
        let wait = match in_loop {
            true => Duration::ZERO,
            false => Duration::from_millis(self.settings.connection.reconnect_wait_ms as u64),
        };
        let closing = &self.shared.closing;
        let settled = self.shared.wait_for(Instant::now() + wait, |c| {
            if c.ready {
                Some(Ok(()))
            } else if closing.load(Ordering::Relaxed) {
                Some(Err(LinkError::Closed))
            } else {
                None
            }
        });
        settled.unwrap_or_else(|c| {
            Err(LinkError::Unreachable {
                peer: to,
                reason: format!(
                    "the MQTT broker {} is unreachable ({}); waited {} ms for the connection to come back",
                    c.broker,
                    c.last_error.as_deref().unwrap_or("disconnected"),
                    wait.as_millis()
                ),
            })
        })
    }
}

impl Link for MqttBridge {
    fn caps(&self) -> LinkCaps {
        // Frames are converted, so their size says nothing of the publish's: the broker's
        // limit is checked against the JSON, at the send.
        LinkCaps {
            max_frame: wire::HEADER_LEN + wire::MAX_PAYLOAD,
            mtu: wire::HEADER_LEN + wire::MAX_PAYLOAD,
            reliable: false,
            // One connection, QoS 0 or 1: publishes on one topic arrive in order.
            ordered: true,
            broadcast: false,
        }
    }

    fn send(&self, to: SystemId, frame: &[u8]) -> Result<(), LinkError> {
        self.publish(to, frame, None)
    }

    /// At QoS 1, a receipt kept with the broker's PUBACK for this publish (as on the `mqtt`
    /// link); at QoS 0 none.
    fn send_relayed(
        &self,
        to: SystemId,
        head: &[u8],
        body: &[u8],
    ) -> Result<Option<RelayReceipt>, LinkError> {
        let frame = [head, body].concat();
        receipts::with_receipt(self.settings.connection.qos.mqtt(), |promise| {
            self.publish(to, &frame, promise)
        })
    }

    fn stats(&self) -> LinkStats {
        LinkStats {
            connects: self.shared.connects.load(Ordering::Relaxed),
            ..self.shared.tally.stats()
        }
    }
}

impl MqttBridge {
    /// Converts `frame` and publishes it on its topic; `promise`: its receipt's, kept with the
    /// broker's PUBACK. A frame that is not data (nobody on the MQTT side takes
    /// acknowledgements) is taken and dropped; its receipt says it left.
    fn publish(
        &self,
        to: SystemId,
        frame: &[u8],
        mut promise: Option<RelayPromise>,
    ) -> Result<(), LinkError> {
        let Some((topic, body)) = self.convert(to, frame)? else {
            if let Some(p) = promise.take() {
                p.keep(RelayVerdict::Left);
            }
            return Ok(());
        };
        if let Some(limit) = self.shared.lock().broker_max_packet {
            let max = (limit as usize).saturating_sub(overhead(topic.len()));
            if body.len() > max {
                return Err(LinkError::TooLarge {
                    len: body.len(),
                    max,
                });
            }
        }
        self.connected_or_wait(to)?;
        let qos = self.settings.connection.qos.mqtt();
        let wait = Duration::from_millis(self.settings.connection.reconnect_wait_ms as u64);
        queue_publish(
            &self.client,
            (topic.to_string(), qos),
            body,
            (to, wait),
            &self.shared.closing,
            (&self.shared.receipts, promise),
        )?;
        self.shared.tally.sent();
        Ok(())
    }
}

impl Drop for MqttBridge {
    fn drop(&mut self) {
        let ready = self.shared.lock().ready;
        self.shared.closing.store(true, Ordering::SeqCst);
        self.shared.receipts.close();
        self.shared.changed.notify_all();
        let thread = self.thread.lock().take();
        let _ = self.client.try_disconnect();
        // Disconnected, the loop ends after its current attempt: nothing to wait for.
        if let (true, Some(t)) = (ready, thread) {
            let _ = t.join();
        }
    }
}

/// The receiving half, owned by the bridge's thread.
struct Receiver {
    shared: Arc<Shared>,
    inbound: Vec<Inbound>,
    maker: FrameMaker,
    robot: SystemId,
    sink: Arc<dyn FrameSink>,
}

impl Receiver {
    /// A JSON publish: checked, converted and handed to the sink as a frame from the robot,
    /// or dropped, counted and described.
    fn on_publish(&mut self, p: &Publish) {
        let tally = &self.shared.tally;
        let Ok(topic) = std::str::from_utf8(&p.topic) else {
            return tally.dropped(1, "a publish whose topic is not UTF-8 (dropped)".into());
        };
        // An empty retained publish clears a retained message: no message to deliver.
        if p.payload.is_empty() && p.retain {
            return;
        }
        let found = self
            .inbound
            .iter()
            .find_map(|i| i.mapping.matches(topic).map(|c| (i, c)));
        let Some((inb, captures)) = found else {
            return tally.dropped(
                1,
                format!("a publish on {topic} matches no mapping (dropped)"),
            );
        };
        let m = &inb.mapping;
        let mut value: Js = match serde_json::from_slice(&p.payload) {
            Ok(v) => v,
            Err(e) => {
                return tally.dropped(
                    1,
                    format!("a message on {topic} is not JSON: {e} (dropped)"),
                )
            }
        };
        let what = match &inb.declared {
            Some(d) => format!("message type {} ({})", m.message, d.name),
            None => format!("message type {}", m.message),
        };
        let Js::Object(object) = &mut value else {
            return tally.dropped(
                1,
                format!("a message on {topic} is not a JSON object, {what} is (dropped)"),
            );
        };
        for (field, level) in captures {
            object.insert(field, Js::String(level));
        }
        let checked = json::check_fields(object, &m.fields).and_then(|()| match &inb.declared {
            Some(d) => json::fits_shape(&value, &d.shape, ""),
            None => Ok(()),
        });
        if let Err(why) = checked {
            return tally.dropped(
                1,
                format!(
                    "a message on {topic} does not fit {what} for {}: {why} (dropped)",
                    m.module
                ),
            );
        }
        let mut payload = Vec::with_capacity(p.payload.len());
        if rmpv::encode::write_value(&mut payload, &json::to_msgpack(&value)).is_err()
            || payload.len() > wire::MAX_PAYLOAD
        {
            return tally.dropped(
                1,
                format!("a message on {topic} is too large for a hetcomm frame (dropped)"),
            );
        }
        let frame = self.maker.frame_of(inb.module, m.message, &payload);
        tally.received();
        self.sink.on_frame(&frame, Peer::System(self.robot));
    }
}

/// The first pause between connection attempts, doubled after each failure up to
/// [`RETRY_MAX`].
const RETRY_FIRST: Duration = Duration::from_millis(50);
const RETRY_MAX: Duration = Duration::from_millis(500);

/// The bridge's thread: runs the client's event loop until the bridge closes, subscribing at
/// every connection (clean sessions) and reconnecting to each broker in turn.
fn run(
    mut rx: Receiver,
    client: Client,
    mut connection: Connection,
    options: Vec<rumqttc::v5::MqttOptions>,
    brokers: Vec<crate::Broker>,
    filters: Vec<Filter>,
) {
    IN_EVENT_LOOP.with(|c| c.set(true));
    let shared = rx.shared.clone();
    let (mut current, mut pause) = (0, RETRY_FIRST);
    loop {
        let Ok(event) = connection.recv() else { break };
        match &event {
            Ok(event) => shared.receipts.on_event(event),
            Err(_) => shared.receipts.disconnected(&connection.eventloop.pending),
        }
        match event {
            Ok(Event::Incoming(Packet::ConnAck(ack))) => {
                pause = RETRY_FIRST;
                shared.receipts.connected(ack.session_present);
                shared.connects.fetch_add(1, Ordering::Relaxed);
                let limit = ack.properties.as_ref().and_then(|p| p.max_packet_size);
                let subscribe = !filters.is_empty();
                if subscribe {
                    let _ = client.try_subscribe_many(filters.clone());
                }
                shared.set(|c| {
                    c.broker_max_packet = limit;
                    c.refused = None;
                    if !subscribe {
                        c.ready = true;
                        c.last_error = None;
                    }
                });
            }
            Ok(Event::Incoming(Packet::SubAck(ack))) => {
                let refused: Vec<String> = ack
                    .return_codes
                    .iter()
                    .filter(|c| !matches!(c, SubscribeReasonCode::Success(_)))
                    .map(|c| format!("{c:?}"))
                    .collect();
                shared.set(|c| match refused.is_empty() {
                    true => {
                        c.ready = true;
                        c.last_error = None;
                    }
                    false => {
                        c.refused = Some(format!(
                            "the broker refused the bridge's subscriptions: {}",
                            refused.join(", ")
                        ))
                    }
                });
            }
            Ok(Event::Incoming(Packet::Publish(p))) => rx.on_publish(&p),
            Ok(Event::Incoming(Packet::PubAck(ack))) => {
                let counter = match ack.reason {
                    PubAckReason::Success => &shared.broker_acks,
                    PubAckReason::NoMatchingSubscribers => &shared.no_subscribers,
                    _ => &shared.broker_refusals,
                };
                counter.fetch_add(1, Ordering::Relaxed);
            }
            Ok(Event::Outgoing(Outgoing::Disconnect)) if shared.closing.load(Ordering::SeqCst) => {
                break
            }
            Ok(_) => {}
            Err(e) => {
                let (text, refused) = event_loop::describe(&e);
                shared.set(|c| {
                    c.ready = false;
                    c.last_error = Some(text);
                    if refused.is_some() {
                        c.refused = refused;
                    }
                });
                if shared.closing.load(Ordering::SeqCst) {
                    break;
                }
                if options.len() > 1 {
                    current = (current + 1) % options.len();
                    connection.eventloop.options = options[current].clone();
                    shared.lock().broker = brokers[current].to_string();
                    shared.receipts.set_broker(brokers[current].to_string());
                }
                std::thread::sleep(pause);
                pause = (pause * 2).min(RETRY_MAX);
            }
        }
    }
    shared.set(|c| c.ready = false);
}

/// Reads `mqtt_bridge` tables and opens them as [`MqttBridge`]s.
pub struct MqttBridgeFactory;

impl KindSpec for MqttBridgeFactory {
    fn kind(&self) -> TransportKind {
        kind()
    }

    fn keys(&self) -> &[&'static str] {
        &KEYS
    }

    fn parse(&self, s: &mut SettingsReader<'_, '_>) -> Option<RegisteredSettings> {
        settings::parse(s).map(RegisteredSettings::new)
    }
}

impl TransportFactory for MqttBridgeFactory {
    fn kind(&self) -> TransportKind {
        kind()
    }

    fn spec(self: Arc<Self>) -> Option<Arc<dyn KindSpec>> {
        Some(self)
    }

    fn bridged_robot(&self, transport: &TransportDef) -> Option<String> {
        let settings = transport.settings.registered::<BridgeSettings>()?;
        Some(settings.robot.clone())
    }

    fn open(&self, request: OpenRequest<'_>) -> Result<Opened, OpenFailure> {
        let settings: &BridgeSettings = request.settings()?;
        let bridge = MqttBridge::open(
            request.fleet,
            request.local,
            settings,
            request.shapes,
            request.sink,
        )?;
        let address = format!(
            "{NAME}://{}/{}",
            settings.connection.brokers[0]
                .to_string()
                .split_once("://")
                .map_or("", |(_, rest)| rest),
            settings.robot
        );
        Ok(Opened {
            link: Arc::new(bridge),
            local_address: Some(address),
        })
    }
}

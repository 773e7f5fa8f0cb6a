//! The `ros2_bridge` transport kind: an external ROS 2 robot (a system that runs ROS 2, not
//! hetcomm) in the fleet, through typed ROS topics.
//!
//! A bridge is a link between this system and the robot. Its fleet table maps, per module and
//! message type, to ROS topics and types ([`BridgeSettings`]):
//!
//! * **publish** (hetcomm → ROS): a message of type `TYPE_ID` sent to (robot, `MODULE`) is
//!   converted by field name ([`crate::rostypes`]) and published on the topic. Nobody
//!   acknowledges it: the transport must say `delivery = "unacknowledged"`, and the outcome
//!   is Sent (without confirmation). A message that does not convert fails its send, naming
//!   both types and the field.
//! * **subscribe** (ROS → hetcomm): a ROS message on the topic arrives in this system's
//!   `MODULE` as a message of type `TYPE_ID` from the robot (the frame's source module is the
//!   same module id).
//!
//! Bad input never reaches a module: a sample that does not decode as the mapped type, and a
//! publisher on a mapped topic whose type is not the mapped one, are counted (dropped frames
//! in the link's stats) and described in [`Problems`], each problem printed once to stderr.
//! The bridge carries plain ROS messages, unauthenticated like any ROS 2 topic without SROS2:
//! the transport must say `security = "none"`.

mod settings;

use std::collections::{BTreeSet, HashMap};
use std::sync::atomic::{AtomicBool, AtomicU64, Ordering};
use std::sync::{Arc, Mutex};
use std::thread::JoinHandle;
use std::time::{Duration, Instant, SystemTime, UNIX_EPOCH};

use hetcomm_config::{Fleet, KindSpec, RegisteredSettings, SettingsReader};
use hetcomm_config::{TransportDef, TransportKind, TransportSettings};
use hetcomm_core::wire::{self, FrameKind, Header};
use hetcomm_core::{Address, MessageType, ModuleId, SystemId, Time};
use hetcomm_link::registry::{OpenFailure, OpenRequest, Opened, TransportFactory};
use hetcomm_link::{FrameSink, Link, LinkCaps, LinkError, LinkStats, Peer};
use rustdds::mio1::{Events, Interest, Poll, Token};
use rustdds::no_key::{DataReader, DataWriter};
use rustdds::{DomainParticipant, TopicKind};

pub use settings::{BridgeSettings, Mapping, KEYS};

use crate::link::{participant, qos, OpenError};
use crate::names;
use crate::raw::{RawAdapter, RawCdr};

/// The kind's name in fleet files: `kind = "ros2_bridge"`.
pub fn kind() -> TransportKind {
    TransportKind::new("ros2_bridge")
}

/// What went wrong with input from ROS, each distinct problem once, in order.
#[derive(Default)]
pub struct Problems {
    seen: Mutex<BTreeSet<String>>,
}

impl Problems {
    /// Records `problem`; true (and printed to stderr) the first time it is seen.
    fn report(&self, problem: String) -> bool {
        let mut seen = self.seen.lock().unwrap_or_else(|e| e.into_inner());
        let new = seen.insert(problem.clone());
        if new {
            eprintln!("hetcomm ros2_bridge: {problem}");
        }
        new
    }

    /// Every distinct problem seen so far.
    pub fn list(&self) -> Vec<String> {
        let seen = self.seen.lock().unwrap_or_else(|e| e.into_inner());
        seen.iter().cloned().collect()
    }
}

struct Outbound {
    mapping: Mapping,
    writer: DataWriter<RawCdr, RawAdapter>,
}

struct Inbound {
    mapping: Mapping,
    module: ModuleId,
    reader: DataReader<RawCdr, RawAdapter>,
}

#[derive(Default)]
struct Counters {
    sent: AtomicU64,
    received: AtomicU64,
    dropped: AtomicU64,
}

struct Shared {
    counters: Counters,
    problems: Problems,
    closed: AtomicBool,
}

/// A link to an external ROS 2 robot through typed topics.
pub struct Ros2Bridge {
    robot: SystemId,
    robot_name: String,
    /// By (robot's module, message type).
    outbound: HashMap<(ModuleId, MessageType), Outbound>,
    shared: Arc<Shared>,
    receiver: Option<JoinHandle<()>>,
    _participant: DomainParticipant,
}

fn module_id(fleet: &Fleet, name: &str, topic: &str) -> Result<ModuleId, OpenFailure> {
    fleet
        .modules
        .iter()
        .find(|m| m.name == name)
        .map(|m| m.id)
        .ok_or_else(|| {
            format!("the mapping of {topic} names module `{name}`, which is not in [modules]")
                .into()
        })
}

impl Ros2Bridge {
    /// Opens the bridge on system `local` of `fleet` with `settings`.
    pub fn open(
        fleet: &Fleet,
        local: SystemId,
        settings: &BridgeSettings,
        sink: Arc<dyn FrameSink>,
    ) -> Result<Ros2Bridge, OpenFailure> {
        let robot = fleet
            .systems
            .iter()
            .find(|s| s.name == settings.robot)
            .map(|s| s.id)
            .ok_or_else(|| format!("robot `{}` is not in [systems]", settings.robot))?;
        if robot == local {
            return Err(format!(
                "`{}` is the external ROS 2 robot of this bridge: it runs ROS 2, not hetcomm",
                settings.robot
            )
            .into());
        }
        let dp = participant(&settings.dds)?;
        let qos = qos(&settings.dds);
        let dds_err = |what: String| {
            move |e: rustdds::dds::CreateError| OpenError::Dds {
                what,
                reason: e.to_string(),
            }
        };
        let topic = |m: &Mapping| {
            dp.create_topic(
                names::dds_topic(&m.topic),
                names::dds_type(m.ros_type),
                &qos,
                TopicKind::NoKey,
            )
            .map_err(dds_err(format!("topic {}", m.topic)))
        };
        let publisher = dp
            .create_publisher(&qos)
            .map_err(dds_err("a publisher".into()))?;
        let mut outbound = HashMap::new();
        for m in &settings.publish {
            let module = module_id(fleet, &m.module, &m.topic)?;
            let writer = publisher
                .create_datawriter_no_key::<RawCdr, RawAdapter>(&topic(m)?, Some(qos.clone()))
                .map_err(dds_err(format!("the writer of {}", m.topic)))?;
            outbound.insert(
                (module, MessageType(m.message)),
                Outbound {
                    mapping: m.clone(),
                    writer,
                },
            );
        }
        let subscriber = dp
            .create_subscriber(&qos)
            .map_err(dds_err("a subscriber".into()))?;
        // A system that does not host a subscribed module does not read its topic: the
        // messages would have nowhere to go (e.g. the rover that only publishes commands).
        let hosted = fleet
            .systems
            .iter()
            .find(|s| s.id == local)
            .and_then(|s| s.modules.clone());
        let mut inbound = Vec::new();
        for m in &settings.subscribe {
            let module = module_id(fleet, &m.module, &m.topic)?;
            if hosted.as_ref().is_some_and(|h| !h.contains(&module)) {
                continue;
            }
            let reader = subscriber
                .create_datareader_no_key::<RawCdr, RawAdapter>(&topic(m)?, Some(qos.clone()))
                .map_err(dds_err(format!("the reader of {}", m.topic)))?;
            inbound.push(Inbound {
                mapping: m.clone(),
                module,
                reader,
            });
        }
        let shared = Arc::new(Shared {
            counters: Counters::default(),
            problems: Problems::default(),
            closed: AtomicBool::new(false),
        });
        let rx = Receiver {
            dp: dp.clone(),
            inbound,
            local,
            robot,
            sink,
            shared: shared.clone(),
            incarnation: rand::random::<u32>() | 1,
            seq: HashMap::new(),
        };
        let receiver = std::thread::Builder::new()
            .name(format!("hetcomm-ros2-bridge-{}", settings.robot))
            .spawn(move || rx.run())?;
        Ok(Ros2Bridge {
            robot,
            robot_name: settings.robot.clone(),
            outbound,
            shared,
            receiver: Some(receiver),
            _participant: dp,
        })
    }

    /// The problems seen with input from ROS (undecodable samples, publishers of another
    /// type on a mapped topic), each once.
    pub fn problems(&self) -> Vec<String> {
        self.shared.problems.list()
    }
}

fn now() -> Time {
    let us = SystemTime::now()
        .duration_since(UNIX_EPOCH)
        .map(|d| d.as_micros() as u64)
        .unwrap_or(0);
    Time::from_micros(us)
}

/// The bridge's receive side: every subscribed topic's reader, polled on one thread.
struct Receiver {
    dp: DomainParticipant,
    inbound: Vec<Inbound>,
    local: SystemId,
    robot: SystemId,
    sink: Arc<dyn FrameSink>,
    shared: Arc<Shared>,
    incarnation: u32,
    seq: HashMap<ModuleId, u64>,
}

impl Receiver {
    fn run(mut self) {
        let Ok(mut poll) = Poll::new() else {
            return;
        };
        for (i, inb) in self.inbound.iter_mut().enumerate() {
            if poll
                .registry()
                .register(&mut inb.reader, Token(i), Interest::READABLE)
                .is_err()
            {
                return;
            }
        }
        let mut events = Events::with_capacity(16);
        let mut next_check = Instant::now();
        while !self.shared.closed.load(Ordering::Relaxed) {
            let _ = poll.poll(&mut events, Some(Duration::from_millis(50)));
            for i in 0..self.inbound.len() {
                self.drain(i);
            }
            if Instant::now() >= next_check {
                self.check_publisher_types();
                next_check = Instant::now() + Duration::from_millis(500);
            }
        }
    }

    fn drop_with(&self, problem: String) {
        self.shared.counters.dropped.fetch_add(1, Ordering::Relaxed);
        self.shared.problems.report(problem);
    }

    fn drain(&mut self, i: usize) {
        loop {
            let inb = &mut self.inbound[i];
            let sample = match inb.reader.take_next_sample() {
                Ok(Some(s)) => s.into_value(),
                Ok(None) => return,
                Err(e) => {
                    let topic = inb.mapping.topic.clone();
                    self.drop_with(format!("a sample on {topic} could not be read: {e}"));
                    continue;
                }
            };
            let (topic, schema) = (inb.mapping.topic.clone(), inb.mapping.schema());
            let value = match crate::rostypes::from_cdr(
                &sample.body,
                sample.little,
                sample.xcdr2,
                schema,
            ) {
                Ok(v) => v,
                Err(e) => {
                    self.drop_with(format!(
                        "a sample on {topic} is not a {}: {e} (dropped)",
                        schema.name
                    ));
                    continue;
                }
            };
            let mut payload = Vec::with_capacity(sample.body.len() + 16);
            if rmpv::encode::write_value(&mut payload, &value).is_err() {
                self.drop_with(format!("a sample on {topic} could not be encoded"));
                continue;
            }
            let inb = &self.inbound[i];
            let seq = self.seq.entry(inb.module).or_insert(0);
            *seq += 1;
            let header = Header {
                kind: FrameKind::Data,
                incarnation: self.incarnation,
                seq: *seq,
                timestamp: now(),
                ..Header::data(
                    Address {
                        system: self.robot,
                        module: inb.module,
                    },
                    Address {
                        system: self.local,
                        module: inb.module,
                    },
                    MessageType(inb.mapping.message),
                )
            };
            let frame = wire::encode(&header, &payload);
            self.shared
                .counters
                .received
                .fetch_add(1, Ordering::Relaxed);
            self.sink.on_frame(&frame, Peer::System(self.robot));
        }
    }

    /// Reports publishers on a mapped topic whose type is not the mapped one (DDS does not
    /// match them, so their messages would otherwise vanish without a word).
    fn check_publisher_types(&self) {
        let writers = self.dp.discovered_writers();
        for inb in &self.inbound {
            let topic = names::dds_topic(&inb.mapping.topic);
            let expected = names::dds_type(inb.mapping.ros_type);
            for w in &writers {
                let t = &w.publication_topic_data;
                if t.topic_name == topic && t.type_name != expected {
                    let new = self.shared.problems.report(format!(
                        "a publisher on {} has type {}, but the topic is mapped as {} ({}): its \
                         messages are not received",
                        inb.mapping.topic, t.type_name, inb.mapping.ros_type, expected
                    ));
                    if new {
                        // Counted once per such publisher: its samples never reach us.
                        self.shared.counters.dropped.fetch_add(1, Ordering::Relaxed);
                    }
                }
            }
        }
    }
}

impl Link for Ros2Bridge {
    fn caps(&self) -> LinkCaps {
        LinkCaps {
            max_frame: wire::HEADER_LEN + wire::MAX_PAYLOAD,
            mtu: wire::HEADER_LEN + wire::MAX_PAYLOAD,
            reliable: false,
            ordered: true,
            broadcast: false,
        }
    }

    fn send(&self, to: SystemId, frame: &[u8]) -> Result<(), LinkError> {
        let unreachable = |reason: String| LinkError::Unreachable { peer: to, reason };
        if to != self.robot {
            return Err(unreachable(format!(
                "this ros2_bridge reaches only {}",
                self.robot_name
            )));
        }
        let f = wire::decode(frame).map_err(|e| unreachable(format!("not a frame: {e}")))?;
        if f.header.kind != FrameKind::Data {
            // Acknowledgements have no ROS counterpart (delivery is unacknowledged anyway).
            return Ok(());
        }
        let key = (f.header.destination.module, f.header.message_type);
        let Some(out) = self.outbound.get(&key) else {
            return Err(unreachable(format!(
                "no ROS topic is mapped for message type {} to {}'s module {}",
                key.1 .0, self.robot_name, key.0 .0
            )));
        };
        let value = rmpv::decode::read_value(&mut &f.payload[..])
            .map_err(|e| unreachable(format!("payload is not MessagePack: {e}")))?;
        let what = format!(
            "message type {} for {}",
            out.mapping.message, out.mapping.module
        );
        let body =
            crate::rostypes::to_cdr(&value, out.mapping.schema(), &what).map_err(unreachable)?;
        match out.writer.write(
            RawCdr {
                body,
                little: true,
                xcdr2: false,
            },
            None,
        ) {
            Ok(()) => {
                self.shared.counters.sent.fetch_add(1, Ordering::Relaxed);
                Ok(())
            }
            Err(rustdds::dds::WriteError::WouldBlock { .. }) => Err(LinkError::Congested {
                peer: to,
                reason: format!("the DDS writer of {} is full", out.mapping.topic),
            }),
            Err(e) => Err(unreachable(format!(
                "DDS write on {}: {e}",
                out.mapping.topic
            ))),
        }
    }

    fn stats(&self) -> LinkStats {
        let c = &self.shared.counters;
        LinkStats {
            frames_sent: c.sent.load(Ordering::Relaxed),
            frames_received: c.received.load(Ordering::Relaxed),
            frames_dropped: c.dropped.load(Ordering::Relaxed),
            ..LinkStats::default()
        }
    }
}

impl Drop for Ros2Bridge {
    fn drop(&mut self) {
        self.shared.closed.store(true, Ordering::Relaxed);
        if let Some(t) = self.receiver.take() {
            let _ = t.join();
        }
    }
}

/// Reads `ros2_bridge` tables and opens them as [`Ros2Bridge`]s.
pub struct Ros2BridgeFactory;

impl KindSpec for Ros2BridgeFactory {
    fn kind(&self) -> TransportKind {
        kind()
    }

    fn keys(&self) -> &[&'static str] {
        &KEYS
    }

    fn parse(&self, s: &mut SettingsReader<'_, '_>) -> Option<RegisteredSettings> {
        settings::parse(s)
    }
}

impl TransportFactory for Ros2BridgeFactory {
    fn kind(&self) -> TransportKind {
        kind()
    }

    fn spec(self: Arc<Self>) -> Option<Arc<dyn KindSpec>> {
        Some(self)
    }

    fn bridged_robot(&self, transport: &TransportDef) -> Option<String> {
        let TransportSettings::Registered(s) = &transport.settings else {
            return None;
        };
        s.downcast_ref::<BridgeSettings>().map(|b| b.robot.clone())
    }

    fn open(&self, request: OpenRequest<'_>) -> Result<Opened, OpenFailure> {
        let TransportSettings::Registered(s) = &request.transport.settings else {
            return Err("expected ros2_bridge settings".into());
        };
        let settings: &BridgeSettings = s
            .downcast_ref()
            .ok_or("the transport's settings are not ros2_bridge settings")?;
        let bridge = Ros2Bridge::open(request.fleet, request.local, settings, request.sink)?;
        let local_address = Some(format!(
            "ros2_bridge://{}/{}",
            settings.dds.domain_id, settings.robot
        ));
        Ok(Opened {
            link: Arc::new(bridge),
            local_address,
        })
    }
}

//! The `ros2_bridge` transport kind: an external ROS 2 robot (a system that runs ROS 2, not
//! hetcomm) in the fleet, through typed ROS topics.
//!
//! A bridge is a link between this system and the robot. Its fleet table maps, per module and
//! message type, to ROS topics and types ([`BridgeSettings`]):
//!
//! * **publish** (hetcomm → ROS): a message of type `TYPE_ID` sent to (robot, `MODULE`) is
//!   converted by field name ([`crate::rostypes`]) and published on the topic. Nobody
//!   acknowledges it: the transport must say `delivery = "unacknowledged"`, and the outcome
//!   is Sent (without confirmation). A message that does not convert fails its send at once
//!   ([`LinkError::Refused`]), naming both types and the field. A send waits (at most
//!   `connect_timeout_ms`) until the readers discovery knows on the topic are matched
//!   ([`publish`]); if none is, nothing is written and the send fails
//!   ([`LinkError::Unreachable`], "no subscriber of … matched"). A closing bridge waits (as
//!   long again) for the matched readers' acknowledgements of what it wrote.
//! * **subscribe** (ROS → hetcomm): a ROS message on the topic arrives in this system's
//!   `MODULE` as a message of type `TYPE_ID` from the robot (the frame's source module is the
//!   same module id). A system whose `[systems]` entry lists its modules without `MODULE`
//!   does not read that topic.
//!
//! Bad input never reaches a module: a sample that does not decode as the mapped type, and a
//! publisher on a mapped topic whose type is not the mapped one, are counted (dropped frames
//! in the link's stats) and described in [`Problems`], each problem printed once to stderr.
//! The bridge carries plain ROS messages, unauthenticated like any ROS 2 topic without SROS2:
//! the transport must say `security = "none"`.

pub mod dds;
mod publish;
mod settings;

use std::collections::HashMap;
use std::sync::atomic::{AtomicBool, Ordering};
use std::sync::Arc;
use std::thread::JoinHandle;
use std::time::{Duration, Instant};

use hetcomm_config::{Fleet, SettingsReader, TransportKind};
use hetcomm_core::{ModuleId, SystemId};
use hetcomm_link::registry::OpenFailure;
use hetcomm_link::{FrameSink, Link, LinkCaps, LinkError, LinkStats, Peer};
use hetcomm_rosmsg::bridge::{caps, hosts, module_id, robot_id, FrameMaker, Outbound, Tally};
use hetcomm_rosmsg::bridge::{BridgeFactory, BridgeKind};
use hetcomm_rosmsg::codec::Wire;
use hetcomm_rosmsg::schema::Flavour;
use hetcomm_rosmsg::typehash;
use rustdds::mio1::{Events, Interest, Poll, Token};
use rustdds::no_key::DataReader;
use rustdds::{DomainParticipant, TopicKind, GUID};

pub use settings::{BridgeSettings, Mapping, KEYS};

use crate::link::{participant, qos, retire, Ros2OpenError};
use crate::names;
use crate::raw::{RawAdapter, RawCdr};

/// The kind's name in fleet files: `kind = "ros2_bridge"`.
pub fn kind() -> TransportKind {
    TransportKind::new(Ros2BridgeKind::NAME)
}

struct Inbound {
    mapping: Mapping,
    module: ModuleId,
    reader: DataReader<RawCdr, RawAdapter>,
    /// The writers seen on the topic, each with why its samples are dropped, if they are
    /// (it offers a type hash that is not the mapped definition's).
    writers: HashMap<GUID, Option<String>>,
}

struct Shared {
    tally: Tally,
    closed: AtomicBool,
}

/// A link to an external ROS 2 robot through typed topics.
pub struct Ros2Bridge {
    /// Each publish mapping with the index of its topic in `published`.
    outbound: Outbound<usize>,
    published: Vec<publish::Published>,
    connect_timeout: Duration,
    shared: Arc<Shared>,
    receiver: Option<JoinHandle<()>>,
    /// Retired last (`link::retire`): the writers and readers belong to it.
    participant: Option<DomainParticipant>,
}

impl Ros2Bridge {
    /// Opens the bridge on system `local` of `fleet` with `settings`.
    pub fn open(
        fleet: &Fleet,
        local: SystemId,
        settings: &BridgeSettings,
        sink: Arc<dyn FrameSink>,
    ) -> Result<Ros2Bridge, OpenFailure> {
        Self::open_named(fleet, local, settings, &Naming::Ros2, sink)
    }

    /// Like [`open`](Self::open), with the DDS topic and type names of `naming`.
    pub(crate) fn open_named(
        fleet: &Fleet,
        local: SystemId,
        settings: &BridgeSettings,
        naming: &Naming,
        sink: Arc<dyn FrameSink>,
    ) -> Result<Ros2Bridge, OpenFailure> {
        let robot = robot_id(fleet, local, &settings.robot, Flavour::Ros2)?;
        let dp = participant(&settings.dds)?;
        let qos = qos(&settings.dds);
        let dds_err = |what: String| {
            move |e: rustdds::dds::CreateError| Ros2OpenError::Dds {
                what,
                reason: e.to_string(),
            }
        };
        let topic = |m: &Mapping| {
            dp.create_topic(naming.topic(m), naming.type_name(m), &qos, TopicKind::NoKey)
                .map_err(dds_err(format!("topic {}", m.topic)))
        };
        let publisher = dp
            .create_publisher(&qos)
            .map_err(dds_err("a publisher".into()))?;
        let mut outbound = Outbound::new("ros2_bridge", robot, &settings.robot, Wire::CDR);
        let mut published = Vec::new();
        for m in &settings.publish {
            let module = module_id(fleet, &m.module, &m.topic)?;
            let writer = publisher
                .create_datawriter_no_key::<RawCdr, RawAdapter>(&topic(m)?, Some(qos.clone()))
                .map_err(dds_err(format!("the writer of {}", m.topic)))?;
            outbound.insert(module, m.clone(), published.len());
            published.push(publish::Published::new(
                &m.topic,
                naming.topic(m),
                naming.type_name(m),
                writer,
            ));
        }
        let subscriber = dp
            .create_subscriber(&qos)
            .map_err(dds_err("a subscriber".into()))?;
        let mut inbound = Vec::new();
        for m in &settings.subscribe {
            let module = module_id(fleet, &m.module, &m.topic)?;
            if !hosts(fleet, local, module) {
                continue;
            }
            let reader = subscriber
                .create_datareader_no_key::<RawCdr, RawAdapter>(&topic(m)?, Some(qos.clone()))
                .map_err(dds_err(format!("the reader of {}", m.topic)))?;
            inbound.push(Inbound {
                mapping: m.clone(),
                module,
                reader,
                writers: HashMap::new(),
            });
        }
        let shared = Arc::new(Shared {
            tally: Tally::new("ros2_bridge"),
            closed: AtomicBool::new(false),
        });
        let rx = Receiver {
            naming: naming.clone(),
            dp: dp.clone(),
            inbound,
            published: settings.publish.clone(),
            robot,
            sink,
            shared: shared.clone(),
            frames: FrameMaker::new(local, robot),
        };
        let receiver = std::thread::Builder::new()
            .name(format!("hetcomm-ros2-bridge-{}", settings.robot))
            .spawn(move || rx.run())?;
        Ok(Ros2Bridge {
            outbound,
            published,
            connect_timeout: Duration::from_millis(settings.dds.connect_timeout_ms),
            shared,
            receiver: Some(receiver),
            participant: Some(dp),
        })
    }

    /// The problems seen with input from ROS (undecodable samples, publishers of another
    /// type on a mapped topic, publishers and subscribers that offer another type hash), each
    /// once.
    pub fn problems(&self) -> Vec<String> {
        self.shared.tally.problems()
    }
}

/// How a bridge names its topics and types on DDS.
#[derive(Clone, Debug)]
pub(crate) enum Naming {
    /// As ROS 2 does (`ros2_bridge`): `rt/` before the topic, `pkg::msg::dds_::Type_`.
    Ros2,
    /// Plain DDS (`dds`): the topic as written, the type `pkg::Type` unless the topic's entry
    /// in this map (topic → DDS type name) says otherwise.
    Plain(std::collections::BTreeMap<String, String>),
}

impl Naming {
    /// The DDS topic of `m`.
    pub(crate) fn topic(&self, m: &Mapping) -> String {
        match self {
            Naming::Ros2 => names::dds_topic(&m.topic),
            Naming::Plain(_) => m.topic.clone(),
        }
    }

    /// The type hash (`RIHS01_…`) peers on `m`'s topic should offer, if they offer one:
    /// ROS 2 names its types by ROS names and hashes them; a plain DDS topic does neither.
    fn type_hash(&self, m: &Mapping) -> Option<&'static str> {
        match self {
            Naming::Ros2 if !m.schema.type_hash.is_empty() => Some(m.schema.type_hash),
            _ => None,
        }
    }

    /// The DDS type name of `m`.
    pub(crate) fn type_name(&self, m: &Mapping) -> String {
        match self {
            Naming::Ros2 => names::dds_type(m.ros_type()),
            Naming::Plain(types) => types
                .get(&m.topic)
                .cloned()
                .unwrap_or_else(|| dds::plain_type(m.ros_type())),
        }
    }
}

/// The bridge's receive side: every subscribed topic's reader, polled on one thread.
struct Receiver {
    naming: Naming,
    dp: DomainParticipant,
    inbound: Vec<Inbound>,
    /// The publish mappings, to check their subscribers' type hashes.
    published: Vec<Mapping>,
    robot: SystemId,
    sink: Arc<dyn FrameSink>,
    shared: Arc<Shared>,
    frames: FrameMaker,
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
                self.check_subscriber_hashes();
                next_check = Instant::now() + Duration::from_millis(500);
            }
        }
    }

    fn drop_with(&self, problem: String) {
        self.shared.tally.dropped(1, problem);
    }

    fn drain(&mut self, i: usize) {
        loop {
            let inb = &mut self.inbound[i];
            let (writer, sample) = match inb.reader.take_next_sample() {
                Ok(Some(s)) => (s.sample_info().writer_guid(), s.into_value()),
                Ok(None) => return,
                Err(e) => {
                    let topic = inb.mapping.topic.clone();
                    self.drop_with(format!("a sample on {topic} could not be read: {e}"));
                    continue;
                }
            };
            if let Some(why) = self.writer_refused(i, writer) {
                self.drop_with(why);
                continue;
            }
            let inb = &self.inbound[i];
            let (topic, schema) = (inb.mapping.topic.clone(), inb.mapping.schema);
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
            let inb = &self.inbound[i];
            let frame = match self.frames.frame(inb.module, inb.mapping.message, &value) {
                Ok(f) => f,
                Err(e) => {
                    self.drop_with(format!("a sample on {topic} {e}"));
                    continue;
                }
            };
            self.shared.tally.received();
            self.sink.on_frame(&frame, Peer::System(self.robot));
        }
    }

    /// Why samples of `writer` on inbound topic `i` are dropped, if they are: it offers a
    /// type hash that is not the mapped definition's (the same type name, another layout).
    /// A writer is looked up in discovery once, when its first sample comes.
    fn writer_refused(&mut self, i: usize, writer: GUID) -> Option<String> {
        let expected = self.naming.type_hash(&self.inbound[i].mapping)?;
        if !self.inbound[i].writers.contains_key(&writer) {
            let offered = self
                .dp
                .discovered_writers()
                .into_iter()
                .find(|w| w.writer_proxy.remote_writer_guid == writer)
                .and_then(|w| typehash::offered(&w.user_data).map(str::to_string));
            let inb = &mut self.inbound[i];
            let why = offered.filter(|h| h != expected).map(|h| {
                format!(
                    "a publisher on {} offers type hash {h} for {}, but the definition the \
                     bridge read hashes to {expected}: the two definitions differ, so its \
                     messages are dropped",
                    inb.mapping.topic,
                    typehash::ros2_name(inb.mapping.ros_type()),
                )
            });
            inb.writers.insert(writer, why);
        }
        self.inbound[i].writers[&writer].clone()
    }

    /// Reports (once each) subscribers of a published topic that offer a type hash other
    /// than the mapped definition's: DDS matches them by type name, but they may misread
    /// what the bridge publishes. Nothing is dropped here, so nothing is counted.
    fn check_subscriber_hashes(&self) {
        let readers = self.dp.discovered_readers();
        for m in &self.published {
            let Some(expected) = self.naming.type_hash(m) else {
                continue;
            };
            let (topic, ty) = (self.naming.topic(m), self.naming.type_name(m));
            for r in &readers {
                let t = &r.subscription_topic_data;
                if *t.topic_name() != topic || *t.type_name() != ty {
                    continue;
                }
                if let Some(h) = typehash::offered(&r.user_data).filter(|h| *h != expected) {
                    self.shared.tally.report(format!(
                        "a subscriber of {} expects type hash {h} for {}, but the definition \
                         the bridge read hashes to {expected}: the two definitions differ, so \
                         it may misread what the bridge publishes",
                        m.topic,
                        typehash::ros2_name(m.ros_type()),
                    ));
                }
            }
        }
    }

    /// Reports publishers on a mapped topic whose type is not the mapped one (DDS does not
    /// match them, so their messages would otherwise vanish without a word).
    fn check_publisher_types(&self) {
        let writers = self.dp.discovered_writers();
        for inb in &self.inbound {
            let topic = self.naming.topic(&inb.mapping);
            let expected = self.naming.type_name(&inb.mapping);
            for w in &writers {
                let t = &w.publication_topic_data;
                if t.topic_name == topic && t.type_name != expected {
                    // Counted once per such publisher: its samples never reach us.
                    self.shared.tally.dropped_once(format!(
                        "a publisher on {} has type {}, but the topic is mapped as {} ({}): its \
                         messages are not received",
                        inb.mapping.topic,
                        t.type_name,
                        inb.mapping.ros_type(),
                        expected
                    ));
                }
            }
        }
    }
}

impl Link for Ros2Bridge {
    /// True: the frames the router sends are read, and the frames it receives are made,
    /// in this process (`hetcomm_rosmsg::bridge::FrameMaker`); only their headers need a CRC.
    fn checksums_payload(&self) -> bool {
        true
    }

    fn caps(&self) -> LinkCaps {
        caps()
    }

    fn send(&self, to: SystemId, frame: &[u8]) -> Result<(), LinkError> {
        let Some(out) = self.outbound.convert(to, frame)? else {
            return Ok(());
        };
        let (m, p) = (out.mapping, &self.published[*out.publisher]);
        p.wait(
            self.participant.as_ref().expect("open"),
            self.connect_timeout,
        )
        .map_err(|reason| LinkError::Unreachable { peer: to, reason })?;
        let cdr = RawCdr {
            body: out.body,
            little: true,
            xcdr2: false,
        };
        match p.writer.write(cdr, None) {
            Ok(()) => {
                p.wrote();
                self.shared.tally.sent();
                Ok(())
            }
            Err(rustdds::dds::WriteError::WouldBlock { .. }) => Err(LinkError::Congested {
                peer: to,
                reason: format!("the DDS writer of {} is full", m.topic),
            }),
            Err(e) => Err(LinkError::Unreachable {
                peer: to,
                reason: format!("DDS write on {}: {e}", m.topic),
            }),
        }
    }

    fn stats(&self) -> LinkStats {
        self.shared.tally.stats()
    }
}

impl Drop for Ros2Bridge {
    fn drop(&mut self) {
        // What was written reaches the readers matched before the participant goes.
        let deadline = Instant::now() + self.connect_timeout;
        for p in &self.published {
            p.flush(deadline.saturating_duration_since(Instant::now()));
        }
        self.shared.closed.store(true, Ordering::Relaxed);
        if let Some(t) = self.receiver.take() {
            let _ = t.join();
        }
        self.published.clear();
        if let Some(dp) = self.participant.take() {
            retire(dp);
        }
    }
}

/// The `ros2_bridge` kind, registered as a [`BridgeFactory`] ([`Ros2BridgeFactory`]).
pub struct Ros2BridgeKind;

/// Reads `ros2_bridge` tables and opens them as [`Ros2Bridge`]s.
pub type Ros2BridgeFactory = BridgeFactory<Ros2BridgeKind>;

impl BridgeKind for Ros2BridgeKind {
    type Settings = BridgeSettings;
    const NAME: &'static str = "ros2_bridge";
    const KEYS: &'static [&'static str] = &KEYS;

    fn parse(s: &mut SettingsReader<'_, '_>) -> Option<BridgeSettings> {
        settings::parse(s)
    }

    fn robot(settings: &BridgeSettings) -> &str {
        &settings.robot
    }

    fn mappings(settings: &BridgeSettings) -> (&[Mapping], &[Mapping]) {
        (&settings.publish, &settings.subscribe)
    }

    fn open(
        fleet: &Fleet,
        local: SystemId,
        settings: &BridgeSettings,
        sink: Arc<dyn FrameSink>,
    ) -> Result<(Arc<dyn Link>, String), OpenFailure> {
        let bridge = Ros2Bridge::open(fleet, local, settings, sink)?;
        let address = format!(
            "ros2_bridge://{}/{}",
            settings.dds.domain_id, settings.robot
        );
        Ok((Arc::new(bridge), address))
    }
}

//! [`Ros2Link`]: one DDS participant per system, one reader on the system's own topic, one
//! writer per other system of the fleet.

use std::collections::HashMap;
use std::sync::atomic::{AtomicBool, AtomicI32, AtomicU64, Ordering};
use std::sync::{Arc, Mutex};
use std::thread::JoinHandle;
use std::time::{Duration, Instant};

use hetcomm_core::SystemId;
use hetcomm_link::{FrameSink, Link, LinkCaps, LinkError, LinkStats, Peer};
use rustdds::mio1::{Events, Interest, Poll, Token};
use rustdds::no_key::{DataReaderCdr, DataWriterCdr};
use rustdds::policy::{Durability, History, Reliability as DdsReliability};
use rustdds::{
    DataWriterStatus, DomainParticipant, DomainParticipantBuilder, QosPolicies, QosPolicyBuilder,
    StatusEvented, TopicKind,
};

use crate::msg::{FrameMessage, FRAME_TYPE};
use crate::names;
use crate::settings::{Reliability, Ros2Settings};

/// Largest frame the link carries (DDS fragments it into RTPS DATA_FRAG submessages).
pub const MAX_FRAME: usize = 16 * 1024 * 1024;

/// Why a `ros2` link did not open.
#[derive(Debug, thiserror::Error)]
pub enum OpenError {
    /// The local system is not in the fleet's name list.
    #[error("system {0} has no name in the fleet")]
    UnknownLocal(SystemId),
    /// rustdds refused to create the participant or one of its entities.
    #[error("DDS: could not create {what}: {reason}")]
    Dds {
        /// What was being created.
        what: String,
        /// rustdds's error.
        reason: String,
    },
}

fn dds_err(what: impl Into<String>) -> impl FnOnce(rustdds::dds::CreateError) -> OpenError {
    let what = what.into();
    move |e| OpenError::Dds {
        what,
        reason: e.to_string(),
    }
}

/// The QoS of a transport's topics (readers and writers alike), from its settings.
pub fn qos(settings: &Ros2Settings) -> QosPolicies {
    let reliability = match settings.reliability {
        Reliability::Reliable => DdsReliability::Reliable {
            max_blocking_time: rustdds::Duration::from_millis(100),
        },
        Reliability::BestEffort => DdsReliability::BestEffort,
    };
    QosPolicyBuilder::new()
        .reliability(reliability)
        .durability(Durability::Volatile)
        .history(History::KeepLast {
            depth: settings.history_depth,
        })
        .build()
}

/// Opens the DDS participant a `ros2` transport (or bridge) uses.
pub fn participant(settings: &Ros2Settings) -> Result<DomainParticipant, OpenError> {
    let mut builder =
        DomainParticipantBuilder::new(settings.domain_id).same_host_loopback(settings.same_host);
    if let Some(ip) = settings.interface {
        builder = builder.with_only_networks([ip]);
    }
    builder.build().map_err(dds_err("the domain participant"))
}

/// One destination: its topic's writer and whether a reader is matched to it.
struct Dest {
    topic: String,
    writer: Mutex<DataWriterCdr<FrameMessage>>,
    /// Readers matched to the writer, as its status events last said.
    matched: AtomicI32,
}

impl Dest {
    /// Applies the writer's pending status events; returns the matched readers.
    fn refresh(&self, writer: &DataWriterCdr<FrameMessage>) -> i32 {
        while let Some(status) = writer.try_recv_status() {
            if let DataWriterStatus::PublicationMatched { current, .. } = status {
                self.matched.store(current.count(), Ordering::Relaxed);
            }
        }
        self.matched.load(Ordering::Relaxed)
    }
}

#[derive(Default)]
struct Counters {
    sent: AtomicU64,
    received: AtomicU64,
    dropped: AtomicU64,
    malformed: AtomicU64,
}

struct Shared {
    counters: Counters,
    closed: AtomicBool,
}

/// A `ros2` link: frames as `std_msgs/msg/UInt8MultiArray` on `<namespace>/<System>`.
pub struct Ros2Link {
    topic: String,
    dests: HashMap<SystemId, Dest>,
    connect_timeout: Duration,
    shared: Arc<Shared>,
    receiver: Option<JoinHandle<()>>,
    // Dropped last: the writers and the reader belong to it.
    _participant: DomainParticipant,
}

impl Ros2Link {
    /// Opens system `local`'s link: its participant, its reader (delivering to `sink`) and one
    /// writer per other system in `names`.
    pub fn open(
        local: SystemId,
        names: &[(SystemId, String)],
        settings: &Ros2Settings,
        sink: Arc<dyn FrameSink>,
    ) -> Result<Ros2Link, OpenError> {
        let own = names
            .iter()
            .find(|(id, _)| *id == local)
            .ok_or(OpenError::UnknownLocal(local))?;
        let dp = participant(settings)?;
        let qos = qos(settings);
        let type_name = names::dds_type(FRAME_TYPE);
        let topic_of = |name: &str| names::system_topic(&settings.namespace, name);

        let own_topic = topic_of(&own.1);
        let topic = dp
            .create_topic(
                names::dds_topic(&own_topic),
                type_name.clone(),
                &qos,
                TopicKind::NoKey,
            )
            .map_err(dds_err(format!("topic {own_topic}")))?;
        let subscriber = dp
            .create_subscriber(&qos)
            .map_err(dds_err("a subscriber"))?;
        let reader = subscriber
            .create_datareader_no_key_cdr::<FrameMessage>(&topic, Some(qos.clone()))
            .map_err(dds_err(format!("the reader of {own_topic}")))?;

        let publisher = dp.create_publisher(&qos).map_err(dds_err("a publisher"))?;
        let mut dests = HashMap::new();
        for (id, name) in names.iter().filter(|(id, _)| *id != local) {
            let t = topic_of(name);
            let dds_topic = dp
                .create_topic(
                    names::dds_topic(&t),
                    type_name.clone(),
                    &qos,
                    TopicKind::NoKey,
                )
                .map_err(dds_err(format!("topic {t}")))?;
            let writer = publisher
                .create_datawriter_no_key_cdr::<FrameMessage>(&dds_topic, Some(qos.clone()))
                .map_err(dds_err(format!("the writer of {t}")))?;
            dests.insert(
                *id,
                Dest {
                    topic: t,
                    writer: Mutex::new(writer),
                    matched: AtomicI32::new(0),
                },
            );
        }

        let shared = Arc::new(Shared {
            counters: Counters::default(),
            closed: AtomicBool::new(false),
        });
        let rx_shared = shared.clone();
        let receiver = std::thread::Builder::new()
            .name(format!("hetcomm-ros2-rx-{}", own.1))
            .spawn(move || receive(reader, sink, rx_shared))
            .map_err(|e| OpenError::Dds {
                what: "the receive thread".into(),
                reason: e.to_string(),
            })?;
        Ok(Ros2Link {
            topic: own_topic,
            dests,
            connect_timeout: Duration::from_millis(settings.connect_timeout_ms),
            shared,
            receiver: Some(receiver),
            _participant: dp,
        })
    }

    /// This system's ROS 2 topic, e.g. `/hetcomm/Bravo`.
    pub fn topic(&self) -> &str {
        &self.topic
    }

    /// Messages on this system's topic that were not frames (failed to deserialize as
    /// `std_msgs/msg/UInt8MultiArray`, or carried no data).
    pub fn malformed(&self) -> u64 {
        self.shared.counters.malformed.load(Ordering::Relaxed)
    }

    /// Waits (at most the connect timeout) for a reader to be matched to `dest`'s writer.
    fn wait_matched(&self, to: SystemId, dest: &Dest) -> Result<(), LinkError> {
        let deadline = Instant::now() + self.connect_timeout;
        let mut pause = Duration::from_micros(200);
        loop {
            let writer = dest.writer.lock().unwrap_or_else(|e| e.into_inner());
            if dest.refresh(&writer) > 0 {
                return Ok(());
            }
            drop(writer);
            if Instant::now() >= deadline {
                return Err(LinkError::Unreachable {
                    peer: to,
                    reason: format!(
                        "no subscriber of {} matched within {} ms (is that system running, on \
                         the same domain_id, reachable by DDS discovery?)",
                        dest.topic,
                        self.connect_timeout.as_millis()
                    ),
                });
            }
            std::thread::sleep(pause);
            pause = (pause * 2).min(Duration::from_millis(10));
        }
    }
}

/// The receive thread: polls the reader, hands every frame to the sink.
fn receive(mut reader: DataReaderCdr<FrameMessage>, sink: Arc<dyn FrameSink>, shared: Arc<Shared>) {
    let Ok(mut poll) = Poll::new() else {
        return;
    };
    if poll
        .registry()
        .register(&mut reader, Token(0), Interest::READABLE)
        .is_err()
    {
        return;
    }
    let mut events = Events::with_capacity(8);
    while !shared.closed.load(Ordering::Relaxed) {
        if poll
            .poll(&mut events, Some(Duration::from_millis(50)))
            .is_err()
        {
            continue;
        }
        // Edge-triggered: take everything there is, in batches.
        loop {
            match reader.take(256, rustdds::ReadCondition::any()) {
                Ok(batch) if batch.is_empty() => break,
                Ok(batch) => {
                    for sample in batch {
                        let msg = sample.into_value();
                        if msg.data.is_empty() {
                            shared.counters.malformed.fetch_add(1, Ordering::Relaxed);
                            shared.counters.dropped.fetch_add(1, Ordering::Relaxed);
                            continue;
                        }
                        shared.counters.received.fetch_add(1, Ordering::Relaxed);
                        sink.on_frame(&msg.data, Peer::Unknown);
                    }
                }
                Err(_) => {
                    // A sample that is not a UInt8MultiArray: counted, never delivered.
                    shared.counters.malformed.fetch_add(1, Ordering::Relaxed);
                    shared.counters.dropped.fetch_add(1, Ordering::Relaxed);
                }
            }
        }
    }
}

impl Link for Ros2Link {
    fn caps(&self) -> LinkCaps {
        LinkCaps {
            max_frame: MAX_FRAME,
            mtu: MAX_FRAME,
            reliable: false,
            ordered: true,
            broadcast: false,
        }
    }

    fn send(&self, to: SystemId, frame: &[u8]) -> Result<(), LinkError> {
        if frame.len() > MAX_FRAME {
            return Err(LinkError::TooLarge {
                len: frame.len(),
                max: MAX_FRAME,
            });
        }
        let Some(dest) = self.dests.get(&to) else {
            return Err(LinkError::Unreachable {
                peer: to,
                reason: "not a system of this ros2 transport".into(),
            });
        };
        if dest.matched.load(Ordering::Relaxed) <= 0 {
            self.wait_matched(to, dest)?;
        }
        let writer = dest.writer.lock().unwrap_or_else(|e| e.into_inner());
        dest.refresh(&writer);
        let message = FrameMessage {
            data: frame.to_vec(),
            ..FrameMessage::default()
        };
        match writer.write(message, None) {
            Ok(()) => {
                self.shared.counters.sent.fetch_add(1, Ordering::Relaxed);
                Ok(())
            }
            Err(rustdds::dds::WriteError::WouldBlock { .. }) => Err(LinkError::Congested {
                peer: to,
                reason: format!("the DDS writer of {} is full", dest.topic),
            }),
            Err(e) => {
                self.shared.counters.dropped.fetch_add(1, Ordering::Relaxed);
                Err(LinkError::Unreachable {
                    peer: to,
                    reason: format!("DDS write on {}: {e}", dest.topic),
                })
            }
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

impl Drop for Ros2Link {
    fn drop(&mut self) {
        self.shared.closed.store(true, Ordering::Relaxed);
        if let Some(t) = self.receiver.take() {
            let _ = t.join();
        }
    }
}

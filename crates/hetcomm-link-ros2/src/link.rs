//! [`Ros2Link`]: one DDS participant per system, one reader on the system's own topic, one
//! writer per other system of the fleet.

use std::collections::HashMap;
use std::sync::atomic::{AtomicBool, AtomicI32, AtomicU64, Ordering};
use std::sync::{Arc, Mutex};
use std::thread::JoinHandle;
use std::time::{Duration, Instant};

use hetcomm_core::SystemId;
use hetcomm_link::{FrameSink, Link, LinkCaps, LinkError, LinkStats, Peer, Readable};
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

/// Largest frame the link carries (DDS fragments it into RTPS DATA_FRAG submessages): the
/// largest rustdds delivered every time on loopback under the conformance suite (16 MiB
/// frames were lost without a trace, 8 MiB ones now and then; docs/ros2.md).
pub const MAX_FRAME: usize = 4 * 1024 * 1024;

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
    driven: Option<Driven>,
    // Dropped last: the writers and the reader belong to it.
    _participant: DomainParticipant,
}

impl Ros2Link {
    /// Opens system `local`'s link: its participant, its reader (delivering to `sink`, read
    /// by a thread of the link's own) and one writer per other system in `names`.
    pub fn open(
        local: SystemId,
        names: &[(SystemId, String)],
        settings: &Ros2Settings,
        sink: Arc<dyn FrameSink>,
    ) -> Result<Ros2Link, OpenError> {
        Self::open_with(local, names, settings, sink, false)
    }

    /// Like [`open`](Self::open), but the reader is read through [`Link::readable`] by
    /// whoever drives it (the runtime's reactor, a module thread waiting for a message): no
    /// thread hand-off between the DDS reader and the router.
    pub fn open_driven(
        local: SystemId,
        names: &[(SystemId, String)],
        settings: &Ros2Settings,
        sink: Arc<dyn FrameSink>,
    ) -> Result<Ros2Link, OpenError> {
        Self::open_with(local, names, settings, sink, true)
    }

    fn open_with(
        local: SystemId,
        names: &[(SystemId, String)],
        settings: &Ros2Settings,
        sink: Arc<dyn FrameSink>,
        driven: bool,
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
        let io_err = |e: std::io::Error| OpenError::Dds {
            what: "the receive side".into(),
            reason: e.to_string(),
        };
        let rx = Rx::new(reader, sink).map_err(io_err)?;
        let (receiver, driven) = if driven {
            use std::os::fd::AsRawFd;
            let fd = rx.poll.as_raw_fd();
            let driven = Driven {
                fd,
                rx: Mutex::new(rx),
                shared: shared.clone(),
            };
            (None, Some(driven))
        } else {
            let rx_shared = shared.clone();
            let mut rx = rx;
            let thread = std::thread::Builder::new()
                .name(format!("hetcomm-ros2-rx-{}", own.1))
                .spawn(move || {
                    while !rx_shared.closed.load(Ordering::Relaxed) {
                        rx.read(Duration::from_millis(50), &rx_shared);
                    }
                })
                .map_err(io_err)?;
            (Some(thread), None)
        };
        Ok(Ros2Link {
            topic: own_topic,
            dests,
            connect_timeout: Duration::from_millis(settings.connect_timeout_ms),
            shared,
            receiver,
            driven,
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

/// The receive side: the reader, registered with its own `mio` poll.
struct Rx {
    poll: Poll,
    events: Events,
    reader: DataReaderCdr<FrameMessage>,
    sink: Arc<dyn FrameSink>,
}

impl Rx {
    fn new(
        mut reader: DataReaderCdr<FrameMessage>,
        sink: Arc<dyn FrameSink>,
    ) -> std::io::Result<Rx> {
        let poll = Poll::new()?;
        poll.registry()
            .register(&mut reader, Token(0), Interest::READABLE)?;
        Ok(Rx {
            poll,
            events: Events::with_capacity(8),
            reader,
            sink,
        })
    }

    /// Waits at most `timeout` for a notification, then takes everything there is (the
    /// registration is edge-triggered), in batches; returns the frames handed on.
    fn read(&mut self, timeout: Duration, shared: &Shared) -> usize {
        let _ = self.poll.poll(&mut self.events, Some(timeout));
        let mut frames = 0;
        loop {
            match self.reader.take(256, rustdds::ReadCondition::any()) {
                Ok(batch) if batch.is_empty() => return frames,
                Ok(batch) => {
                    for sample in batch {
                        let msg = sample.into_value();
                        if msg.data.is_empty() {
                            shared.counters.malformed.fetch_add(1, Ordering::Relaxed);
                            shared.counters.dropped.fetch_add(1, Ordering::Relaxed);
                            continue;
                        }
                        shared.counters.received.fetch_add(1, Ordering::Relaxed);
                        self.sink.on_frame(&msg.data, Peer::Unknown);
                        frames += 1;
                    }
                }
                Err(_) => {
                    // A sample that is not a UInt8MultiArray (rustdds consumed it): counted,
                    // never delivered; the samples after it stay for the next batch.
                    shared.counters.malformed.fetch_add(1, Ordering::Relaxed);
                    shared.counters.dropped.fetch_add(1, Ordering::Relaxed);
                }
            }
        }
    }
}

/// The receive side read by the runtime's reactor or a waiting module thread
/// ([`Ros2Link::open_driven`]): the poll's epoll descriptor turns readable when a sample
/// notification arrives.
struct Driven {
    fd: std::os::fd::RawFd,
    rx: Mutex<Rx>,
    shared: Arc<Shared>,
}

impl Readable for Driven {
    fn fd(&self) -> std::os::fd::RawFd {
        self.fd
    }

    fn read_ready(&self, _budget: usize) -> std::io::Result<usize> {
        // Everything is taken at once: the registration is edge-triggered, so samples left
        // behind would wait for the next notification.
        let mut rx = match self.rx.try_lock() {
            Ok(rx) => rx,
            Err(std::sync::TryLockError::Poisoned(e)) => e.into_inner(),
            Err(std::sync::TryLockError::WouldBlock) => return Ok(0),
        };
        Ok(rx.read(Duration::ZERO, &self.shared))
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

    fn readable(&self) -> Option<&dyn Readable> {
        self.driven.as_ref().map(|d| d as &dyn Readable)
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

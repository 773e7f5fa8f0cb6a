//! [`Ros2Link`]: one DDS participant per system, one reader on the system's own topic, one
//! writer per other system of the fleet.

use parking_lot::Mutex;
use std::collections::HashMap;
use std::sync::atomic::{AtomicBool, AtomicI32, AtomicU64, Ordering};
use std::sync::Arc;
use std::thread::JoinHandle;
use std::time::{Duration, Instant};

use hetcomm_core::SystemId;
use hetcomm_link::{FrameSink, Link, LinkCaps, LinkError, LinkEvent, LinkStats, Peer, Readable};
use rustdds::mio1::{Events, Interest, Poll, Token};
use rustdds::no_key::{DataReaderCdr, DataWriterCdr};
use rustdds::policy::{Durability, History, Reliability as DdsReliability};
use rustdds::{
    DataWriterStatus, DomainParticipant, DomainParticipantBuilder, QosPolicies, QosPolicyBuilder,
    StatusEvented, TopicKind, GUID,
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
pub enum Ros2OpenError {
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

fn dds_err(what: impl Into<String>) -> impl FnOnce(rustdds::dds::CreateError) -> Ros2OpenError {
    let what = what.into();
    move |e| Ros2OpenError::Dds {
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

/// Opens the DDS participant a `ros2` transport (or bridge) uses. Give it back with
/// [`retire`] when done: participants dropped elsewhere can take the process down at exit.
pub fn participant(settings: &Ros2Settings) -> Result<DomainParticipant, Ros2OpenError> {
    // Participants retired earlier go now, on this thread (see `retire`).
    let retired = std::mem::take(&mut *retired().lock());
    drop(retired);
    let mut builder =
        DomainParticipantBuilder::new(settings.domain_id).same_host_loopback(settings.same_host);
    if let Some(ip) = settings.interface {
        builder = builder.with_only_networks([ip]);
    }
    builder.build().map_err(dds_err("the domain participant"))
}

fn retired() -> &'static Mutex<Vec<DomainParticipant>> {
    static RETIRED: std::sync::OnceLock<Mutex<Vec<DomainParticipant>>> = std::sync::OnceLock::new();
    RETIRED.get_or_init(Default::default)
}

/// Takes a participant whose readers and writers are gone: it is dropped when the next
/// participant is opened, or never if the process exits first.
///
/// rustdds's discovery thread holds its participant for a moment now and then (its
/// announcements); if the last other handle goes meanwhile, the discovery thread drops it,
/// joins itself and panics ("failed to join thread: Resource deadlock avoided", about one
/// process in two hundred, when a process exits right after closing its links). A participant
/// kept here is not dropped at exit (statics are not), so a process that exits after closing
/// its links never hits that; at most the participants retired since the last one opened are
/// kept meanwhile.
pub fn retire(dp: DomainParticipant) {
    retired().lock().push(dp);
}

/// One destination: its topic's writer and whether a reader is matched to it.
struct Dest {
    id: SystemId,
    topic: String,
    writer: Mutex<DataWriterCdr<FrameMessage>>,
    /// Readers matched to the writer, as its status events last said.
    matched: AtomicI32,
    /// The readers matched, each with when it was.
    readers: Mutex<HashMap<GUID, Instant>>,
    /// Whether the link last reported the destination up (a reader matched).
    up: AtomicBool,
}

impl Dest {
    /// Applies the writer's pending status events; returns the matched readers. A change
    /// between none and some is queued in `events` as the destination's presence.
    fn refresh(&self, writer: &DataWriterCdr<FrameMessage>, events: &Mutex<Vec<LinkEvent>>) -> i32 {
        while let Some(status) = writer.try_recv_status() {
            if let DataWriterStatus::PublicationMatched {
                current, reader, ..
            } = status
            {
                let mut readers = self.readers.lock();
                if current.count_change() > 0 {
                    readers.insert(reader, Instant::now());
                } else if current.count_change() < 0 {
                    readers.remove(&reader);
                }
                self.matched.store(current.count(), Ordering::Relaxed);
                let up = current.count() > 0;
                if self.up.swap(up, Ordering::Relaxed) != up {
                    let event = match up {
                        true => LinkEvent::PeerUp(self.id),
                        false => LinkEvent::PeerDown(self.id),
                    };
                    events.lock().push(event);
                }
            }
        }
        self.matched.load(Ordering::Relaxed)
    }
}

/// How long after the first reader of a destination matched a send waits for a writer of that
/// reader's participant on this link's own topic (the destination's answers) to be
/// discovered, so that its first acknowledgement is read at once; a reader with no such
/// writer (a program that only reads) is not waited for longer.
const ANSWER_WAIT: Duration = Duration::from_millis(100);

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
    /// Presence changes not yet reported to the sink (reported by the receive side).
    events: Mutex<Vec<LinkEvent>>,
}

/// A `ros2` link: frames as `std_msgs/msg/UInt8MultiArray` on `<namespace>/<System>`.
pub struct Ros2Link {
    topic: String,
    dests: Arc<HashMap<SystemId, Dest>>,
    /// This system's DDS topic (the destinations' answers come on it).
    own_dds_topic: String,
    connect_timeout: Duration,
    shared: Arc<Shared>,
    receiver: Option<JoinHandle<()>>,
    driven: Option<Driven>,
    /// Retired last ([`retire`]): the writers and the reader belong to it.
    participant: Option<DomainParticipant>,
}

impl Ros2Link {
    /// Opens system `local`'s link: its participant, its reader (delivering to `sink`, read
    /// by a thread of the link's own) and one writer per other system in `names`.
    pub fn open(
        local: SystemId,
        names: &[(SystemId, String)],
        settings: &Ros2Settings,
        sink: Arc<dyn FrameSink>,
    ) -> Result<Ros2Link, Ros2OpenError> {
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
    ) -> Result<Ros2Link, Ros2OpenError> {
        Self::open_with(local, names, settings, sink, true)
    }

    fn open_with(
        local: SystemId,
        names: &[(SystemId, String)],
        settings: &Ros2Settings,
        sink: Arc<dyn FrameSink>,
        driven: bool,
    ) -> Result<Ros2Link, Ros2OpenError> {
        let own = names
            .iter()
            .find(|(id, _)| *id == local)
            .ok_or(Ros2OpenError::UnknownLocal(local))?;
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

        let io_err = |e: std::io::Error| Ros2OpenError::Dds {
            what: "the receive side".into(),
            reason: e.to_string(),
        };
        // The writers' status (readers matched and lost) wakes the receive side too.
        let poll = Poll::new().map_err(io_err)?;
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
            let mut writer = publisher
                .create_datawriter_no_key_cdr::<FrameMessage>(&dds_topic, Some(qos.clone()))
                .map_err(dds_err(format!("the writer of {t}")))?;
            poll.registry()
                .register(
                    writer.as_status_source_mio1(),
                    Token(1 + dests.len()),
                    Interest::READABLE,
                )
                .map_err(io_err)?;
            dests.insert(
                *id,
                Dest {
                    id: *id,
                    topic: t,
                    writer: Mutex::new(writer),
                    matched: AtomicI32::new(0),
                    readers: Mutex::default(),
                    up: AtomicBool::new(false),
                },
            );
        }
        let dests = Arc::new(dests);

        let shared = Arc::new(Shared {
            counters: Counters::default(),
            closed: AtomicBool::new(false),
            events: Mutex::default(),
        });
        let rx = Rx::new(poll, reader, sink, dests.clone()).map_err(io_err)?;
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
            own_dds_topic: names::dds_topic(&own_topic),
            topic: own_topic,
            dests,
            connect_timeout: Duration::from_millis(settings.connect_timeout_ms),
            shared,
            receiver,
            driven,
            participant: Some(dp),
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

    /// Waits (at most the connect timeout) for a reader to be matched to `dest`'s writer, and
    /// (at most [`ANSWER_WAIT`] more) for a writer of that reader's participant on this
    /// link's own topic to be discovered: the destination answers on it (acknowledgements),
    /// and an answer from a writer this link's reader has not matched yet would wait for
    /// DDS's repair, past the first retransmission.
    fn wait_matched(&self, to: SystemId, dest: &Dest) -> Result<(), LinkError> {
        let deadline = Instant::now() + self.connect_timeout;
        let mut pause = Duration::from_micros(200);
        loop {
            let writer = dest.writer.lock();
            let matched = dest.refresh(&writer, &self.shared.events);
            drop(writer);
            if matched > 0 && self.answers_matched(dest) {
                return Ok(());
            }
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

    /// Whether a participant with a reader matched to `dest`'s writer has a writer on this
    /// link's own topic that discovery knows, or the first such reader matched
    /// [`ANSWER_WAIT`] ago.
    fn answers_matched(&self, dest: &Dest) -> bool {
        let readers = dest.readers.lock();
        if readers.values().any(|at| at.elapsed() >= ANSWER_WAIT) {
            return true;
        }
        let Some(dp) = &self.participant else {
            return true;
        };
        dp.discovered_writers().iter().any(|w| {
            let t = &w.publication_topic_data;
            t.topic_name == self.own_dds_topic
                && readers
                    .keys()
                    .any(|r| r.prefix == w.writer_proxy.remote_writer_guid.prefix)
        })
    }
}

/// The receive side: the reader, registered with its own `mio` poll (with the writers'
/// status), and the destinations, whose presence it reports to the sink.
struct Rx {
    poll: Poll,
    events: Events,
    reader: DataReaderCdr<FrameMessage>,
    sink: Arc<dyn FrameSink>,
    dests: Arc<HashMap<SystemId, Dest>>,
}

impl Rx {
    fn new(
        poll: Poll,
        mut reader: DataReaderCdr<FrameMessage>,
        sink: Arc<dyn FrameSink>,
        dests: Arc<HashMap<SystemId, Dest>>,
    ) -> std::io::Result<Rx> {
        poll.registry()
            .register(&mut reader, Token(0), Interest::READABLE)?;
        Ok(Rx {
            poll,
            events: Events::with_capacity(8),
            reader,
            sink,
            dests,
        })
    }

    /// Applies the writers' status and reports presence changes: a destination is up while a
    /// reader is matched to its writer, down when the last one unmatched (its system closed,
    /// or DDS discovery lost it).
    fn presence(&self, shared: &Shared) {
        for dest in self.dests.values() {
            let writer = dest.writer.lock();
            dest.refresh(&writer, &shared.events);
        }
        let events = std::mem::take(&mut *shared.events.lock());
        for event in events {
            self.sink.on_event(event);
        }
    }

    /// Waits at most `timeout` for a notification, then takes everything there is (the
    /// registration is edge-triggered), in batches; returns the frames handed on.
    fn read(&mut self, timeout: Duration, shared: &Shared) -> usize {
        let _ = self.poll.poll(&mut self.events, Some(timeout));
        self.presence(shared);
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
        let Some(mut rx) = self.rx.try_lock() else {
            return Ok(0);
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
        let writer = dest.writer.lock();
        dest.refresh(&writer, &self.shared.events);
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
        self.driven = None;
        drop(std::mem::take(&mut self.dests));
        if let Some(dp) = self.participant.take() {
            retire(dp);
        }
    }
}

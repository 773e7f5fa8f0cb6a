//! [`Recorder`]: an [`Observer`] that writes every send, retransmission, receipt and outcome
//! of the systems it is attached to into an MCAP file.

use parking_lot::{Condvar, Mutex};
use std::collections::{BTreeMap, HashMap};
use std::fs::File;
use std::io::BufWriter;
use std::path::{Path, PathBuf};
use std::sync::atomic::{AtomicU64, Ordering};
use std::sync::Arc;
use std::thread::JoinHandle;

use hetcomm::config::Fleet;
use hetcomm::observe::{OutcomeRecord, PathChangeRecord, ReceiptRecord, SendRecord};
use hetcomm::{Comm, Observer, ObserverHandle, Time};
use serde_json::Value;

use crate::events::{EventBuilder, Observed};
use crate::format::{self, Event};

/// How payloads (and the records around them) are written.
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq)]
pub enum Encoding {
    /// JSON messages with a JSON Schema per channel (Foxglove and the `mcap` Python package
    /// show the fields without hetcomm). The default.
    #[default]
    Json,
    /// MessagePack maps (MCAP message encoding `msgpack`, no schema) with the payload's own
    /// bytes untouched in `payload_msgpack`: smaller and faster, but readers need to know it.
    MsgPack,
}

impl Encoding {
    /// The MCAP message encoding name.
    pub fn mcap_name(self) -> &'static str {
        match self {
            Encoding::Json => "json",
            Encoding::MsgPack => "msgpack",
        }
    }
}

/// Options of a recording.
#[derive(Clone, Debug)]
pub struct RecordOptions {
    /// Payload encoding.
    pub encoding: Encoding,
    /// The recording's time origin (a replay's time 0), on the recorded systems' clock: the
    /// monotonic clock in real time ([`Time::now_mono`], the default: now), the virtual
    /// clock under simulation (set it to `sim.now()`).
    pub origin: Time,
    /// MCAP chunk size in bytes: a file cut short loses at most the chunk being written.
    pub chunk_size: u64,
}

impl Default for RecordOptions {
    fn default() -> Self {
        RecordOptions {
            encoding: Encoding::Json,
            origin: Time::now_mono(),
            chunk_size: 256 * 1024,
        }
    }
}

/// What a finished recording holds.
#[derive(Clone, Debug, Default, PartialEq, Eq)]
pub struct RecordSummary {
    /// Send attempts written (first attempts and retransmissions).
    pub sends: u64,
    /// Receipts written.
    pub receipts: u64,
    /// Outcomes written.
    pub outcomes: u64,
    /// Path switches written (docs/failover.md).
    pub path_switches: u64,
    /// Messages written on other channels ([`Recorder::write_other`]).
    pub others: u64,
    /// Events that could not be written (the first error is returned by
    /// [`Recorder::finish`]).
    pub lost: u64,
}

/// A channel whose messages another crate encodes, written beside the recorded events (the
/// demo's rover poses as Foxglove well-known schemas, for instance).
#[derive(Clone, Debug, PartialEq, Eq)]
pub struct OtherChannel {
    /// The MCAP topic.
    pub topic: String,
    /// The messages' encoding (`protobuf`, `json`, …).
    pub message_encoding: String,
    /// The schema's name (`foxglove.FrameTransforms`, …).
    pub schema_name: String,
    /// The schema's encoding (`protobuf`, `jsonschema`, …).
    pub schema_encoding: String,
    /// The schema itself (for protobuf, a serialized `FileDescriptorSet`).
    pub schema: Vec<u8>,
}

struct Inner {
    writer: Option<mcap::Writer<BufWriter<File>>>,
    /// topic → channel id.
    channels: HashMap<String, u16>,
    /// (kind, message type) → schema id.
    schemas: HashMap<(&'static str, u32), u16>,
    /// Schema name → schema id, for [`OtherChannel`]s.
    other_schemas: HashMap<String, u16>,
    sequence: u32,
    error: Option<String>,
}

/// Writes what the systems it is attached to send, receive and conclude into an MCAP file.
///
/// ```no_run
/// # fn main() -> Result<(), Box<dyn std::error::Error>> {
/// let fleet = hetcomm::LocalFleet::open_file("fleet.toml")?;
/// let alpha = fleet.system("Alpha")?;
/// let recorder = hetcomm_record::Recorder::create("run.mcap", alpha.fleet(), Default::default())?;
/// let _handle = recorder.attach(&alpha);
/// // … run …
/// let summary = recorder.finish()?;
/// println!("{} sends, {} outcomes", summary.sends, summary.outcomes);
/// # Ok(()) }
/// ```
pub struct Recorder {
    path: PathBuf,
    events: EventBuilder,
    encoding: Encoding,
    inner: Mutex<Inner>,
    /// Observed events on their way to the writer thread.
    queue: Mutex<Queue>,
    /// Signalled when a batch is ready (or the queue closes), and when room is made.
    ready: Condvar,
    room: Condvar,
    thread: Mutex<Option<JoinHandle<()>>>,
    sends: AtomicU64,
    receipts: AtomicU64,
    outcomes: AtomicU64,
    path_switches: AtomicU64,
    others: AtomicU64,
    lost: AtomicU64,
}

impl std::fmt::Debug for Recorder {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        f.debug_struct("Recorder")
            .field("path", &self.path)
            .field("encoding", &self.encoding)
            .finish()
    }
}

/// A recording could not be started or finished.
#[derive(Debug, thiserror::Error)]
#[error("{path}: {message}")]
pub struct RecordError {
    /// The file.
    pub path: PathBuf,
    /// What went wrong.
    pub message: String,
}

impl Recorder {
    /// Creates `path` (replacing it) and writes the recording's header and metadata.
    pub fn create(
        path: impl AsRef<Path>,
        fleet: &Fleet,
        options: RecordOptions,
    ) -> Result<Arc<Recorder>, RecordError> {
        let path = path.as_ref().to_path_buf();
        let err = |m: String| RecordError {
            path: path.clone(),
            message: m,
        };
        let file = File::create(&path).map_err(|e| err(e.to_string()))?;
        let mut writer = mcap::WriteOptions::new()
            .profile(format::PROFILE)
            .library(concat!("hetcomm-record ", env!("CARGO_PKG_VERSION")))
            .compression(None)
            .chunk_size(Some(options.chunk_size))
            .create(BufWriter::with_capacity(1 << 16, file))
            .map_err(|e| err(e.to_string()))?;
        let mut metadata = BTreeMap::new();
        metadata.insert("fleet".to_string(), fleet.name.clone().unwrap_or_default());
        metadata.insert(
            "origin_us".to_string(),
            options.origin.as_micros().to_string(),
        );
        metadata.insert(
            "encoding".to_string(),
            options.encoding.mcap_name().to_string(),
        );
        metadata.insert("format_version".to_string(), "1".to_string());
        writer
            .write_metadata(&mcap::records::Metadata {
                name: format::METADATA_NAME.to_string(),
                metadata,
            })
            .map_err(|e| err(e.to_string()))?;
        let recorder = Arc::new(Recorder {
            queue: Mutex::new(Queue::default()),
            ready: Condvar::new(),
            room: Condvar::new(),
            thread: Mutex::new(None),
            path: path.clone(),
            events: EventBuilder::new(fleet, options.encoding),
            encoding: options.encoding,
            inner: Mutex::new(Inner {
                writer: Some(writer),
                channels: HashMap::new(),
                schemas: HashMap::new(),
                other_schemas: HashMap::new(),
                sequence: 0,
                error: None,
            }),
            sends: AtomicU64::new(0),
            receipts: AtomicU64::new(0),
            outcomes: AtomicU64::new(0),
            path_switches: AtomicU64::new(0),
            others: AtomicU64::new(0),
            lost: AtomicU64::new(0),
        });
        let r = recorder.clone();
        let thread = std::thread::Builder::new()
            .name("hetcomm-record".into())
            .spawn(move || r.drain())
            .map_err(|e| err(e.to_string()))?;
        *recorder.thread.lock() = Some(thread);
        Ok(recorder)
    }

    /// Hands an observed event to the writer thread. Cheap: a lock and a push; the writer is
    /// woken once per [`BATCH`] events (or by its own timer), and the observed thread waits
    /// only while [`QUEUE`] events are queued (nothing is dropped).
    fn enqueue(&self, item: Observed) {
        let mut q = self.queue.lock();
        while q.items.len() >= QUEUE && !q.closed {
            self.room.wait(&mut q);
        }
        if q.closed {
            drop(q);
            self.lost.fetch_add(1, Ordering::Relaxed);
            return;
        }
        q.items.push(item);
        if q.items.len() == BATCH {
            self.ready.notify_one();
        }
    }

    /// The writer thread: takes batches and writes them until the queue is closed and empty.
    fn drain(&self) {
        let mut batch = Vec::new();
        loop {
            {
                let mut q = self.queue.lock();
                while q.items.len() < BATCH && !q.closed {
                    self.ready
                        .wait_for(&mut q, std::time::Duration::from_millis(20));
                    if !q.items.is_empty() {
                        break;
                    }
                }
                if q.items.is_empty() && q.closed {
                    return;
                }
                std::mem::swap(&mut batch, &mut q.items);
                self.room.notify_all();
            }
            for item in batch.drain(..) {
                self.process(item);
            }
        }
    }

    /// Records `comm`'s sends, receipts, outcomes and path switches until the handle is dropped.
    pub fn attach(self: &Arc<Self>, comm: &Comm) -> ObserverHandle {
        comm.observe(Arc::new(SystemRecorder {
            recorder: self.clone(),
            system: comm.name().into(),
        }))
    }

    /// The file being written.
    pub fn path(&self) -> &Path {
        &self.path
    }

    /// Counts so far.
    pub fn summary(&self) -> RecordSummary {
        RecordSummary {
            sends: self.sends.load(Ordering::Relaxed),
            receipts: self.receipts.load(Ordering::Relaxed),
            outcomes: self.outcomes.load(Ordering::Relaxed),
            path_switches: self.path_switches.load(Ordering::Relaxed),
            others: self.others.load(Ordering::Relaxed),
            lost: self.lost.load(Ordering::Relaxed),
        }
    }

    /// Writes one message on `channel` (added to the file on first use), logged at `time` on
    /// the recorded systems' clock, as the recorded events are. Written at once, from the
    /// calling thread; a message that cannot be written is counted as lost.
    pub fn write_other(&self, channel: &OtherChannel, time: Time, data: &[u8]) {
        let log_time = time.as_micros() * 1000;
        let mut inner = self.inner.lock();
        let inner = &mut *inner;
        let Some(writer) = inner.writer.as_mut() else {
            self.lost.fetch_add(1, Ordering::Relaxed);
            return;
        };
        let channel_id = match inner.channels.get(&channel.topic) {
            Some(&c) => Ok(c),
            None => match inner.other_schemas.get(&channel.schema_name) {
                Some(&s) => Ok(s),
                None => writer
                    .add_schema(
                        &channel.schema_name,
                        &channel.schema_encoding,
                        &channel.schema,
                    )
                    .inspect(|&s| {
                        inner.other_schemas.insert(channel.schema_name.clone(), s);
                    }),
            }
            .and_then(|s| {
                writer
                    .add_channel(
                        s,
                        &channel.topic,
                        &channel.message_encoding,
                        &BTreeMap::new(),
                    )
                    .inspect(|&c| {
                        inner.channels.insert(channel.topic.clone(), c);
                    })
            }),
        };
        self.log(inner, channel_id, log_time, data, &self.others);
    }

    /// Counts a message its writer could not encode for [`Recorder::write_other`] as lost.
    pub fn count_lost(&self) {
        self.lost.fetch_add(1, Ordering::Relaxed);
    }

    /// Writes the summary and index and closes the file. Events after this are counted as
    /// lost. An error says what failed first (a full disk, …) and how many events were lost.
    pub fn finish(&self) -> Result<RecordSummary, RecordError> {
        // Close the queue, let the writer thread write what is in it, and end.
        self.queue.lock().closed = true;
        self.ready.notify_all();
        self.room.notify_all();
        let thread = self.thread.lock().take();
        if let Some(t) = thread {
            if t.join().is_err() {
                self.fail("the writer thread panicked".into());
            }
        }
        let mut inner = self.inner.lock();
        if let Some(mut w) = inner.writer.take() {
            if let Err(e) = w.finish() {
                inner.error.get_or_insert(e.to_string());
            }
        }
        let summary = self.summary();
        match inner.error.clone() {
            Some(message) => Err(RecordError {
                path: self.path.clone(),
                message: format!("{message} ({} events not recorded)", summary.lost),
            }),
            None => Ok(summary),
        }
    }

    /// Encodes and writes one event on `topic`.
    fn write(&self, topic: String, kind: &'static str, event: &Event, payload: &[u8]) {
        let (data, sample) = match self.encoding {
            Encoding::Json => match serde_json::to_vec(event) {
                Ok(d) => (d, event_payload(event)),
                Err(e) => return self.fail(e.to_string()),
            },
            Encoding::MsgPack => match to_msgpack(event, payload, kind) {
                Ok(d) => (d, None),
                Err(e) => return self.fail(e),
            },
        };
        let message_type = match event {
            Event::Send(s) => s.message.message_type,
            Event::Receipt(r) => r.message.message_type,
            Event::Outcome(_) | Event::PathSwitch(_) => 0,
        };
        let time = event.time_us() * 1000;
        let mut inner = self.inner.lock();
        let inner = &mut *inner;
        let Some(writer) = inner.writer.as_mut() else {
            self.lost.fetch_add(1, Ordering::Relaxed);
            return;
        };
        let channel = match inner.channels.get(&topic) {
            Some(&c) => Ok(c),
            None => {
                let schema = match self.encoding {
                    Encoding::MsgPack => Ok(0),
                    Encoding::Json => match inner.schemas.get(&(kind, message_type)) {
                        Some(&s) => Ok(s),
                        None => {
                            let (name, schema) = if kind == "outcome" {
                                ("hetcomm.Outcome".to_string(), format::outcome_schema())
                            } else if kind == "path_switch" {
                                (
                                    "hetcomm.PathSwitch".to_string(),
                                    format::path_switch_schema(),
                                )
                            } else {
                                (
                                    format!(
                                        "hetcomm.{}.type{message_type}",
                                        if kind == "send" { "Send" } else { "Receipt" }
                                    ),
                                    format::message_schema(kind, message_type, sample.as_ref()),
                                )
                            };
                            let text = serde_json::to_vec(&schema).unwrap_or_default();
                            writer.add_schema(&name, "jsonschema", &text).inspect(|&s| {
                                inner.schemas.insert((kind, message_type), s);
                            })
                        }
                    },
                };
                schema.and_then(|s| {
                    writer
                        .add_channel(s, &topic, self.encoding.mcap_name(), &BTreeMap::new())
                        .inspect(|&c| {
                            inner.channels.insert(topic.clone(), c);
                        })
                })
            }
        };
        let counter = match kind {
            "send" => &self.sends,
            "receipt" => &self.receipts,
            "path_switch" => &self.path_switches,
            _ => &self.outcomes,
        };
        self.log(inner, channel, time, &data, counter);
    }

    /// Writes `data` on the channel `channel` names (or records why there is none), and counts
    /// it in `counter`, or as lost.
    fn log(
        &self,
        inner: &mut Inner,
        channel: Result<u16, mcap::McapError>,
        log_time: u64,
        data: &[u8],
        counter: &AtomicU64,
    ) {
        let Some(writer) = inner.writer.as_mut() else {
            self.lost.fetch_add(1, Ordering::Relaxed);
            return;
        };
        let result = channel.and_then(|channel_id| {
            inner.sequence = inner.sequence.wrapping_add(1);
            writer.write_to_known_channel(
                &mcap::records::MessageHeader {
                    channel_id,
                    sequence: inner.sequence,
                    log_time,
                    publish_time: log_time,
                },
                data,
            )
        });
        match result {
            Ok(()) => {
                counter.fetch_add(1, Ordering::Relaxed);
            }
            Err(e) => {
                self.lost.fetch_add(1, Ordering::Relaxed);
                inner.error.get_or_insert(e.to_string());
            }
        }
    }

    fn fail(&self, message: String) {
        self.lost.fetch_add(1, Ordering::Relaxed);
        let mut inner = self.inner.lock();
        inner.error.get_or_insert(message);
    }
}

fn event_payload(event: &Event) -> Option<Value> {
    match event {
        Event::Send(s) => s.message.payload_value(),
        Event::Receipt(r) => r.message.payload_value(),
        Event::Outcome(_) | Event::PathSwitch(_) => None,
    }
}

/// The event as a MessagePack map, the payload's bytes as `payload_msgpack` (binary).
fn to_msgpack(event: &Event, payload: &[u8], kind: &str) -> Result<Vec<u8>, String> {
    let json = serde_json::to_value(event).map_err(|e| e.to_string())?;
    let mut value = format::json_to_msgpack(&json);
    if kind != "outcome" && kind != "path_switch" {
        if let rmpv::Value::Map(m) = &mut value {
            m.push((
                rmpv::Value::from("payload_msgpack"),
                rmpv::Value::Binary(payload.to_vec()),
            ));
        }
    }
    let mut out = Vec::with_capacity(payload.len() + 256);
    rmpv::encode::write_value(&mut out, &value).map_err(|e| e.to_string())?;
    Ok(out)
}

/// Events queued for the writer thread at most; an observer waits while the queue is full.
const QUEUE: usize = 1 << 16;
/// Events that wake the writer thread at once (it also wakes every 20 ms).
const BATCH: usize = 512;

#[derive(Default)]
struct Queue {
    items: Vec<Observed>,
    closed: bool,
}

impl Recorder {
    /// Encodes and writes one event (on the writer thread).
    fn process(&self, item: Observed) {
        let event = self.events.event(&item);
        let (topic, kind) = match &event {
            Event::Send(e) => (
                format!(
                    "/send/{}/{}/{}/{}",
                    e.message.source.system,
                    e.message.source.module,
                    e.message.destination.system,
                    e.message.destination.module
                ),
                "send",
            ),
            Event::Receipt(e) => (
                format!(
                    "/receipt/{}/{}",
                    e.message.destination.system, e.message.destination.module
                ),
                "receipt",
            ),
            Event::Outcome(e) => (
                format!("/outcome/{}/{}", e.source_system, e.destination_system),
                "outcome",
            ),
            Event::PathSwitch(e) => (
                format!("/path_switch/{}/{}", e.source_system, e.destination_system),
                "path_switch",
            ),
        };
        self.write(topic, kind, &event, item.payload());
    }
}

/// The recorder as seen by one system: copies each event and queues it for the writer
/// thread, so the observed thread only pays for a copy.
struct SystemRecorder {
    recorder: Arc<Recorder>,
    system: Arc<str>,
}

impl Observer for SystemRecorder {
    fn on_send(&self, record: &SendRecord<'_>) {
        self.recorder.enqueue(Observed::send(record));
    }
    fn on_retransmit(&self, record: &SendRecord<'_>) {
        self.recorder.enqueue(Observed::send(record));
    }
    fn on_receipt(&self, record: &ReceiptRecord<'_>) {
        self.recorder.enqueue(Observed::receipt(record));
    }
    fn on_outcome(&self, record: &OutcomeRecord<'_>) {
        self.recorder
            .enqueue(Observed::outcome(&self.system, record));
    }
    fn on_path_change(&self, record: &PathChangeRecord<'_>) {
        self.recorder
            .enqueue(Observed::path_switch(&self.system, record));
    }
}

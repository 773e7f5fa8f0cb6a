//! Reading a recording back: every event that can be read, and what stopped the reading when
//! the file is cut short or damaged (never a panic).

use std::collections::BTreeMap;
use std::path::{Path, PathBuf};

use base64::Engine as _;

use crate::format::{self, Event};

/// A recording could not be read at all (no such file, not an MCAP file).
#[derive(Debug, thiserror::Error)]
#[error("{path}: {message}")]
pub struct ReadError {
    /// The file.
    pub path: PathBuf,
    /// What went wrong.
    pub message: String,
}

/// What reading a recording found.
#[derive(Clone, Debug, Default)]
pub struct ReadReport {
    /// The recording's metadata (`fleet`, `origin_us`, `encoding`, …); empty when it could not
    /// be read.
    pub metadata: BTreeMap<String, String>,
    /// Events read (handed to the callback).
    pub events: u64,
    /// Messages on channels other than the events' (`/send/…`, `/receipt/…`, `/outcome/…`):
    /// written beside them, e.g. the demo's rover poses for Foxglove; not read.
    pub others: u64,
    /// Messages on the events' channels that did not decode (the first reason is in
    /// `skipped_reason`).
    pub skipped: u64,
    /// Why the first skipped message did not decode.
    pub skipped_reason: Option<String>,
    /// Why reading stopped before the end of a complete file (truncated, corrupt): everything
    /// before it was read.
    pub problem: Option<String>,
}

impl ReadReport {
    /// The recording's time origin, microseconds (replays count from it); None when the
    /// metadata is missing.
    pub fn origin_us(&self) -> Option<u64> {
        self.metadata.get("origin_us")?.parse().ok()
    }

    /// One line for a person: events read, and what stopped the reading.
    pub fn describe(&self) -> String {
        let mut s = format!("{} events read", self.events);
        if self.others > 0 {
            s += &format!(", {} messages on other channels left aside", self.others);
        }
        if self.skipped > 0 {
            s += &format!(
                ", {} messages skipped ({})",
                self.skipped,
                self.skipped_reason
                    .as_deref()
                    .unwrap_or("not hetcomm events")
            );
        }
        if let Some(p) = &self.problem {
            s +=
                &format!("; the file is damaged or cut short: {p} (everything before it was read)");
        }
        s
    }
}

/// Reads `path` and hands each event to `f`, in file order. A damaged or truncated file ends
/// the reading with [`ReadReport::problem`] set, after every event before the damage.
pub fn read_with(path: impl AsRef<Path>, f: impl FnMut(Event)) -> Result<ReadReport, ReadError> {
    let path = path.as_ref();
    let bytes = std::fs::read(path).map_err(|e| ReadError {
        path: path.to_path_buf(),
        message: e.to_string(),
    })?;
    read_bytes(&bytes, f).map_err(|message| ReadError {
        path: path.to_path_buf(),
        message,
    })
}

/// Reads every event of `path` into memory.
pub fn read(path: impl AsRef<Path>) -> Result<(Vec<Event>, ReadReport), ReadError> {
    let mut events = Vec::new();
    let report = read_with(path, |e| events.push(e))?;
    Ok((events, report))
}

/// [`read_with`] on bytes in memory. Err only when they are not an MCAP file at all.
pub fn read_bytes(bytes: &[u8], mut f: impl FnMut(Event)) -> Result<ReadReport, String> {
    read_bytes_timed(bytes, |_, e| f(e))
}

/// [`read_with`], handing each event with the recording's time origin in microseconds (the
/// metadata's `origin_us`, or the first event's time when the metadata is missing).
pub fn read_timed(
    path: impl AsRef<Path>,
    f: impl FnMut(u64, Event),
) -> Result<ReadReport, ReadError> {
    let path = path.as_ref();
    let bytes = std::fs::read(path).map_err(|e| ReadError {
        path: path.to_path_buf(),
        message: e.to_string(),
    })?;
    read_bytes_timed(&bytes, f).map_err(|message| ReadError {
        path: path.to_path_buf(),
        message,
    })
}

fn read_bytes_timed(bytes: &[u8], mut f: impl FnMut(u64, Event)) -> Result<ReadReport, String> {
    if bytes.len() < mcap::MAGIC.len() || &bytes[..mcap::MAGIC.len()] != mcap::MAGIC {
        return Err("not an MCAP file (no MCAP magic at the start)".into());
    }
    let mut report = ReadReport {
        metadata: metadata(bytes),
        ..ReadReport::default()
    };
    let mut origin = report.origin_us();
    let stream = match mcap::MessageStream::new(bytes) {
        Ok(s) => s,
        Err(e) => {
            report.problem = Some(e.to_string());
            return Ok(report);
        }
    };
    let mut stream = stream;
    while let Some(message) = next_guarded(&mut stream) {
        let message = match message {
            Ok(Ok(m)) => m,
            Ok(Err(e)) => {
                report.problem = Some(e.to_string());
                break;
            }
            Err(panicked) => {
                report.problem = Some(panicked);
                break;
            }
        };
        if !format::is_event_topic(&message.channel.topic) {
            report.others += 1;
            continue;
        }
        match decode(&message.channel.message_encoding, &message.data) {
            Ok(event) => {
                report.events += 1;
                let o = *origin.get_or_insert(event.time_us());
                f(o, event);
            }
            Err(reason) => {
                report.skipped += 1;
                report
                    .skipped_reason
                    .get_or_insert(format!("{}: {reason}", message.channel.topic));
            }
        }
    }
    Ok(report)
}

/// The `hetcomm` metadata record, read from the records before the first chunk (where the
/// recorder writes it).
fn metadata(bytes: &[u8]) -> BTreeMap<String, String> {
    let Ok(reader) = mcap::read::LinearReader::new_with_options(
        bytes,
        enumset::enum_set!(mcap::read::Options::IgnoreEndMagic),
    ) else {
        return BTreeMap::new();
    };
    let mut reader = reader;
    while let Some(record) = next_guarded(&mut reader) {
        match record {
            Ok(Ok(mcap::records::Record::Metadata(m))) if m.name == format::METADATA_NAME => {
                return m.metadata
            }
            Ok(Ok(mcap::records::Record::Chunk { .. }))
            | Ok(Ok(mcap::records::Record::Message { .. }))
            | Ok(Err(_))
            | Err(_) => break,
            Ok(Ok(_)) => {}
        }
    }
    BTreeMap::new()
}

/// The reader's next item, or `Err` if the MCAP reader panicked: some damaged lengths make
/// the `mcap` crate's arithmetic overflow (a panic in debug builds), and a damaged file must
/// be reported as damaged, not bring the program down.
fn next_guarded<I: Iterator>(it: &mut I) -> Option<Result<I::Item, String>> {
    match std::panic::catch_unwind(std::panic::AssertUnwindSafe(|| it.next())) {
        Ok(item) => item.map(Ok),
        Err(_) => Some(Err("the MCAP reader failed on damaged bytes".to_string())),
    }
}

/// One MCAP message as an event.
pub fn decode(encoding: &str, data: &[u8]) -> Result<Event, String> {
    match encoding {
        "json" => serde_json::from_slice(data).map_err(|e| e.to_string()),
        "msgpack" => {
            let mut cursor = std::io::Cursor::new(data);
            let value = rmpv::decode::read_value(&mut cursor).map_err(|e| e.to_string())?;
            let rmpv::Value::Map(mut map) = value else {
                return Err("not a MessagePack map".into());
            };
            let mut payload = None;
            map.retain(|(k, v)| {
                if k.as_str() == Some("payload_msgpack") {
                    payload = v.as_slice().map(<[u8]>::to_vec);
                    false
                } else {
                    true
                }
            });
            let json = format::msgpack_to_json(&rmpv::Value::Map(map));
            let mut event: Event = serde_json::from_value(json).map_err(|e| e.to_string())?;
            if let Some(p) = payload {
                let env = match &mut event {
                    Event::Send(s) => Some(&mut s.message),
                    Event::Receipt(r) => Some(&mut r.message),
                    Event::Outcome(_) | Event::PathSwitch(_) => None,
                };
                if let Some(env) = env {
                    env.payload = format::payload_json(&p).0;
                    env.payload_b64 = Some(base64::engine::general_purpose::STANDARD.encode(&p));
                }
            }
            Ok(event)
        }
        other => Err(format!(
            "message encoding {other:?} is not a hetcomm recording's"
        )),
    }
}

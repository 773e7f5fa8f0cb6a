//! Record and replay for hetcomm (MCAP), and the statistics the live monitor shows.
//!
//! - [`Recorder`]: an observer ([`hetcomm::Observer`]) writing every send (envelope, payload,
//!   each attempt), every receipt and every send's outcome of the systems it is attached to
//!   into an MCAP file. Payloads are JSON with a JSON Schema per message type by default, so
//!   any MCAP reader (Foxglove, the `mcap` Python package) shows their fields;
//!   [`Encoding::MsgPack`] keeps the raw MessagePack instead. [`format`] documents the
//!   topics and fields.
//! - [`events`]: what an observer sees, named by the fleet, as the recording's events (the
//!   recorder and the live Foxglove view share it).
//! - [`reader`]: reads a recording back, reporting what stopped the reading of a damaged or
//!   truncated file after every event before the damage (never a panic).
//! - [`replay`]: sends the recorded sends again, from the same systems and modules, with the
//!   recorded timing (or scaled), into a simulation or live systems.
//! - [`stats`]: per-pair counters (an observer) and the periodic reports a live monitor
//!   (`hetcomm monitor`) receives from other processes.
//!
//! `docs/record-replay.md` is the user's guide.

pub mod events;
pub mod format;
pub mod reader;
pub mod replay;
pub mod stats;
mod writer;

pub use format::Event;
pub use reader::{read, read_with, ReadError, ReadReport};
pub use replay::{Player, ReplayFilter, ReplayItem, ReplayReport, ReplayStats};
pub use writer::{Encoding, OtherChannel, RecordError, RecordOptions, RecordSummary, Recorder};

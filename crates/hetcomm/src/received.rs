//! What a receiver gets: the message and its envelope.

use hetcomm_core::{Address, Header, MessageId, MessageType, PayloadBuf, Priority, Time};

/// The envelope of a received message, with friendly names resolved.
#[derive(Clone, Debug)]
pub struct Envelope {
    /// The raw header as it came off the wire.
    pub header: Header,
    /// The sending system's friendly name.
    pub source_system: &'static str,
    /// The sending module's name.
    pub source_module: &'static str,
    /// When this system's router put it into the inbox: the receiver's wall clock, µs since
    /// the UNIX epoch (virtual time under simulation), so that `received_at - timestamp` is
    /// the one-way latency when the two hosts' clocks agree. Not for timing on this host:
    /// the wall clock may be stepped.
    pub received_at: Time,
}

impl Envelope {
    /// (source system, source module) ids.
    pub fn source(&self) -> Address {
        self.header.source
    }
    /// The message id: (origin system, sequence).
    pub fn id(&self) -> MessageId {
        self.header.message_id()
    }
    /// The message type.
    pub fn message_type(&self) -> MessageType {
        self.header.message_type
    }
    /// The priority.
    pub fn priority(&self) -> Priority {
        self.header.priority
    }
    /// When the sender created it: the sender's wall clock, µs since the UNIX epoch (virtual
    /// time under simulation).
    pub fn timestamp(&self) -> Time {
        self.header.timestamp
    }
    /// Whether it was one copy of a broadcast.
    pub fn is_broadcast(&self) -> bool {
        self.header.is_broadcast()
    }
}

/// A typed message with its envelope.
#[derive(Clone, Debug)]
pub struct Received<M> {
    /// The message.
    pub message: M,
    /// Where it came from, when, at which priority.
    pub envelope: Envelope,
}

/// An undecoded message with its envelope (for tools and other-language bindings).
#[derive(Clone, Debug)]
pub struct RawMessage {
    /// Where it came from, when, at which priority.
    pub envelope: Envelope,
    /// The encoded payload (see `docs/wire-format.md`): reads as a `[u8]`; small payloads
    /// are stored inline, `into_vec` gives a `Vec<u8>`.
    pub payload: PayloadBuf,
}

//! Errors, one enum per operation.

use std::time::Duration;

use hetcomm_config::{ConfigErrors, TransportKind};
use hetcomm_core::payload::PayloadError;
use hetcomm_core::{MessageType, TypeRegistryError};

/// Opening a fleet or a system failed.
#[derive(Debug, thiserror::Error)]
#[non_exhaustive]
pub enum OpenError {
    /// The fleet file is invalid (each error names file:line:column).
    #[error("{0}")]
    Config(#[from] ConfigErrors),
    /// No system of that name in the fleet.
    #[error("no system named `{name}` in the fleet (systems: {known})")]
    UnknownSystem {
        /// The name asked for.
        name: String,
        /// The fleet's systems, comma-separated.
        known: String,
    },
    /// No module of that name in the fleet.
    #[error("no module named `{name}` in the fleet (modules: {known})")]
    UnknownModule {
        /// The name asked for.
        name: String,
        /// The fleet's modules, comma-separated.
        known: String,
    },
    /// The transport's kind is not built into this program.
    #[error("transport `{transport}` is of kind `{kind}`, which is not available yet in this build: {hint}")]
    KindUnavailable {
        /// The transport instance's name.
        transport: String,
        /// Its kind.
        kind: TransportKind,
        /// What to do instead.
        hint: String,
    },
    /// The transport could not be opened.
    #[error("cannot open transport `{transport}` for system `{system}`: {reason}")]
    Transport {
        /// The transport instance's name.
        transport: String,
        /// The system being opened.
        system: String,
        /// What went wrong.
        reason: String,
        /// The error underneath (a link's, the operating system's), when there is one.
        #[source]
        source: Option<Box<dyn std::error::Error + Send + Sync + 'static>>,
    },
}

impl OpenError {
    /// Opening `transport` for `system` failed with `error`, kept as the source.
    pub(crate) fn transport(
        transport: &str,
        system: &str,
        error: impl Into<Box<dyn std::error::Error + Send + Sync + 'static>>,
    ) -> OpenError {
        let error = error.into();
        OpenError::Transport {
            transport: transport.to_string(),
            system: system.to_string(),
            reason: error.to_string(),
            source: Some(error),
        }
    }
}

/// A send was refused before any transmission.
#[derive(Debug, thiserror::Error)]
#[non_exhaustive]
pub enum SendError {
    /// No system of that name.
    #[error("no system named `{0}` in the fleet")]
    UnknownSystem(String),
    /// No module of that name.
    #[error("no module named `{0}` in the fleet")]
    UnknownModule(String),
    /// The communication table says `X` for this pair.
    #[error(
        "no traffic allowed from `{from}` to `{to}`: the communication table says X for this pair"
    )]
    NoRoute {
        /// Sending system.
        from: String,
        /// Destination system.
        to: String,
    },
    /// The message is larger than the transport takes.
    #[error("message to `{to}` is {len} bytes with its header, over the transport's limit of {max} bytes")]
    TooLarge {
        /// Destination system.
        to: String,
        /// Frame length.
        len: usize,
        /// The limit.
        max: usize,
    },
    /// The transport's `max_in_flight` sends (or `max_in_flight_bytes` of frames) to that
    /// system already await their outcome (acknowledgements not yet back, or retries after the
    /// link refused frames). Nothing was
    /// sent. Wait for an earlier send's outcome ([`crate::Ticket::wait`]) and send again.
    #[error("sends to `{to}` awaiting their outcome fill the transport's window (max_in_flight = {limit} sends, or max_in_flight_bytes): nothing was sent; wait for an earlier outcome and send again")]
    Backpressure {
        /// Destination system.
        to: String,
        /// The transport's `max_in_flight`.
        limit: u32,
    },
    /// The message could not be encoded.
    #[error(transparent)]
    Encode(#[from] PayloadError),
    /// The message type's id is taken by another type.
    #[error(transparent)]
    TypeConflict(#[from] TypeRegistryError),
    /// The system was closed.
    #[error("the system is closed")]
    Closed,
}

/// Taking a message out of an inbox failed.
#[derive(Debug, thiserror::Error)]
#[non_exhaustive]
pub enum RecvError {
    /// The next message is of another type; it stays in the inbox.
    #[error("next message is of type {found} ({found_name}), not {expected} ({expected_name}); it stays in the inbox")]
    WrongType {
        /// The type asked for.
        expected: MessageType,
        /// Its name.
        expected_name: &'static str,
        /// The type found.
        found: MessageType,
        /// Its name, if registered, else "unregistered".
        found_name: String,
    },
    /// The payload did not decode as the expected type (the message is consumed: it can never
    /// decode).
    #[error(transparent)]
    Decode(#[from] PayloadError),
    /// No message arrived in time.
    #[error("no message within {0:?}")]
    Timeout(Duration),
    /// The system was closed and the inbox is empty.
    #[error("the system is closed")]
    Closed,
    /// The message type's id is taken by another type.
    #[error(transparent)]
    TypeConflict(#[from] TypeRegistryError),
}

//! # hetcomm-core — the bottom layer
//!
//! Plain data shared by every other hetcomm crate: newtype ids ([`SystemId`], [`ModuleId`],
//! [`MessageType`], [`Priority`]), the envelope [`Header`] and its byte-exact wire codec
//! ([`wire`]), the language-neutral payload encoding ([`payload`]), the [`Message`] trait that
//! user types implement (by derive, through the `hetcomm` facade), and the virtual-or-real
//! [`Time`] the router is driven with.
//!
//! This crate does no I/O, reads no clock and starts no thread.
//!
//! ```
//! use hetcomm_core::{wire, Header, FrameKind, SystemId, ModuleId, MessageType, Priority, Time};
//! let header = Header::data(
//!     (SystemId(1), ModuleId(2)).into(),
//!     (SystemId(3), ModuleId(4)).into(),
//!     MessageType(7),
//! );
//! let frame = wire::encode(&header, b"hello");
//! let decoded = wire::decode(&frame).unwrap();
//! assert_eq!(decoded.header.kind, FrameKind::Data);
//! assert_eq!(decoded.payload, b"hello");
//! # let _ = (Priority::NORMAL, Time::ZERO);
//! ```

pub mod buf;
pub mod ids;
pub mod message;
pub mod payload;
pub mod pool;
pub mod time;
pub mod wire;

pub use buf::{PayloadBuf, PayloadSource, INLINE_PAYLOAD};
pub use ids::{Address, MessageId, MessageType, ModuleId, Priority, SystemId};
pub use message::{Message, TypeInfo, TypeRegistry, TypeRegistryError};
pub use pool::{BufferPool, FrameBuf};
pub use time::Time;
pub use wire::{AckStatus, DecodeError, Frame, FrameKind, Header};

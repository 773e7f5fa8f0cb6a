//! The Test Harness: taps on the paths between modules, and fault and injection schedules.
//!
//! The thesis's framework puts a *Test Harness* between the autonomy modules and the rest of
//! the framework (its §2.4), so that data can be observed, injected, replaced or manipulated
//! before and after each module. Here a **tap** sits on a **path** ([`TapPath`]):
//!
//! - a topic inside one system ([`TapPath::topic`]): every value a node publishes on it;
//! - messages between systems ([`TapPath::messages`]): those arriving at a destination system,
//!   optionally narrowed to one source system, one destination module and one message type.
//!
//! A tap's [`TapAction`] observes, drops, delays, duplicates, modifies (a user function), or
//! replaces the path's source ([`Comm::replace`]: the real messages are dropped and the
//! [`Replacement`] supplies others — a virtual environment, a recording, a script). Taps act
//! where a message enters its destination (the module's inbox or callback, a topic's
//! subscribers), so they act identically whichever transport carried the message, in real
//! time and under the simulator ([`crate::sim`]), and the receiving module sees a message the
//! same way with or without a tap.
//!
//! What the sender sees: a tap acts inside the receiving system, after the transport delivered
//! the message, so an acknowledged send is `Delivered` even when a tap drops or delays it (the
//! system did receive it). Every such action is counted in [`HarnessStats`]. To make a send
//! *fail*, schedule a network fault instead ([`scenario`]: partitions, silence, loss),
//! which acts on frames before they leave and so shows in outcomes and retransmissions.
//!
//! Cost: a system with no message tap checks one atomic at each delivery; one with taps
//! checks a filter word per tap (source, module, type), so a path no tap can take never reads
//! the list of taps. A system with no topic tap checks one atomic at each publish. An
//! observe-only tap costs a path match, a counter and the function call per message
//! (`hetcomm-bench --only harness`; docs/harness.md has the figures).

mod engine;
pub(crate) mod faults;
pub mod scenario;

use std::any::Any;
use std::sync::{Arc, Weak};
use std::time::Duration;

use hetcomm_core::{payload, Header, Message, MessageType, PayloadBuf, SystemId, Time};

use crate::comm::Comm;
use crate::runtime::SystemCore;

pub(crate) use engine::{Held, SystemHarness};

/// A value carried on a topic: shared, never copied or serialized between nodes of a process.
pub type TopicValue = Arc<dyn Any + Send + Sync>;

/// A path a tap sits on. Build one with [`TapPath::topic`] or [`TapPath::messages`].
#[derive(Clone, Debug, PartialEq, Eq, Hash)]
#[non_exhaustive]
pub enum TapPath {
    /// Values published on `topic` inside `system`.
    Topic {
        /// The system whose nodes publish and subscribe.
        system: String,
        /// The topic's name.
        topic: String,
    },
    /// Messages arriving at `to` (from another system, or from this one's own modules).
    Messages {
        /// Only messages from this source system (None: any).
        from: Option<String>,
        /// The destination system, where the tap acts.
        to: String,
        /// Only messages for this destination module (None: any).
        module: Option<String>,
        /// Only messages of this type (None: any).
        message_type: Option<MessageType>,
    },
}

impl TapPath {
    /// The topic `topic` of `system`.
    pub fn topic(system: &str, topic: &str) -> TapPath {
        TapPath::Topic {
            system: system.to_string(),
            topic: topic.to_string(),
        }
    }

    /// Every message arriving at system `to`; narrow it with [`TapPath::from`],
    /// [`TapPath::module`] and [`TapPath::message_type`].
    pub fn messages(to: &str) -> TapPath {
        TapPath::Messages {
            from: None,
            to: to.to_string(),
            module: None,
            message_type: None,
        }
    }

    /// Only messages from system `system` (message paths; a topic path is returned unchanged).
    pub fn from(mut self, system: &str) -> TapPath {
        if let TapPath::Messages { from, .. } = &mut self {
            *from = Some(system.to_string());
        }
        self
    }

    /// Only messages for module `name` (message paths).
    pub fn module(mut self, name: &str) -> TapPath {
        if let TapPath::Messages { module, .. } = &mut self {
            *module = Some(name.to_string());
        }
        self
    }

    /// Only messages of type `ty` (message paths).
    pub fn message_type(mut self, ty: MessageType) -> TapPath {
        if let TapPath::Messages { message_type, .. } = &mut self {
            *message_type = Some(ty);
        }
        self
    }

    /// The system where a tap on this path acts.
    pub fn system(&self) -> &str {
        match self {
            TapPath::Topic { system, .. } => system,
            TapPath::Messages { to, .. } => to,
        }
    }
}

impl std::fmt::Display for TapPath {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        match self {
            TapPath::Topic { system, topic } => write!(f, "topic {system}/{topic}"),
            TapPath::Messages {
                from,
                to,
                module,
                message_type,
            } => {
                write!(f, "{} -> {to}", from.as_deref().unwrap_or("*"))?;
                write!(f, ".{}", module.as_deref().unwrap_or("*"))?;
                match message_type {
                    Some(t) => write!(f, " type {}", t.0),
                    None => write!(f, " type *"),
                }
            }
        }
    }
}

/// What a tap decided for one message.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
#[non_exhaustive]
pub enum TapVerdict {
    /// Deliver it (as it is now, after any modification).
    Pass,
    /// Discard it (counted in [`HarnessStats::dropped`]).
    Drop,
    /// Deliver it this much later (on the system's clock: virtual time under simulation).
    Delay(Duration),
    /// Deliver it and this many extra copies.
    Duplicate(u32),
}

/// A user function that may inspect and change a message and decides what happens to it.
pub type TapFn = Arc<dyn Fn(&mut TapMessage) -> TapVerdict + Send + Sync>;

/// A user function that sees a message and changes nothing.
pub type ObserveFn = Arc<dyn Fn(&TapMessage) + Send + Sync>;

/// What a tap does with each message on its path.
#[derive(Clone)]
#[non_exhaustive]
pub enum TapAction {
    /// Calls the function with each message; changes nothing.
    Observe(ObserveFn),
    /// Discards every message.
    Drop,
    /// Delivers every message this much later.
    Delay(Duration),
    /// Delivers every message and this many extra copies.
    Duplicate(u32),
    /// Calls the function, which may change the message (payload or topic value) and decides
    /// its fate.
    Modify(TapFn),
    /// Discards the real messages: another source supplies the path ([`Comm::replace`]).
    Replace,
}

impl TapAction {
    /// [`TapAction::Observe`] from a closure.
    pub fn observe(f: impl Fn(&TapMessage) + Send + Sync + 'static) -> TapAction {
        TapAction::Observe(Arc::new(f))
    }

    /// [`TapAction::Modify`] from a closure.
    pub fn modify(f: impl Fn(&mut TapMessage) -> TapVerdict + Send + Sync + 'static) -> TapAction {
        TapAction::Modify(Arc::new(f))
    }

    pub(crate) fn kind(&self) -> &'static str {
        match self {
            TapAction::Observe(_) => "observe",
            TapAction::Drop => "drop",
            TapAction::Delay(_) => "delay",
            TapAction::Duplicate(_) => "duplicate",
            TapAction::Modify(_) => "modify",
            TapAction::Replace => "replace",
        }
    }
}

impl std::fmt::Debug for TapAction {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        match self {
            TapAction::Delay(d) => write!(f, "Delay({d:?})"),
            TapAction::Duplicate(n) => write!(f, "Duplicate({n})"),
            other => f.write_str(other.kind()),
        }
    }
}

/// The body of a message on a tapped path: encoded bytes between systems, a shared value on
/// a topic.
#[derive(Clone)]
pub(crate) enum Body {
    Bytes(PayloadBuf),
    Value(TopicValue),
}

/// One message on a tapped path, as a tap sees it.
#[derive(Clone)]
pub struct TapMessage {
    pub(crate) header: Option<Header>,
    pub(crate) topic: Option<Arc<str>>,
    pub(crate) time: Time,
    pub(crate) body: Body,
    pub(crate) modified: bool,
}

impl TapMessage {
    /// The message's header (source, destination, type, sequence number, sender's timestamp);
    /// None for a topic value, which has no header.
    pub fn header(&self) -> Option<&Header> {
        self.header.as_ref()
    }

    /// The topic's name, for a topic value.
    pub fn topic(&self) -> Option<&str> {
        self.topic.as_deref()
    }

    /// When the message reached the tap, on the system's clock (virtual under simulation).
    pub fn time(&self) -> Time {
        self.time
    }

    /// The encoded payload of a message between systems (None for a topic value).
    pub fn payload(&self) -> Option<&[u8]> {
        match &self.body {
            Body::Bytes(b) => Some(b),
            Body::Value(_) => None,
        }
    }

    /// Replaces the encoded payload (a message between systems; a topic value becomes these
    /// bytes only if its subscribers take bytes, so prefer [`TapMessage::set_value`] there).
    pub fn set_payload(&mut self, bytes: Vec<u8>) {
        self.body = Body::Bytes(PayloadBuf::from_vec(bytes));
        self.modified = true;
    }

    /// Decodes the payload of a message between systems as an `M` (None for a topic value,
    /// which is not encoded: see [`TapMessage::value`]).
    pub fn decode<M: Message>(&self) -> Option<Result<M, payload::PayloadError>> {
        match &self.body {
            Body::Bytes(b) => Some(payload::decode(b)),
            Body::Value(_) => None,
        }
    }

    /// Encodes `msg` as the new payload of a message between systems.
    pub fn encode<M: Message>(&mut self, msg: &M) -> Result<(), payload::PayloadError> {
        self.set_payload(payload::encode(msg)?);
        Ok(())
    }

    /// The topic value, if it is a `T`.
    pub fn value<T: Any>(&self) -> Option<&T> {
        match &self.body {
            Body::Value(v) => v.downcast_ref::<T>(),
            Body::Bytes(_) => None,
        }
    }

    /// Replaces the topic value (subscribers of the topic's type receive it).
    pub fn set_value<T: Any + Send + Sync>(&mut self, value: T) {
        self.body = Body::Value(Arc::new(value));
        self.modified = true;
    }
}

impl std::fmt::Debug for TapMessage {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        f.debug_struct("TapMessage")
            .field("header", &self.header)
            .field("topic", &self.topic)
            .field("time", &self.time)
            .field("payload", &self.payload())
            .finish()
    }
}

/// Why a tap could not be placed.
#[derive(Debug, Clone, PartialEq, Eq, thiserror::Error)]
#[non_exhaustive]
pub enum TapError {
    /// The path names a system that is not in the fleet.
    #[error("tap on {path}: no system `{name}` in the fleet")]
    UnknownSystem {
        /// The path.
        path: String,
        /// The unknown name.
        name: String,
    },
    /// The path names a module that is not in the fleet.
    #[error("tap on {path}: no module `{name}` in the fleet")]
    UnknownModule {
        /// The path.
        path: String,
        /// The unknown name.
        name: String,
    },
    /// The path's destination is another system than the one asked to place the tap.
    #[error("tap on {path}: it acts at system `{path_system}`, not at `{here}` (place it through that system, or through the fleet)")]
    WrongSystem {
        /// The path.
        path: String,
        /// Where the path's tap acts.
        path_system: String,
        /// The system asked.
        here: String,
    },
    /// The communication table forbids the path's pair (`X`): no message can travel it.
    #[error("tap on {path}: the communication table has `X` from {from} to {to}, so no message travels this path")]
    NoSuchPath {
        /// The path.
        path: String,
        /// Source system.
        from: String,
        /// Destination system.
        to: String,
    },
    /// The path's system is not open in this process.
    #[error("tap on {path}: system `{name}` is not open in this process")]
    NotOpen {
        /// The path.
        path: String,
        /// The system.
        name: String,
    },
    /// Another tap already replaces the path's source.
    #[error("tap on {path}: its source is already replaced")]
    AlreadyReplaced {
        /// The path.
        path: String,
    },
}

/// What a system's harness did, counted since the system opened.
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq)]
#[non_exhaustive]
pub struct HarnessStats {
    /// Messages and topic values a tap saw.
    pub tapped: u64,
    /// Discarded by a tap (drop, or a modify function that said so).
    pub dropped: u64,
    /// Held back by a tap and delivered later.
    pub delayed: u64,
    /// Extra copies delivered.
    pub duplicated: u64,
    /// Changed by a modify function.
    pub modified: u64,
    /// Real messages discarded because their path's source is replaced.
    pub replaced: u64,
    /// Messages and values a replacement or a schedule injected.
    pub injected: u64,
    /// Frames a scheduled fault discarded (partition, silence, loss) before they left.
    pub fault_dropped: u64,
    /// Frames a scheduled fault held back (latency, jitter).
    pub fault_delayed: u64,
    /// Delayed items still waiting when the system closed, or that could not be delivered.
    pub lost_on_close: u64,
}

/// Keeps a tap on its path; dropping it (or [`TapHandle::remove`]) takes the tap off.
#[must_use = "dropping the handle removes the tap"]
pub struct TapHandle {
    core: Weak<SystemCore>,
    id: u64,
}

impl TapHandle {
    /// Takes the tap off (as dropping the handle does).
    pub fn remove(self) {}

    /// Leaves the tap on for as long as its system is open.
    pub fn keep(mut self) {
        self.core = Weak::new();
    }
}

impl Drop for TapHandle {
    fn drop(&mut self) {
        if let Some(core) = self.core.upgrade() {
            core.harness.remove_tap(self.id);
        }
    }
}

impl std::fmt::Debug for TapHandle {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        f.debug_struct("TapHandle").field("id", &self.id).finish()
    }
}

/// The source of a replaced path ([`Comm::replace`]): while it lives, the real messages on the
/// path are discarded, and what it injects arrives in their place, looking to the receiving
/// module as the real ones would.
pub struct Replacement {
    tap: TapHandle,
    core: Weak<SystemCore>,
    target: engine::Target,
}

impl Replacement {
    /// Injects an encoded payload on a message path (as from the path's source system and,
    /// for a path without one, as from the destination itself). `message_type` is the path's
    /// type when it has one. For a topic path the bytes are decoded as the topic's type.
    pub fn inject_raw(&self, message_type: MessageType, payload: &[u8]) -> Result<(), InjectError> {
        let core = self.core.upgrade().ok_or(InjectError::Closed)?;
        let now = core.clock.now();
        core.harness
            .inject_bytes(&core, &self.target, message_type, payload, now)
    }

    /// Injects `msg` on a message path (encoded as a send would).
    pub fn inject<M: Message>(&self, msg: &M) -> Result<(), InjectError> {
        let bytes = payload::encode(msg).map_err(|e| InjectError::Encode(e.to_string()))?;
        self.inject_raw(M::TYPE, &bytes)
    }

    /// Publishes `value` on a replaced topic path, to the topic's subscribers.
    pub fn publish<T: Any + Send + Sync>(&self, value: T) -> Result<(), InjectError> {
        let core = self.core.upgrade().ok_or(InjectError::Closed)?;
        core.harness
            .inject_value(&self.target, Arc::new(value), core.clock.now())
    }

    /// Ends the replacement: real messages flow again.
    pub fn end(self) {
        drop(self.tap);
    }
}

impl std::fmt::Debug for Replacement {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        f.debug_struct("Replacement")
            .field("tap", &self.tap)
            .finish()
    }
}

/// Why an injection did not happen.
#[derive(Debug, Clone, PartialEq, Eq, thiserror::Error)]
#[non_exhaustive]
pub enum InjectError {
    /// The system is closed.
    #[error("the system is closed")]
    Closed,
    /// The value could not be encoded.
    #[error("could not encode the message: {0}")]
    Encode(String),
    /// The bytes do not decode as the topic's type.
    #[error("injected bytes do not decode as topic `{topic}`'s type: {reason}")]
    Decode {
        /// The topic.
        topic: String,
        /// Why.
        reason: String,
    },
    /// A topic value injected into a message path, or bytes into a topic nobody advertised
    /// or subscribed to with a typed API.
    #[error("cannot inject into {path}: {reason}")]
    Unsupported {
        /// The path.
        path: String,
        /// Why.
        reason: String,
    },
    /// The destination module refused it (inbox full, no such module).
    #[error("the destination refused the message: {0:?}")]
    Refused(hetcomm_core::wire::AckStatus),
}

impl Comm {
    /// Places a tap on `path`, which must act at this system (a topic of this system, or
    /// messages arriving here). The tap acts from now until the handle is dropped.
    pub fn tap(&self, path: &TapPath, action: TapAction) -> Result<TapHandle, TapError> {
        self.tap_between(path, action, None)
    }

    /// [`Comm::tap`] for a window of time only: from `start` to `end` on the system's clock
    /// (monotonic in real time, [`Time::now_mono`]; virtual under simulation).
    pub fn tap_between(
        &self,
        path: &TapPath,
        action: TapAction,
        window: Option<(Time, Time)>,
    ) -> Result<TapHandle, TapError> {
        let core = &self.handle.core;
        let target = resolve(self, path)?;
        let id = core.harness.add_tap(target, action, window)?;
        Ok(TapHandle {
            core: Arc::downgrade(core),
            id,
        })
    }

    /// Replaces the source of `path` (acting at this system): the real messages are discarded
    /// while the returned [`Replacement`] lives, and what it injects takes their place.
    pub fn replace(&self, path: &TapPath) -> Result<Replacement, TapError> {
        self.replace_between(path, None)
    }

    /// [`Comm::replace`] for a window of time only.
    pub fn replace_between(
        &self,
        path: &TapPath,
        window: Option<(Time, Time)>,
    ) -> Result<Replacement, TapError> {
        let core = &self.handle.core;
        let target = resolve(self, path)?;
        let id = core
            .harness
            .add_tap(target.clone(), TapAction::Replace, window)?;
        Ok(Replacement {
            tap: TapHandle {
                core: Arc::downgrade(core),
                id,
            },
            core: Arc::downgrade(core),
            target,
        })
    }

    /// What this system's harness did so far.
    pub fn harness_stats(&self) -> HarnessStats {
        self.handle.core.harness.stats()
    }
}

/// A path's names turned into ids, checked against the fleet and this system.
pub(crate) fn resolve(comm: &Comm, path: &TapPath) -> Result<engine::Target, TapError> {
    let fleet = comm.fleet();
    let shown = path.to_string();
    let system_id = |name: &str| -> Result<SystemId, TapError> {
        fleet
            .system_by_name(name)
            .map(|s| s.id)
            .ok_or_else(|| TapError::UnknownSystem {
                path: shown.clone(),
                name: name.to_string(),
            })
    };
    let here = comm.name();
    let at = path.system();
    system_id(at)?;
    if at != here {
        return Err(TapError::WrongSystem {
            path: shown,
            path_system: at.to_string(),
            here: here.to_string(),
        });
    }
    match path {
        TapPath::Topic { topic, .. } => Ok(engine::Target::Topic(Arc::from(topic.as_str()))),
        TapPath::Messages {
            from,
            to,
            module,
            message_type,
        } => {
            let to_id = system_id(to)?;
            let from = match from {
                Some(f) => {
                    let id = system_id(f)?;
                    if id != to_id && fleet.route(id, to_id).is_none() {
                        return Err(TapError::NoSuchPath {
                            path: shown,
                            from: f.clone(),
                            to: to.clone(),
                        });
                    }
                    Some(id)
                }
                None => None,
            };
            let module = match module {
                Some(m) => Some(
                    fleet
                        .modules
                        .iter()
                        .find(|x| x.name == *m)
                        .map(|x| x.id)
                        .ok_or_else(|| TapError::UnknownModule {
                            path: shown.clone(),
                            name: m.clone(),
                        })?,
                ),
                None => None,
            };
            Ok(engine::Target::Messages(engine::MessageMatch {
                from,
                to: to_id,
                module,
                message_type: *message_type,
            }))
        }
    }
}

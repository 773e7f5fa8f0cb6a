//! The thesis's extended `Node` (its Fig. 12): one object per module that talks to the other
//! modules of its own system over named **topics** (publish–subscribe), and to modules of
//! other systems with the communication API ([`Module::send`], [`Module::broadcast`],
//! [`Module::recv`], [`Module::on`]). [`Node`] is [`Module`]: the topic methods below are
//! methods of every module.
//!
//! | thesis (Table 4) | here |
//! |---|---|
//! | Initialization | [`Comm::node`](crate::Comm::node) (= [`Comm::module`](crate::Comm::module)) |
//! | Advertise | [`Module::advertise`] → [`Publisher`] |
//! | Subscribe | [`Module::subscribe`] → [`Subscription`] (poll it) |
//! | Notification | [`Module::notification`] (= [`Module::on_topic`]): a function called per value |
//! | Publish | [`Publisher::publish`] |
//! | Callback | [`Subscription::try_recv`] / [`Subscription::recv_timeout`], or the notification function |
//!
//! Topics live inside one system, and a system lives in one process (its modules share its
//! router and inboxes), so a topic never crosses a process: a value published is handed to
//! the subscribers as an `Arc<T>` — no serialization, no copy. To reach another system, send
//! a message. A topic's type is fixed by its first advertise or subscribe; a different type
//! later is refused ([`TopicError::TypeMismatch`]).
//!
//! Delivery is synchronous: [`Publisher::publish`] puts the value in every subscription's
//! queue and calls every notification function on the publishing thread (under the simulator,
//! the simulator's thread: runs stay repeatable), then returns. A subscription's queue holds
//! `capacity` values; a value arriving at a full queue pushes out the oldest, counted in
//! [`Subscription::dropped`].
//!
//! Taps ([`crate::harness`]) on a topic path see each value before the subscribers do.

use parking_lot::{Condvar, Mutex, RwLock};
use std::any::{Any, TypeId};
use std::collections::{HashMap, VecDeque};
use std::marker::PhantomData;
use std::sync::atomic::{AtomicU64, Ordering};
use std::sync::{Arc, Weak};
use std::time::{Duration, Instant};

use hetcomm_core::{payload, Message, ModuleId, Time};

use crate::harness::{InjectError, TopicValue};
use crate::module::Module;
use crate::runtime::SystemCore;

/// The thesis's name for a module: a [`Module`] is a node (Table 4).
pub type Node = Module;

/// How many values a subscription holds before the oldest is pushed out.
pub const DEFAULT_TOPIC_CAPACITY: usize = 64;

/// Why a topic operation was refused.
#[derive(Debug, Clone, PartialEq, Eq, thiserror::Error)]
#[non_exhaustive]
pub enum TopicError {
    /// The topic already carries another type.
    #[error("topic `{topic}` carries {existing}, not {requested}")]
    TypeMismatch {
        /// The topic.
        topic: String,
        /// The type it was advertised or subscribed with first.
        existing: &'static str,
        /// The type asked for now.
        requested: &'static str,
    },
    /// An empty topic name.
    #[error("a topic needs a name")]
    EmptyName,
    /// No value arrived in time.
    #[error("no value on topic `{topic}` within {timeout:?}")]
    Timeout {
        /// The topic.
        topic: String,
        /// How long it waited.
        timeout: Duration,
    },
    /// The system was closed.
    #[error("the system is closed")]
    Closed,
}

type DecodeFn = fn(&[u8]) -> Result<TopicValue, String>;

fn decode_as<T: Message + Sync>(bytes: &[u8]) -> Result<TopicValue, String> {
    payload::decode::<T>(bytes)
        .map(|v| Arc::new(v) as TopicValue)
        .map_err(|e| e.to_string())
}

struct TopicType {
    id: TypeId,
    name: &'static str,
    decode: DecodeFn,
}

type Notify = Arc<dyn Fn(TopicValue, Time) + Send + Sync>;

enum SubKind {
    Queue {
        values: Mutex<VecDeque<TopicValue>>,
        ready: Condvar,
        capacity: usize,
    },
    Notify(Notify),
}

struct SubCore {
    id: u64,
    module: ModuleId,
    kind: SubKind,
    received: AtomicU64,
    dropped: AtomicU64,
}

struct TopicCore {
    name: Arc<str>,
    ty: Mutex<Option<TopicType>>,
    subs: RwLock<Arc<[Arc<SubCore>]>>,
    published: AtomicU64,
}

/// A system's topics (in its harness, beside its taps).
#[derive(Default)]
pub(crate) struct Topics {
    map: RwLock<HashMap<Arc<str>, Arc<TopicCore>>>,
    next_sub: AtomicU64,
}

impl Topics {
    fn topic<T: Message + Sync>(&self, name: &str) -> Result<Arc<TopicCore>, TopicError> {
        if name.is_empty() {
            return Err(TopicError::EmptyName);
        }
        let t = {
            let mut map = self.map.write();
            map.entry(Arc::from(name))
                .or_insert_with(|| {
                    Arc::new(TopicCore {
                        name: Arc::from(name),
                        ty: Mutex::new(None),
                        subs: RwLock::new(Arc::new([])),
                        published: AtomicU64::new(0),
                    })
                })
                .clone()
        };
        let mut ty = t.ty.lock();
        match &*ty {
            Some(existing) if existing.id != TypeId::of::<T>() => {
                return Err(TopicError::TypeMismatch {
                    topic: name.to_string(),
                    existing: existing.name,
                    requested: T::NAME,
                })
            }
            Some(_) => {}
            None => {
                *ty = Some(TopicType {
                    id: TypeId::of::<T>(),
                    name: T::NAME,
                    decode: decode_as::<T>,
                })
            }
        }
        drop(ty);
        Ok(t)
    }

    fn get(&self, name: &str) -> Option<Arc<TopicCore>> {
        self.map.read().get(name).cloned()
    }

    /// Decodes `bytes` as the topic's type (for injections from scenario files and tools).
    pub(crate) fn decode(&self, name: &str, bytes: &[u8]) -> Result<TopicValue, InjectError> {
        let decode = self
            .get(name)
            .and_then(|t| t.ty.lock().as_ref().map(|ty| ty.decode))
            .ok_or_else(|| InjectError::Unsupported {
                path: format!("topic {name}"),
                reason: "no node advertised or subscribed to it yet, so its type is unknown".into(),
            })?;
        decode(bytes).map_err(|reason| InjectError::Decode {
            topic: name.to_string(),
            reason,
        })
    }

    /// Hands `value` to every subscriber of topic `name`, past its taps.
    pub(crate) fn deliver(&self, name: &str, value: TopicValue, now: Time) {
        if let Some(t) = self.get(name) {
            deliver_to(&t, value, now);
        }
    }

    fn subscribe(&self, t: &Arc<TopicCore>, module: ModuleId, kind: SubKind) -> Arc<SubCore> {
        let sub = Arc::new(SubCore {
            id: self.next_sub.fetch_add(1, Ordering::Relaxed),
            module,
            kind,
            received: AtomicU64::new(0),
            dropped: AtomicU64::new(0),
        });
        let mut subs = t.subs.write();
        let mut v: Vec<_> = subs.iter().cloned().collect();
        v.push(sub.clone());
        *subs = v.into();
        sub
    }

    /// Every topic: (name, type name, values published, subscribers).
    pub(crate) fn list(&self) -> Vec<TopicInfo> {
        let map = self.map.read();
        let mut v: Vec<_> = map
            .values()
            .map(|t| TopicInfo {
                name: t.name.to_string(),
                type_name: t.ty.lock().as_ref().map_or("", |ty| ty.name),
                published: t.published.load(Ordering::Relaxed),
                subscribers: t.subs.read().len(),
            })
            .collect();
        v.sort_by(|a, b| a.name.cmp(&b.name));
        v
    }
}

fn unsubscribe(t: &TopicCore, id: u64) {
    let mut subs = t.subs.write();
    let v: Vec<_> = subs.iter().filter(|s| s.id != id).cloned().collect();
    *subs = v.into();
}

fn deliver_to(t: &TopicCore, value: TopicValue, now: Time) {
    let subs = t.subs.read().clone();
    for s in subs.iter() {
        s.received.fetch_add(1, Ordering::Relaxed);
        match &s.kind {
            SubKind::Queue {
                values,
                ready,
                capacity,
            } => {
                let mut q = values.lock();
                if q.len() >= *capacity {
                    q.pop_front();
                    s.dropped.fetch_add(1, Ordering::Relaxed);
                }
                q.push_back(value.clone());
                drop(q);
                ready.notify_one();
            }
            SubKind::Notify(f) => f(value.clone(), now),
        }
    }
}

/// One topic of a system, as listed by [`Comm::topics`](crate::Comm::topics).
#[derive(Clone, Debug, PartialEq, Eq)]
#[non_exhaustive]
pub struct TopicInfo {
    /// The topic's name.
    pub name: String,
    /// The Rust message type it carries.
    pub type_name: &'static str,
    /// Values published on it (by nodes; injected values are counted by the harness).
    pub published: u64,
    /// Subscriptions and notification functions on it now.
    pub subscribers: usize,
}

/// Publishes `T`s on one topic of this module's system; made by [`Module::advertise`].
pub struct Publisher<T> {
    core: Weak<SystemCore>,
    topic: Arc<TopicCore>,
    _type: PhantomData<fn(T)>,
}

impl<T> Clone for Publisher<T> {
    fn clone(&self) -> Self {
        Publisher {
            core: self.core.clone(),
            topic: self.topic.clone(),
            _type: PhantomData,
        }
    }
}

impl<T: Message + Sync> Publisher<T> {
    /// Publishes `value` to every subscriber (Table 4's *Publish*).
    pub fn publish(&self, value: T) -> Result<(), TopicError> {
        self.publish_arc(Arc::new(value))
    }

    /// Publishes a value already shared: subscribers get this very `Arc`.
    pub fn publish_arc(&self, value: Arc<T>) -> Result<(), TopicError> {
        let core = self.core.upgrade().ok_or(TopicError::Closed)?;
        if core.is_closed() {
            return Err(TopicError::Closed);
        }
        self.topic.published.fetch_add(1, Ordering::Relaxed);
        let now = core.clock.now();
        let value: TopicValue = value;
        core.publish(&self.topic.name, value, now, |v| {
            deliver_to(&self.topic, v, now)
        });
        Ok(())
    }

    /// The topic's name.
    pub fn topic(&self) -> &str {
        &self.topic.name
    }
}

/// Values of one topic queued for one module; made by [`Module::subscribe`]. Dropping it
/// unsubscribes.
pub struct Subscription<T> {
    topic: Arc<TopicCore>,
    sub: Arc<SubCore>,
    _type: PhantomData<fn() -> T>,
}

impl<T: Any + Send + Sync> Subscription<T> {
    fn queue(&self) -> (&Mutex<VecDeque<TopicValue>>, &Condvar) {
        match &self.sub.kind {
            SubKind::Queue { values, ready, .. } => (values, ready),
            SubKind::Notify(_) => unreachable!("a Subscription is always a queue"),
        }
    }

    fn cast(v: TopicValue) -> Arc<T> {
        // The topic's type is checked at advertise/subscribe, and injections decode as it.
        v.downcast::<T>()
            .unwrap_or_else(|_| unreachable!("a topic carries one type"))
    }

    /// Takes the oldest value waiting, if any (Table 4's *Callback*, polled).
    pub fn try_recv(&self) -> Option<Arc<T>> {
        let (q, _) = self.queue();
        let v = q.lock().pop_front()?;
        Some(Self::cast(v))
    }

    /// Waits up to `timeout` for a value.
    pub fn recv_timeout(&self, timeout: Duration) -> Result<Arc<T>, TopicError> {
        let (q, ready) = self.queue();
        let deadline = Instant::now() + timeout;
        let mut g = q.lock();
        loop {
            if let Some(v) = g.pop_front() {
                return Ok(Self::cast(v));
            }
            let left = deadline.saturating_duration_since(Instant::now());
            if left.is_zero() {
                return Err(TopicError::Timeout {
                    topic: self.topic.name.to_string(),
                    timeout,
                });
            }
            ready.wait_for(&mut g, left);
        }
    }

    /// Takes every value waiting and returns the newest (older ones are discarded).
    pub fn latest(&self) -> Option<Arc<T>> {
        let (q, _) = self.queue();
        let mut g = q.lock();
        let last = g.pop_back();
        g.clear();
        last.map(Self::cast)
    }

    /// Values waiting.
    pub fn pending(&self) -> usize {
        self.queue().0.lock().len()
    }

    /// Values pushed out of a full queue so far.
    pub fn dropped(&self) -> u64 {
        self.sub.dropped.load(Ordering::Relaxed)
    }

    /// Values that reached this subscription so far.
    pub fn received(&self) -> u64 {
        self.sub.received.load(Ordering::Relaxed)
    }

    /// The topic's name.
    pub fn topic(&self) -> &str {
        &self.topic.name
    }
}

impl<T> Drop for Subscription<T> {
    fn drop(&mut self) {
        unsubscribe(&self.topic, self.sub.id);
    }
}

/// Keeps a notification function on a topic; dropping it takes the function off.
#[must_use = "dropping the handle takes the notification off"]
pub struct Notification {
    topic: Arc<TopicCore>,
    id: u64,
    kept: bool,
}

impl Notification {
    /// Leaves the function on for as long as the system is open.
    pub fn keep(mut self) {
        self.kept = true;
    }
}

impl Drop for Notification {
    fn drop(&mut self) {
        if !self.kept {
            unsubscribe(&self.topic, self.id);
        }
    }
}

impl Module {
    /// Advertises topic `topic` of this module's system, carrying `T`s (Table 4's
    /// *Advertise*); publish through the returned [`Publisher`].
    pub fn advertise<T: Message + Sync>(&self, topic: &str) -> Result<Publisher<T>, TopicError> {
        let core = &self.sys.core;
        let topic = core.harness.topics.topic::<T>(topic)?;
        Ok(Publisher {
            core: Arc::downgrade(core),
            topic,
            _type: PhantomData,
        })
    }

    /// Subscribes this module to topic `topic` (Table 4's *Subscribe*): values queue in the
    /// returned [`Subscription`] (up to [`DEFAULT_TOPIC_CAPACITY`]).
    pub fn subscribe<T: Message + Sync>(&self, topic: &str) -> Result<Subscription<T>, TopicError> {
        self.subscribe_with_capacity(topic, DEFAULT_TOPIC_CAPACITY)
    }

    /// [`Module::subscribe`] holding up to `capacity` values (at least 1).
    pub fn subscribe_with_capacity<T: Message + Sync>(
        &self,
        topic: &str,
        capacity: usize,
    ) -> Result<Subscription<T>, TopicError> {
        let topics = &self.sys.core.harness.topics;
        let t = topics.topic::<T>(topic)?;
        let sub = topics.subscribe(
            &t,
            self.core.id,
            SubKind::Queue {
                values: Mutex::new(VecDeque::new()),
                ready: Condvar::new(),
                capacity: capacity.max(1),
            },
        );
        Ok(Subscription {
            topic: t,
            sub,
            _type: PhantomData,
        })
    }

    /// Calls `f` with every value published on `topic` from now on, on the publishing thread
    /// (Table 4's *Notification*).
    pub fn on_topic<T: Message + Sync>(
        &self,
        topic: &str,
        f: impl Fn(Arc<T>) + Send + Sync + 'static,
    ) -> Result<Notification, TopicError> {
        let topics = &self.sys.core.harness.topics;
        let t = topics.topic::<T>(topic)?;
        let notify: Notify = Arc::new(move |v: TopicValue, _| {
            if let Ok(v) = v.downcast::<T>() {
                f(v)
            }
        });
        let sub = topics.subscribe(&t, self.core.id, SubKind::Notify(notify));
        Ok(Notification {
            topic: t,
            id: sub.id,
            kept: false,
        })
    }

    /// The thesis's name for [`Module::on_topic`] (Table 4's *Notification*).
    pub fn notification<T: Message + Sync>(
        &self,
        topic: &str,
        f: impl Fn(Arc<T>) + Send + Sync + 'static,
    ) -> Result<Notification, TopicError> {
        self.on_topic(topic, f)
    }

    /// Publishes one value on `topic` without keeping a [`Publisher`] (advertises it first).
    pub fn publish<T: Message + Sync>(&self, topic: &str, value: T) -> Result<(), TopicError> {
        self.advertise::<T>(topic)?.publish(value)
    }
}

impl crate::Comm {
    /// The thesis's *Initialization* (Table 4): this system's node `name`, the same object as
    /// [`Comm::module`](crate::Comm::module).
    pub fn node(&self, name: &str) -> Result<Node, crate::OpenError> {
        self.module(name)
    }

    /// This system's topics, by name.
    pub fn topics(&self) -> Vec<TopicInfo> {
        self.handle.core.harness.topics.list()
    }
}

impl<T> std::fmt::Debug for Publisher<T> {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        f.debug_struct("Publisher")
            .field("topic", &self.topic.name)
            .finish()
    }
}

impl<T> std::fmt::Debug for Subscription<T> {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        f.debug_struct("Subscription")
            .field("topic", &self.topic.name)
            .field("module", &self.sub.module)
            .finish()
    }
}

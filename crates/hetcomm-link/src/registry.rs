//! Transport factories: one per kind, registered by the kind's crate.
//!
//! A [`TransportFactory`] is everything about one transport kind in one place: its settings
//! (a [`KindSpec`]: keys, parsing with located errors, validation) and how to open a link of
//! it from a fleet's transport definition. A program builds one [`Registry`] from the kinds
//! compiled into it, one line per crate, each crate offering a `register_transports` function:
//!
//! ```ignore
//! let mut registry = Registry::new();
//! hetcomm_link_ip::register_transports(&mut registry);
//! #[cfg(feature = "mqtt")]
//! hetcomm_link_mqtt::register_transports(&mut registry);
//! ```
//!
//! (the `hetcomm` crate does this in `crates/hetcomm/src/transports.rs`). The registry then
//! gives the fleet loader the specs ([`Registry::kinds`], for `hetcomm_config::load_with`) and
//! opens links ([`Registry::open`]).
//!
//! The two halves are split by the crates' dependency direction: the fleet loader
//! (`hetcomm-config`) sits below this crate, so it knows the spec half only, through a
//! [`Kinds`] table; opening needs the [`Link`] trait, which lives here. The kinds the loader
//! models itself (`udp`, `tcp`, `ros1`, `bluetooth`: `hetcomm validate` checks them in every
//! build, and the legacy table files name them) have no spec; their factories only open.
//! `inproc` and `emulated` belong to the runtime (direct hand-over, the layer stack) and are
//! opened by it, not through a factory.
//!
//! Opening only: nothing here is on the path of a frame.

use std::collections::{BTreeMap, BTreeSet};
use std::sync::Arc;

use hetcomm_config::{Fleet, KindSpec, Kinds, TransportDef, TransportKind};
use hetcomm_core::SystemId;

use crate::shape::MessageShapes;
use crate::{FrameSink, Link};

/// The fleet model, for factories in crates that depend on this one only.
pub use hetcomm_config as config;

/// What a factory gets to open one system's link of a transport.
pub struct OpenRequest<'a> {
    /// The whole fleet (system names, other transports).
    pub fleet: &'a Fleet,
    /// The transport being opened; its `settings` are the ones its kind's parser built
    /// (`TransportSettings::Registered` for a kind with a [`KindSpec`]).
    pub transport: &'a TransportDef,
    /// The system the link is for.
    pub local: SystemId,
    /// Where the link delivers the frames it receives.
    pub sink: Arc<dyn FrameSink>,
    /// The shapes of the message types the program declared, for a kind that converts
    /// payloads and checks its mappings when it opens ([`NO_SHAPES`](crate::shape::NO_SHAPES)
    /// when there are none).
    pub shapes: &'a MessageShapes,
}

/// An opened link and where it listens.
pub struct Opened {
    /// The link.
    pub link: Arc<dyn Link>,
    /// Where it listens, for tools to print (e.g. `udp://127.0.0.1:7400`), if it does.
    pub local_address: Option<String>,
}

/// One transport kind: its settings and how to open it. Implemented in the kind's own crate
/// and added to a [`Registry`] by that crate's `register_transports` function.
pub trait TransportFactory: Send + Sync {
    /// The kind it opens.
    fn kind(&self) -> TransportKind;

    /// The kind's settings half, for a kind the fleet loader does not model itself. A
    /// factory usually implements [`KindSpec`] too and returns itself here (see
    /// [`Registry::register`]). The default, None, is for `udp`, `tcp`, `ros1` and
    /// `bluetooth`, whose settings the loader reads.
    fn spec(self: Arc<Self>) -> Option<Arc<dyn KindSpec>> {
        None
    }

    /// Opens `request.local`'s link of `request.transport`. The error says what went wrong
    /// (the caller adds which transport and system it was) and keeps its cause as its
    /// `source()`: a link's own error converts with `?`, a sentence with `.into()`.
    fn open(&self, request: OpenRequest<'_>) -> Result<Opened, OpenFailure>;

    /// For a bridge kind (a transport to a robot that runs something else than hetcomm, e.g.
    /// ROS, through typed topics): the name of that robot in `transport`'s settings. No
    /// hetcomm process may open that system; tools such as the demonstration ask this to
    /// leave it out and to talk to it through the bridge's mapped types. The default, None,
    /// is for every transport between hetcomm systems.
    fn bridged_robot(&self, transport: &TransportDef) -> Option<String> {
        let _ = transport;
        None
    }
}

/// Why a factory could not open a link: any error, its cause chain kept.
pub type OpenFailure = Box<dyn std::error::Error + Send + Sync + 'static>;

/// The transport kinds compiled into a program, by kind.
#[derive(Clone, Default)]
pub struct Registry {
    factories: BTreeMap<TransportKind, Arc<dyn TransportFactory>>,
    kinds: Kinds,
    /// Kinds known by name whose crate is not compiled in, with the feature that adds it.
    unbuilt: BTreeMap<TransportKind, &'static str>,
    /// Those of them that are bridges: each transport of one stands for a robot that runs no
    /// hetcomm, which nothing in this program can stand in for.
    unbuilt_bridges: BTreeSet<TransportKind>,
}

impl Registry {
    /// No kinds.
    pub fn new() -> Registry {
        Registry::default()
    }

    /// Adds a kind's factory (and its settings spec, if it has one), replacing an earlier one
    /// of the same kind.
    pub fn register<F: TransportFactory + 'static>(&mut self, factory: F) {
        let factory = Arc::new(factory);
        if let Some(spec) = factory.clone().spec() {
            self.kinds.add(spec);
        }
        self.factories.insert(factory.kind(), factory);
    }

    /// Records that `kind` exists but its crate is not compiled in; `feature` compiles it in.
    /// A fleet file may still name it (its keys are kept raw, [`Kinds::add_unbuilt`]), and
    /// opening it can say which feature to rebuild with ([`Registry::feature_for`]).
    pub fn not_built(&mut self, kind: TransportKind, feature: &'static str) {
        self.kinds.add_unbuilt(kind);
        self.unbuilt.insert(kind, feature);
    }

    /// Like [`Registry::not_built`], for a bridge kind (see [`TransportFactory::bridged_robot`]):
    /// [`Registry::unbuilt_bridges`] names fleets' transports of it.
    pub fn not_built_bridge(&mut self, kind: TransportKind, feature: &'static str) {
        self.not_built(kind, feature);
        self.unbuilt_bridges.insert(kind);
    }

    /// The transports of `fleet` of a bridge kind not compiled in, with the feature that adds
    /// it, in transport order. A program that would simulate the robot such a transport stands
    /// for (in virtual time) should refuse instead: the robot is not simulated, it runs ROS.
    pub fn unbuilt_bridges<'f>(&self, fleet: &'f Fleet) -> Vec<(&'f TransportDef, &'static str)> {
        fleet
            .transports
            .iter()
            .filter(|t| self.unbuilt_bridges.contains(&t.kind))
            .filter_map(|t| Some((t, self.feature_for(t.kind)?)))
            .collect()
    }

    /// The feature that compiles `kind` in, for a kind recorded with [`Registry::not_built`].
    pub fn feature_for(&self, kind: TransportKind) -> Option<&'static str> {
        self.unbuilt.get(&kind).copied()
    }

    /// The factory of `kind`, if it is compiled in.
    pub fn factory(&self, kind: TransportKind) -> Option<&dyn TransportFactory> {
        self.factories.get(&kind).map(|f| &**f)
    }

    /// The registered kinds, in name order.
    pub fn registered(&self) -> impl Iterator<Item = TransportKind> + '_ {
        self.factories.keys().copied()
    }

    /// The settings specs of the registered kinds, for `hetcomm_config::load_with` and
    /// `parse_str_with`.
    pub fn kinds(&self) -> &Kinds {
        &self.kinds
    }

    /// The robots of `fleet` that bridge transports stand for ([`TransportFactory::bridged_robot`]),
    /// each once, in transport order: systems that run no hetcomm.
    pub fn bridged_robots(&self, fleet: &Fleet) -> Vec<String> {
        let mut robots: Vec<String> = Vec::new();
        for t in &fleet.transports {
            let robot = self.factory(t.kind).and_then(|f| f.bridged_robot(t));
            if let Some(robot) = robot.filter(|r| !robots.contains(r)) {
                robots.push(robot);
            }
        }
        robots
    }

    /// Opens `request.transport`'s link through its kind's factory; None when the kind is not
    /// registered (not compiled in).
    pub fn open(&self, request: OpenRequest<'_>) -> Option<Result<Opened, OpenFailure>> {
        let factory = self.factory(request.transport.kind)?;
        Some(factory.open(request))
    }
}

impl std::fmt::Debug for Registry {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        f.debug_set().entries(self.factories.keys()).finish()
    }
}

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
//! [`Kinds`] table; opening needs the [`Link`] trait, which lives here. The loader models no
//! kind itself: `inproc` and `emulated` are this crate's factories and specs
//! ([`register_transports`](crate::register_transports)), registered like every other kind;
//! what they need of the program that opens them (its in-process hubs, opening the transport
//! an `emulated` one is layered over) comes through the request's [`OpenHost`].
//!
//! A factory also answers what the runtime and the security layer ask of a kind, so that
//! neither names a kind: whether its frames leave the process
//! ([`TransportFactory::leaves_process`]), the layer it puts over its link
//! ([`TransportFactory::layer`]) and whether its systems may skip the link and hand messages
//! over directly ([`TransportFactory::hands_over`]).
//!
//! Opening only: nothing here is on the path of a frame.

use std::collections::{BTreeMap, BTreeSet};
use std::sync::Arc;
use std::time::Instant;

use hetcomm_config::{Fleet, KindSettings, KindSpec, Kinds, TransportDef, TransportKind};
use hetcomm_core::SystemId;

use crate::emulation::{LinkModel, PositionTable};
use crate::inproc::InprocHub;
use crate::layer::LinkLayer;
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
    /// What the program opening the link offers a factory ([`STANDALONE`] outside a runtime).
    pub host: &'a dyn OpenHost,
}

impl<'a> OpenRequest<'a> {
    /// The transport's settings as the type its kind's [`KindSpec`] built
    /// (`TransportSettings::registered`); an error naming the transport for any other
    /// settings, which only a fleet built by hand rather than loaded could hold.
    pub fn settings<T: KindSettings>(&self) -> Result<&'a T, OpenFailure> {
        let t = self.transport;
        t.settings.registered().ok_or_else(|| {
            format!(
                "transport `{}` (kind {}) holds settings its kind did not read: {:?}",
                t.name, t.kind, t.settings
            )
            .into()
        })
    }
}

/// What the program that opens links offers their factories beyond the fleet: the in-process
/// meeting points of the systems it opens together, opening another transport of the fleet
/// for a kind layered over one, and what emulated links share.
pub trait OpenHost {
    /// The in-process hub named `name` that the systems opened together meet at.
    fn hub(&self, name: &str) -> InprocHub;

    /// Opens transport number `index` of the fleet for the same system, with its own layers,
    /// delivering to `sink`: the link under a kind layered over another (`emulated` with
    /// `over`). An error of the program's own is returned as it is, boxed.
    fn open_transport(&self, index: usize, sink: Arc<dyn FrameSink>)
        -> Result<Opened, OpenFailure>;

    /// The positions distance-dependent emulation reads.
    fn positions(&self) -> PositionTable;

    /// The instant emulated links count their outage schedules from.
    fn epoch(&self) -> Instant;
}

/// An [`OpenHost`] for a link opened on its own, outside a runtime: every hub is a new one
/// (so nothing meets there), no other transport can be opened, positions are empty and the
/// epoch is now.
pub struct Standalone;

/// The [`OpenHost`] of links opened on their own.
pub const STANDALONE: &Standalone = &Standalone;

impl OpenHost for Standalone {
    fn hub(&self, _name: &str) -> InprocHub {
        InprocHub::new()
    }

    fn open_transport(
        &self,
        index: usize,
        _sink: Arc<dyn FrameSink>,
    ) -> Result<Opened, OpenFailure> {
        Err(format!("transport number {index} cannot be opened outside a runtime").into())
    }

    fn positions(&self) -> PositionTable {
        PositionTable::default()
    }

    fn epoch(&self) -> Instant {
        Instant::now()
    }
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

    /// The kind's settings half. A factory usually implements [`KindSpec`] too and returns
    /// itself here (see [`Registry::register`]). The default, None, leaves the kind's keys
    /// raw, unchecked (a test factory's).
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

    /// Whether frames of this kind leave the process (then the security layer seals them,
    /// unless the transport says `security = "none"`). The default, true, is every network
    /// kind's; `inproc` and `emulated` (whose own link is a private in-process hub) say false.
    fn leaves_process(&self) -> bool {
        true
    }

    /// The layer this kind puts over its link (the top of the link's stack, nearest the
    /// router), e.g. `emulated`'s model. The default, None, is for a kind whose link is all.
    fn layer(
        &self,
        transport: &TransportDef,
        host: &dyn OpenHost,
    ) -> Result<Option<Arc<dyn LinkLayer>>, OpenFailure> {
        let _ = (transport, host);
        Ok(None)
    }

    /// The loss model a simulation applies, in virtual time, to frames on `transport` (what
    /// the kind's [`layer`](TransportFactory::layer) does in real time), its seed mixed with
    /// `seed_mix` (the simulation's). The default, None, is for a kind that models nothing.
    fn sim_model(
        &self,
        transport: &TransportDef,
        seed_mix: u64,
    ) -> Result<Option<LinkModel>, OpenFailure> {
        let _ = (transport, seed_mix);
        Ok(None)
    }

    /// Whether the systems on a link of this kind are all in this process, so that a send
    /// between two of them may skip the link and go straight to the destination's inbox (when
    /// no layer is over the link). Only `inproc` says true.
    fn hands_over(&self) -> bool {
        false
    }

    /// Whether the kind's frames never leave the host they are sent on (shared memory between
    /// processes of one machine): the operating system's permissions guard them, like an
    /// in-process transport's, so the runtime seals them only with `[security] in_process =
    /// true`. The default, false, is for every kind whose frames may cross a network.
    fn host_local(&self) -> bool {
        false
    }
}

/// Why a factory could not open a link: any error, its cause chain kept.
pub type OpenFailure = Box<dyn std::error::Error + Send + Sync + 'static>;

/// The transport kinds compiled into a program, by kind.
#[derive(Clone, Default)]
pub struct Registry {
    factories: BTreeMap<TransportKind, Arc<dyn TransportFactory>>,
    kinds: Kinds,
    /// Kinds known by name whose crate is not compiled in, with the feature that adds it and
    /// what else to do (when there is more to say than to rebuild).
    unbuilt: BTreeMap<TransportKind, (&'static str, Option<&'static str>)>,
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
        self.unbuilt.insert(kind, (feature, None));
    }

    /// Like [`Registry::not_built`], with the whole sentence opening such a transport says
    /// instead of "rebuild with `--features …`" (e.g. how to run without the kind).
    pub fn not_built_with_hint(
        &mut self,
        kind: TransportKind,
        feature: &'static str,
        hint: &'static str,
    ) {
        self.kinds.add_unbuilt(kind);
        self.unbuilt.insert(kind, (feature, Some(hint)));
    }

    /// What to do about a transport of `kind` in a program without it: the hint it was
    /// recorded with, else to rebuild with its feature, else (a kind nothing here knows) to
    /// choose another kind.
    pub fn unavailable_hint(&self, kind: TransportKind) -> String {
        match self.unbuilt.get(&kind) {
            Some((_, Some(hint))) => (*hint).to_string(),
            Some((feature, None)) => format!("rebuild with `--features {feature}`"),
            None => "choose `inproc` (one process) or another available kind in the fleet file"
                .to_string(),
        }
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
        self.unbuilt.get(&kind).map(|(feature, _)| *feature)
    }

    /// Whether `kind` is compiled in and declares itself host-local
    /// ([`TransportFactory::host_local`]).
    pub fn host_local(&self, kind: TransportKind) -> bool {
        self.factory(kind).is_some_and(|f| f.host_local())
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

    /// Whether frames of `kind` leave the process ([`TransportFactory::leaves_process`]); true
    /// for a kind not compiled in (a network kind, as far as anything here knows).
    pub fn leaves_process(&self, kind: TransportKind) -> bool {
        self.factory(kind).is_none_or(|f| f.leaves_process())
    }

    /// The index in `fleet` of the transport `t` is layered over ([`TransportDef::over`], which
    /// its kind's spec read), if it is layered over one and that one exists. Its frames then
    /// travel on that transport's link, and are secured by its layer.
    pub fn over(&self, fleet: &Fleet, t: &TransportDef) -> Option<usize> {
        let name = t.over.as_deref()?;
        fleet.transports.iter().position(|o| o.name == name)
    }

    /// Whether `t` names a transport it is layered over ([`TransportDef::over`]), whether or
    /// not the fleet has it.
    pub fn is_layered(&self, t: &TransportDef) -> bool {
        t.over.is_some()
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

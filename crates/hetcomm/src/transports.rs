//! The one dispatch point from a transport's kind to the code that opens it, and the one
//! place where layers are put over links ([`open_link`]): the same layers, built the same way,
//! whether the link is a real one or the simulator's.
//!
//! Which kinds this program has is [`registry`]: one registration line per link crate, behind
//! that crate's feature (without it, the crate's kinds stay known by name and opening one says
//! which feature to rebuild with). Every kind, `inproc` and `emulated` included, is opened by
//! its crate's `TransportFactory`, which also says whether it leaves the process, which
//! transport it is layered over, which layer it adds and whether its systems may hand
//! messages over directly; a kind without a factory says it is not available in this build.
//! Nothing here names a kind.

use parking_lot::Mutex;
use std::collections::HashMap;
use std::path::Path;
use std::sync::{Arc, OnceLock, Weak};

use hetcomm_config::{ConfigErrors, Fleet, TransportDef, TransportKind};
use hetcomm_core::SystemId;
use hetcomm_link::emulation::PositionTable;
use hetcomm_link::inproc::InprocHub;
use hetcomm_link::layer::{LayerContext, LayerError, LayerStack};
#[cfg(doc)]
use hetcomm_link::registry::TransportFactory;
use hetcomm_link::registry::{OpenFailure, OpenHost, OpenRequest, Opened, Registry};
use hetcomm_link::{FrameSink, Link};

use crate::comm::OpenEnv;
use crate::error::OpenError;
use crate::runtime::SystemCore;

/// One link crate's registration line: with its feature on, the crate registers its kinds;
/// with it off, the kinds stay known by name (a fleet file may name them, keys kept raw) and
/// opening one says to rebuild with the feature.
macro_rules! link_crate {
    ($registry:ident, $feature:literal, $krate:ident, [$($kind:literal),+] $(, bridges [$($bridge:literal),+])? $(, hint $hint:literal)?) => {
        #[cfg(feature = $feature)]
        $krate::register_transports(&mut $registry);
        #[cfg(not(feature = $feature))]
        {
            let hint: Option<&'static str> = None $(.or(Some($hint)))?;
            $(match hint {
                Some(hint) => $registry.not_built_with_hint(TransportKind::new($kind), $feature, hint),
                None => $registry.not_built(TransportKind::new($kind), $feature),
            })+
            $($($registry.not_built_bridge(TransportKind::new($bridge), $feature);)+)?
        }
    };
}

/// The transport kinds compiled into this program: one line per link crate. A new kind adds
/// its line here (and its feature in `Cargo.toml`) and nothing else outside its crate.
pub fn registry() -> &'static Registry {
    static REGISTRY: OnceLock<Registry> = OnceLock::new();
    REGISTRY.get_or_init(|| {
        let mut registry = Registry::new();
        hetcomm_link::register_transports(&mut registry);
        hetcomm_link_ip::register_transports(&mut registry);
        link_crate!(
            registry,
            "bluetooth",
            hetcomm_link_bluetooth,
            ["bluetooth"],
            hint "rebuild with `--features bluetooth` to use RFCOMM on a machine with Bluetooth, or use an `emulated` transport with profile = \"bluetooth-classic\" to simulate the radio"
        );
        link_crate!(
            registry,
            "ros1",
            hetcomm_link_ros1,
            ["ros1"],
            bridges["ros1_bridge"],
            hint "rebuild with `--features ros1` to use a ROS master, or map the letter to an `inproc` or `emulated` transport in the fleet file's [letters] table to run without one"
        );
        link_crate!(
            registry,
            "ros2",
            hetcomm_link_ros2,
            ["ros2"],
            bridges["ros2_bridge", "dds"]
        );
        link_crate!(registry, "zenoh", hetcomm_link_zenoh, ["zenoh"]);
        link_crate!(
            registry,
            "mqtt",
            hetcomm_link_mqtt,
            ["mqtt"],
            bridges["mqtt_bridge"]
        );
        link_crate!(registry, "shm", hetcomm_link_shm, ["shm"]);
        registry
    })
}

/// Reads and validates the fleet file at `path`, knowing the settings of every kind compiled
/// into this program ([`registry`]); `hetcomm_config::load` knows the built-in kinds only.
pub fn load_fleet(path: &Path) -> Result<Fleet, ConfigErrors> {
    hetcomm_config::load_with(path, registry().kinds())
}

/// Validates fleet-file text as [`load_fleet`] does (see `hetcomm_config::parse_str`).
pub fn parse_fleet(
    text: &str,
    origin: &str,
    base_dir: Option<&Path>,
) -> Result<Fleet, ConfigErrors> {
    hetcomm_config::parse_str_with(text, origin, base_dir, registry().kinds())
}

/// The systems on each in-process transport, by (transport name, system).
type LocalSystems = HashMap<(String, SystemId), Weak<SystemCore>>;

/// In-process hubs by transport name: systems opened through the same `Hubs` meet there.
#[derive(Clone, Default)]
pub(crate) struct Hubs {
    hubs: Arc<Mutex<HashMap<String, InprocHub>>>,
    /// The systems on each in-process transport, so that a send between two of them can skip
    /// the link and hand the message straight to the destination's inbox.
    systems: Arc<Mutex<LocalSystems>>,
}

impl Hubs {
    /// The hubs shared by every `Comm::open` of the same fleet file in this process, so that
    /// systems opened one by one (e.g. on different threads) still meet in-process.
    pub(crate) fn for_fleet_key(key: &str) -> Hubs {
        static GLOBAL: OnceLock<Mutex<HashMap<String, Hubs>>> = OnceLock::new();
        let global = GLOBAL.get_or_init(Default::default);
        global.lock().entry(key.to_string()).or_default().clone()
    }

    /// Records that `core` is on in-process transport `name`.
    pub(crate) fn register(&self, name: &str, core: &Arc<SystemCore>) {
        self.systems
            .lock()
            .insert((name.to_string(), core.id), Arc::downgrade(core));
    }

    /// The open system `id` on in-process transport `name`, if any.
    pub(crate) fn system(&self, name: &str, id: SystemId) -> Option<Arc<SystemCore>> {
        self.systems
            .lock()
            .get(&(name.to_string(), id))
            .and_then(Weak::upgrade)
            .filter(|c| !c.is_closed())
    }

    pub(crate) fn hub(&self, name: &str) -> InprocHub {
        self.hubs
            .lock()
            .entry(name.to_string())
            .or_default()
            .clone()
    }
}

/// An opened link and where it listens (for tools to print).
pub(crate) struct OpenedLink {
    pub link: Arc<dyn Link>,
    pub local_address: Option<String>,
    /// For an in-process link in real time: its transport's name, under which the system is
    /// registered in [`Hubs`] for direct hand-over.
    pub direct: Option<String>,
}

/// Opens transport number `index` of the fleet for system `local`, delivering what it
/// receives to `sink`: the transport's link (the simulator's under simulation) with the
/// transport's layers over both its sides (see [`layers`]). A transport without layers gets
/// its bare link, with nothing in between.
pub(crate) fn open_link(
    fleet: &Fleet,
    index: usize,
    local: SystemId,
    sink: Arc<dyn FrameSink>,
    env: &OpenEnv,
) -> Result<OpenedLink, OpenError> {
    let t = &fleet.transports[index];
    let system = fleet
        .system(local)
        .map(|s| s.name.clone())
        .unwrap_or_else(|| local.to_string());
    let failed = |e: OpenFailure| OpenError::transport(&t.name, &system, e);
    // A kind this program cannot open says so first (how to build it in matters more than
    // the keys it would need).
    let factory = match registry().factory(t.kind) {
        Some(factory) => Some(factory),
        None if env.sim.is_some() => None,
        None => return Err(unavailable(t, t.kind)),
    };
    let host = Host { fleet, local, env };
    let stack = layers(fleet, index, local, env, &host).map_err(&failed)?;
    let mut ctx = LayerContext::new(local);
    if env.sim.is_some() {
        ctx = ctx.in_virtual_time();
    }
    let mut local_address = None;
    let mut direct = None;
    let link = stack.open(&ctx, sink, &mut |sink| match (&env.sim, factory) {
        (Some(net), _) => Ok(net.open(index, local, sink)),
        (None, Some(factory)) => {
            let request = OpenRequest {
                fleet,
                transport: t,
                local,
                sink,
                shapes: &env.shapes,
                host: &host,
            };
            let opened = factory.open(request).map_err(LayerError::Open)?;
            local_address = opened.local_address;
            direct = factory.hands_over().then(|| t.name.clone());
            Ok(opened.link)
        }
        (None, None) => unreachable!("a kind without a factory was refused above"),
    });
    let link = link.map_err(|e| match e {
        // An error of the runtime's own (opening the transport under this one) is returned
        // as it is.
        LayerError::Open(e) => e.downcast::<OpenError>().map_or_else(&failed, |e| *e),
        e => failed(e.into()),
    })?;
    let opened = OpenedLink {
        link,
        local_address,
        // A message must pass the layers: no hand-over that skips the link.
        direct: direct.filter(|_| stack.is_empty()),
    };
    Ok(opened)
}

/// What the runtime offers the factories of the kinds it opens ([`OpenHost`]): its hubs,
/// opening the transport another is layered over, emulation's positions and epoch.
struct Host<'a> {
    fleet: &'a Fleet,
    local: SystemId,
    env: &'a OpenEnv,
}

impl OpenHost for Host<'_> {
    fn hub(&self, name: &str) -> InprocHub {
        self.env.hubs.hub(name)
    }

    fn open_transport(
        &self,
        index: usize,
        sink: Arc<dyn FrameSink>,
    ) -> Result<Opened, OpenFailure> {
        let opened = open_link(self.fleet, index, self.local, sink, self.env)?;
        Ok(Opened {
            link: opened.link,
            local_address: opened.local_address,
        })
    }

    fn positions(&self) -> PositionTable {
        self.env.positions.clone()
    }

    fn epoch(&self) -> std::time::Instant {
        self.env.epoch
    }
}

/// The layers over system `local`'s link of transport `index`, from the router down: the
/// kind's own layer (`emulated`'s model, [`TransportFactory::layer`]), then security for a
/// transport that leaves the process (nearest the link, so that what the emulation delays or
/// drops is a sealed frame's worth of traffic, and nothing reaches the link unsealed).
fn layers(
    fleet: &Fleet,
    index: usize,
    local: SystemId,
    env: &OpenEnv,
    host: &Host<'_>,
) -> Result<LayerStack, OpenFailure> {
    let t = &fleet.transports[index];
    let mut stack = LayerStack::new();
    if let Some(factory) = registry().factory(t.kind) {
        if let Some(layer) = factory.layer(t, host)? {
            stack.push(layer);
        }
    }
    if crate::security::secured(fleet, index, env.sim.is_some()) {
        stack.push(crate::security::layer(fleet, index, local, &env.keys)?);
    }
    Ok(stack)
}

/// The error for a kind without a factory in this build: what to rebuild with, or what to use
/// instead (the registry's [`Registry::unavailable_hint`]).
fn unavailable(t: &TransportDef, kind: TransportKind) -> OpenError {
    OpenError::KindUnavailable {
        transport: t.name.clone(),
        kind,
        hint: registry().unavailable_hint(kind),
    }
}

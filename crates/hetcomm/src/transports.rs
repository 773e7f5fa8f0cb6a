//! The one dispatch point from a transport's kind to the code that opens it, and the one
//! place where layers are put over links ([`open_link`]): the same layers, built the same way,
//! whether the link is a real one or the simulator's.
//!
//! Which kinds this program has is [`registry`]: one registration line per link crate, behind
//! that crate's feature (without it, the crate's kinds stay known by name and opening one says
//! which feature to rebuild with). `inproc` and `emulated` are the runtime's own (direct
//! hand-over, the layer stack) and are opened here; every other kind is opened by its crate's
//! `TransportFactory`, and a kind without one says it is not available in this build.

use std::collections::HashMap;
use std::path::Path;
use std::sync::{Arc, Mutex, OnceLock, Weak};

use hetcomm_config::{ConfigErrors, Fleet, TransportDef, TransportKind, TransportSettings};
use hetcomm_core::SystemId;
use hetcomm_link::emulation::EmulationLayer;
use hetcomm_link::inproc::InprocHub;
use hetcomm_link::layer::{LayerContext, LayerStack};
use hetcomm_link::registry::{OpenFailure, OpenRequest, Registry};
use hetcomm_link::{FrameSink, Link};

use crate::comm::OpenEnv;
use crate::error::OpenError;
use crate::runtime::SystemCore;

/// One link crate's registration line: with its feature on, the crate registers its kinds;
/// with it off, the kinds stay known by name (a fleet file may name them, keys kept raw) and
/// opening one says to rebuild with the feature.
macro_rules! link_crate {
    ($registry:ident, $feature:literal, $krate:ident, [$($kind:literal),+] $(, bridges [$($bridge:literal),+])?) => {
        #[cfg(feature = $feature)]
        $krate::register_transports(&mut $registry);
        #[cfg(not(feature = $feature))]
        {
            $($registry.not_built(TransportKind::new($kind), $feature);)+
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
        hetcomm_link_ip::register_transports(&mut registry);
        link_crate!(registry, "bluetooth", hetcomm_link_bluetooth, ["bluetooth"]);
        link_crate!(
            registry,
            "ros1",
            hetcomm_link_ros1,
            ["ros1"],
            bridges["ros1_bridge"]
        );
        link_crate!(
            registry,
            "ros2",
            hetcomm_link_ros2,
            ["ros2"],
            bridges["ros2_bridge"]
        );
        link_crate!(registry, "zenoh", hetcomm_link_zenoh, ["zenoh"]);
        link_crate!(registry, "mqtt", hetcomm_link_mqtt, ["mqtt"]);
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
        global
            .lock()
            .unwrap_or_else(|e| e.into_inner())
            .entry(key.to_string())
            .or_default()
            .clone()
    }

    /// Records that `core` is on in-process transport `name`.
    pub(crate) fn register(&self, name: &str, core: &Arc<SystemCore>) {
        self.systems
            .lock()
            .unwrap_or_else(|e| e.into_inner())
            .insert((name.to_string(), core.id), Arc::downgrade(core));
    }

    /// The open system `id` on in-process transport `name`, if any.
    pub(crate) fn system(&self, name: &str, id: SystemId) -> Option<Arc<SystemCore>> {
        self.systems
            .lock()
            .unwrap_or_else(|e| e.into_inner())
            .get(&(name.to_string(), id))
            .and_then(Weak::upgrade)
            .filter(|c| !c.is_closed())
    }

    fn hub(&self, name: &str) -> InprocHub {
        self.hubs
            .lock()
            .unwrap_or_else(|e| e.into_inner())
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
    if env.sim.is_none()
        && !matches!(t.kind, TransportKind::Inproc | TransportKind::Emulated)
        && registry().factory(t.kind).is_none()
    {
        return Err(unavailable(t, t.kind));
    }
    let stack = layers(fleet, index, local, env).map_err(&failed)?;
    let mut ctx = LayerContext::new(local);
    if env.sim.is_some() {
        ctx = ctx.in_virtual_time();
    }
    let sink = stack.wrap_sink(&ctx, sink);
    let mut opened = match &env.sim {
        Some(net) => OpenedLink {
            link: net.open(index, local, sink),
            local_address: None,
            direct: None,
        },
        None => open_bare(fleet, index, local, sink, env)?,
    };
    if !stack.is_empty() {
        opened.link = stack
            .wrap_link(&ctx, opened.link)
            .map_err(|e| failed(e.into()))?;
        // A message must pass the layers: no hand-over that skips the link.
        opened.direct = None;
    }
    Ok(opened)
}

/// The layers over system `local`'s link of transport `index`, from the router down:
/// emulation for an `emulated` transport, then security for a transport that leaves the
/// process (nearest the link, so that what the emulation delays or drops is a sealed frame's
/// worth of traffic, and nothing reaches the link unsealed).
fn layers(
    fleet: &Fleet,
    index: usize,
    local: SystemId,
    env: &OpenEnv,
) -> Result<LayerStack, OpenFailure> {
    let t = &fleet.transports[index];
    let mut stack = LayerStack::new();
    if let (TransportKind::Emulated, TransportSettings::Emulated(settings)) = (&t.kind, &t.settings)
    {
        let layer = EmulationLayer::from_settings(settings, env.positions.clone(), env.epoch)?;
        stack.push(Arc::new(layer));
    }
    if crate::security::secured(fleet, index, env.sim.is_some()) {
        stack.push(crate::security::layer(fleet, index, local, &env.keys)?);
    }
    Ok(stack)
}

/// Opens transport number `index`'s own link, without its layers.
fn open_bare(
    fleet: &Fleet,
    index: usize,
    local: SystemId,
    sink: Arc<dyn FrameSink>,
    env: &OpenEnv,
) -> Result<OpenedLink, OpenError> {
    let t = &fleet.transports[index];
    let hubs = &env.hubs;
    let system = fleet
        .system(local)
        .map(|s| s.name.clone())
        .unwrap_or_else(|| local.to_string());
    let failed = |e: OpenFailure| OpenError::transport(&t.name, &system, e);
    match (&t.kind, &t.settings) {
        (TransportKind::Inproc, _) => Ok(OpenedLink {
            link: Arc::new(hubs.hub(&t.name).open(local, sink)),
            local_address: None,
            direct: Some(t.name.clone()),
        }),
        (TransportKind::Emulated, TransportSettings::Emulated(settings)) => {
            // The link under the emulation layer: another transport of the fleet (with its own
            // layers), or a private in-process hub.
            match &settings.over {
                Some(over) => {
                    let over_index = fleet
                        .transports
                        .iter()
                        .position(|o| &o.name == over)
                        .ok_or_else(|| {
                            failed(format!("wrapped transport `{over}` not found").into())
                        })?;
                    let inner = open_link(fleet, over_index, local, sink, env)?;
                    let under = inner.local_address.as_deref().unwrap_or("in-process");
                    Ok(OpenedLink {
                        link: inner.link,
                        local_address: Some(format!("emulated over {under}")),
                        direct: None,
                    })
                }
                None => Ok(OpenedLink {
                    link: Arc::new(hubs.hub(&format!("emulated:{}", t.name)).open(local, sink)),
                    local_address: None,
                    direct: None,
                }),
            }
        }
        (&kind, _) => {
            let request = OpenRequest {
                fleet,
                transport: t,
                local,
                sink,
                shapes: &env.shapes,
            };
            match registry().open(request) {
                Some(opened) => {
                    let opened = opened.map_err(failed)?;
                    Ok(OpenedLink {
                        link: opened.link,
                        local_address: opened.local_address,
                        direct: None,
                    })
                }
                None => Err(unavailable(t, kind)),
            }
        }
    }
}

/// The error for a kind without a factory in this build: what to rebuild with, or what to use
/// instead.
fn unavailable(t: &TransportDef, kind: TransportKind) -> OpenError {
    let hint = match kind {
        TransportKind::Ros1 => "rebuild with `--features ros1` to use a ROS master, or map the letter to an `inproc` or `emulated` transport in the fleet file's [letters] table to run without one".to_string(),
        TransportKind::Bluetooth => "rebuild with `--features bluetooth` to use RFCOMM on a machine with Bluetooth, or use an `emulated` transport with profile = \"bluetooth-classic\" to simulate the radio".to_string(),
        _ => match registry().feature_for(kind) {
            Some(feature) => format!("rebuild with `--features {feature}`"),
            None => "choose `inproc` (one process) or another available kind in the fleet file"
                .to_string(),
        },
    };
    OpenError::KindUnavailable {
        transport: t.name.clone(),
        kind,
        hint,
    }
}

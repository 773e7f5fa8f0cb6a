//! The one dispatch point from a transport's kind to the code that opens it.

use std::collections::HashMap;
use std::sync::{Arc, Mutex, OnceLock};

use hetcomm_config::{Fleet, TransportDef, TransportKind};
use hetcomm_core::SystemId;
use hetcomm_link::inproc::InprocHub;
use hetcomm_link::{FrameSink, Link};

use crate::error::OpenError;

/// In-process hubs by transport name: systems opened through the same `Hubs` meet there.
#[derive(Clone, Default)]
pub(crate) struct Hubs {
    hubs: Arc<Mutex<HashMap<String, InprocHub>>>,
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

    fn hub(&self, name: &str) -> InprocHub {
        self.hubs
            .lock()
            .unwrap_or_else(|e| e.into_inner())
            .entry(name.to_string())
            .or_default()
            .clone()
    }
}

/// Opens transport `t` for system `local`, delivering what it receives to `sink`.
pub(crate) fn open_link(
    fleet: &Fleet,
    t: &TransportDef,
    local: SystemId,
    sink: Arc<dyn FrameSink>,
    hubs: &Hubs,
) -> Result<Arc<dyn Link>, OpenError> {
    let system = fleet
        .system(local)
        .map(|s| s.name.clone())
        .unwrap_or_else(|| local.to_string());
    let _ = &system;
    match t.kind {
        TransportKind::Inproc => Ok(Arc::new(hubs.hub(&t.name).open(local, sink))),
        kind => Err(unavailable(t, kind)),
    }
}

fn unavailable(t: &TransportDef, kind: TransportKind) -> OpenError {
    let hint = match kind {
        TransportKind::Ros1 => "map the letter to an `inproc` or `emulated` transport in the fleet file's [letters] table to run without a ROS master",
        TransportKind::Bluetooth => "use an `emulated` transport with profile = \"bluetooth-classic\" to simulate the radio",
        _ => "choose `inproc` (one process) or another available kind in the fleet file",
    };
    OpenError::KindUnavailable {
        transport: t.name.clone(),
        kind,
        hint: hint.to_string(),
    }
}

//! The `ros2` transport factory: its settings half ([`KindSpec`]: the keys and how they are
//! read, `crate::settings`) and its opening half ([`TransportFactory`]).

use std::sync::Arc;

use hetcomm_config::{KindSpec, RegisteredSettings, SettingsReader, TransportKind};
use hetcomm_core::SystemId;
use hetcomm_link::registry::{OpenFailure, OpenRequest, Opened, TransportFactory};
use hetcomm_link::{FrameSink, Link};

use crate::settings::{self, Backend, Ros2Settings};
use crate::{Ros2Link, Ros2OpenError};

/// Opens system `local`'s `ros2` link on the DDS implementation its settings name (`dds`):
/// read through [`Link::readable`] by whoever drives it when `driven`, else by a thread of
/// the link's own.
pub fn open_link(
    local: SystemId,
    names: &[(SystemId, String)],
    settings: &Ros2Settings,
    sink: Arc<dyn FrameSink>,
    driven: bool,
) -> Result<Box<dyn Link>, Ros2OpenError> {
    match (settings.dds, driven) {
        (Backend::RustDds, true) => Ok(Box::new(Ros2Link::open_driven(
            local, names, settings, sink,
        )?)),
        (Backend::RustDds, false) => Ok(Box::new(Ros2Link::open(local, names, settings, sink)?)),
        #[cfg(feature = "cyclone")]
        (Backend::Cyclone, true) => Ok(Box::new(crate::cyclone::CycloneLink::open_driven(
            local, names, settings, sink,
        )?)),
        #[cfg(feature = "cyclone")]
        (Backend::Cyclone, false) => Ok(Box::new(crate::cyclone::CycloneLink::open(
            local, names, settings, sink,
        )?)),
        #[cfg(not(feature = "cyclone"))]
        (Backend::Cyclone, _) => Err(Ros2OpenError::Dds {
            what: "the participant".into(),
            reason: "`dds = \"cyclone\"` needs the cargo feature `cyclone` of \
                     hetcomm-link-ros2 (`ros2-cyclone` of hetcomm)"
                .into(),
        }),
    }
}

/// The kind's name in fleet files: `kind = "ros2"`.
pub fn kind() -> TransportKind {
    TransportKind::new("ros2")
}

/// Reads `ros2` transport tables and opens them as [`Ros2Link`]s.
pub struct Ros2Factory;

impl KindSpec for Ros2Factory {
    fn kind(&self) -> TransportKind {
        kind()
    }

    fn keys(&self) -> &[&'static str] {
        &settings::KEYS
    }

    fn parse(&self, s: &mut SettingsReader<'_, '_>) -> Option<RegisteredSettings> {
        settings::parse(s)
    }
}

impl TransportFactory for Ros2Factory {
    fn kind(&self) -> TransportKind {
        kind()
    }

    fn spec(self: Arc<Self>) -> Option<Arc<dyn KindSpec>> {
        Some(self)
    }

    fn open(&self, request: OpenRequest<'_>) -> Result<Opened, OpenFailure> {
        let ros: &Ros2Settings = request.settings()?;
        let names: Vec<_> = request
            .fleet
            .systems
            .iter()
            .map(|s| (s.id, s.name.clone()))
            .collect();
        // Read by the runtime's reactor or a waiting module thread (`Link::readable`).
        let link = open_link(request.local, &names, ros, request.sink, true)?;
        let topic = names
            .iter()
            .find(|(id, _)| *id == request.local)
            .map(|(_, name)| crate::names::system_topic(&ros.namespace, name))
            .unwrap_or_default();
        let local_address = Some(format!("ros2://{}{topic}", ros.domain_id));
        Ok(Opened {
            link: Arc::from(link),
            local_address,
        })
    }
}

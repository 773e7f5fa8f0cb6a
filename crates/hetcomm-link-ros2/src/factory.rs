//! The `ros2` transport factory: its settings half ([`KindSpec`]: the keys and how they are
//! read, `crate::settings`) and its opening half ([`TransportFactory`]).

use std::sync::Arc;

use hetcomm_config::TransportSettings;
use hetcomm_config::{KindSpec, RegisteredSettings, SettingsReader, TransportKind};
use hetcomm_link::registry::{OpenFailure, OpenRequest, Opened, TransportFactory};

use crate::settings::{self, Ros2Settings};
use crate::Ros2Link;

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
        let TransportSettings::Registered(s) = &request.transport.settings else {
            return Err(format!(
                "expected ros2 settings, found {:?}",
                request.transport.settings
            )
            .into());
        };
        let ros: &Ros2Settings = s
            .downcast_ref()
            .ok_or("the transport's settings are not ros2 settings")?;
        let names: Vec<_> = request
            .fleet
            .systems
            .iter()
            .map(|s| (s.id, s.name.clone()))
            .collect();
        // Read by the runtime's reactor or a waiting module thread (`Link::readable`).
        let link = Ros2Link::open_driven(request.local, &names, ros, request.sink)?;
        let local_address = Some(format!("ros2://{}{}", ros.domain_id, link.topic()));
        Ok(Opened {
            link: Arc::new(link),
            local_address,
        })
    }
}

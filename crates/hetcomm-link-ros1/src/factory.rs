//! The `ros1` transport factory: how the runtime opens a fleet's `ros1` transport. Its
//! settings (`master_uri`, `namespace`, `connect_timeout_ms`: [`Ros1Settings`]) are read by
//! its spec in [`crate::settings`].

use std::sync::Arc;

use hetcomm_config::{KindSpec, TransportKind};
use hetcomm_link::registry::{OpenFailure, OpenRequest, Opened, TransportFactory};

use crate::settings::Ros1Settings;
use crate::{Ros1Config, Ros1Link};

/// Opens `ros1` transports as [`Ros1Link`]s through the transport's ROS master.
pub struct Ros1Factory;

impl TransportFactory for Ros1Factory {
    fn kind(&self) -> TransportKind {
        TransportKind::Ros1
    }

    fn spec(self: Arc<Self>) -> Option<Arc<dyn KindSpec>> {
        Some(self)
    }

    fn open(&self, request: OpenRequest<'_>) -> Result<Opened, OpenFailure> {
        let ros: &Ros1Settings = request.settings()?;
        let names = request
            .fleet
            .systems
            .iter()
            .map(|s| (s.id, s.name.clone()))
            .collect();
        let link = Ros1Link::open(
            request.local,
            &names,
            ros,
            request.sink,
            Ros1Config::default(),
        )?;
        let local_address = Some(format!(
            "ros1://{}{}",
            ros.master_uri.trim_start_matches("http://"),
            link.topic()
        ));
        Ok(Opened {
            link: Arc::new(link),
            local_address,
        })
    }
}

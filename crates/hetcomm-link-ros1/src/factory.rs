//! The `ros1` transport factory: how the runtime opens a fleet's `ros1` transport. Its
//! settings (`master_uri`, `namespace`) are read by the fleet loader itself ([`Ros1Settings`]:
//! the legacy table's `R` names it too), so it only opens.

use std::sync::Arc;

use hetcomm_config::{Ros1Settings, TransportKind, TransportSettings};
use hetcomm_link::registry::{OpenFailure, OpenRequest, Opened, TransportFactory};

use crate::{Ros1Config, Ros1Link};

/// Opens `ros1` transports as [`Ros1Link`]s through the transport's ROS master.
pub struct Ros1Factory;

impl TransportFactory for Ros1Factory {
    fn kind(&self) -> TransportKind {
        TransportKind::Ros1
    }

    fn open(&self, request: OpenRequest<'_>) -> Result<Opened, OpenFailure> {
        let ros: &Ros1Settings = match &request.transport.settings {
            TransportSettings::Ros1(ros) => ros,
            other => return Err(format!("expected ros1 settings, found {other:?}").into()),
        };
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

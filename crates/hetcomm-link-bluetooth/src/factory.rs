//! The `bluetooth` transport factory: how the runtime opens a fleet's `bluetooth` transport.
//! Its settings (`channel`, `addresses`, `addresses_file`: [`BluetoothSettings`]) are read by
//! its spec in [`crate::settings`].

use std::sync::Arc;

use hetcomm_config::{KindSpec, TransportKind};
use hetcomm_link::registry::{OpenFailure, OpenRequest, Opened, TransportFactory};

use crate::settings::BluetoothSettings;
use crate::BluetoothLink;

/// Opens `bluetooth` transports as RFCOMM [`BluetoothLink`]s.
pub struct BluetoothFactory;

impl TransportFactory for BluetoothFactory {
    fn kind(&self) -> TransportKind {
        TransportKind::Bluetooth
    }

    fn spec(self: Arc<Self>) -> Option<Arc<dyn KindSpec>> {
        Some(self)
    }

    fn open(&self, request: OpenRequest<'_>) -> Result<Opened, OpenFailure> {
        let bt: &BluetoothSettings = request.settings()?;
        let config = BluetoothLink::default_config();
        let link = BluetoothLink::open(request.local, bt, request.sink, config)?;
        let local_address = Some(format!("rfcomm://[{}]:{}", link.device(), link.channel()));
        Ok(Opened {
            link: Arc::new(link),
            local_address,
        })
    }
}

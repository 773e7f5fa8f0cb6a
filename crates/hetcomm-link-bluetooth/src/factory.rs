//! The `bluetooth` transport factory: how the runtime opens a fleet's `bluetooth` transport.
//! Its settings (`channel`, `addresses`, `addresses_file`) are read by the fleet loader itself
//! ([`BluetoothSettings`]: the legacy Table 3 files name them too), so it only opens.

use std::sync::Arc;

use hetcomm_config::{BluetoothSettings, TransportKind, TransportSettings};
use hetcomm_link::registry::{OpenFailure, OpenRequest, Opened, TransportFactory};

use crate::BluetoothLink;

/// Opens `bluetooth` transports as RFCOMM [`BluetoothLink`]s.
pub struct BluetoothFactory;

impl TransportFactory for BluetoothFactory {
    fn kind(&self) -> TransportKind {
        TransportKind::Bluetooth
    }

    fn open(&self, request: OpenRequest<'_>) -> Result<Opened, OpenFailure> {
        let bt: &BluetoothSettings = match &request.transport.settings {
            TransportSettings::Bluetooth(bt) => bt,
            other => return Err(format!("expected bluetooth settings, found {other:?}").into()),
        };
        let config = BluetoothLink::default_config();
        let link = BluetoothLink::open(request.local, bt, request.sink, config)?;
        let local_address = Some(format!("rfcomm://[{}]:{}", link.device(), link.channel()));
        Ok(Opened {
            link: Arc::new(link),
            local_address,
        })
    }
}

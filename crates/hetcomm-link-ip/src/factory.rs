//! The `udp` and `tcp` transport factories: how the runtime opens a fleet's `udp` or `tcp`
//! transport. Their settings (`endpoints`, `max_message_bytes`, `max_connections`:
//! [`IpSettings`]) are read by their spec in [`crate::settings`].

use std::collections::BTreeMap;
use std::sync::Arc;

use hetcomm_core::SystemId;
use hetcomm_link::registry::config::{KindSpec, TransportKind};
use hetcomm_link::registry::{OpenFailure, OpenRequest, Opened, TransportFactory};

use crate::settings::{IpSettings, IpSpec};

use crate::stream::StreamConfig;
use crate::{TcpLink, UdpConfig, UdpLink};

/// Opens `udp` transports as [`UdpLink`]s read by the runtime's reactor (`driven`).
pub struct UdpFactory;

/// Opens `tcp` transports as [`TcpLink`]s read by the runtime's reactor (`driven`).
pub struct TcpFactory;

impl TransportFactory for UdpFactory {
    fn kind(&self) -> TransportKind {
        TransportKind::Udp
    }

    fn spec(self: Arc<Self>) -> Option<Arc<dyn KindSpec>> {
        Some(Arc::new(IpSpec(TransportKind::Udp)))
    }

    fn open(&self, request: OpenRequest<'_>) -> Result<Opened, OpenFailure> {
        let ip: &IpSettings = request.settings()?;
        let mut config = if all_loopback(&ip.endpoints) {
            // Loopback has a 64 KiB MTU: fewer, larger datagrams.
            UdpConfig::loopback()
        } else {
            UdpConfig::default()
        };
        if let Some(max) = ip.max_message_bytes {
            config.max_message_bytes = Some(max);
        }
        // The system's reactor reads the socket: a module waiting for a message reads it
        // itself (see `crates/hetcomm/src/reactor.rs`).
        config.driven = true;
        let link = UdpLink::bind(request.local, &ip.endpoints, request.sink, config)?;
        let local_address = Some(format!("udp://{}", link.local_addr()));
        Ok(Opened {
            link: std::sync::Arc::new(link),
            local_address,
        })
    }
}

impl TransportFactory for TcpFactory {
    fn kind(&self) -> TransportKind {
        TransportKind::Tcp
    }

    fn spec(self: Arc<Self>) -> Option<Arc<dyn KindSpec>> {
        Some(Arc::new(IpSpec(TransportKind::Tcp)))
    }

    fn open(&self, request: OpenRequest<'_>) -> Result<Opened, OpenFailure> {
        let ip: &IpSettings = request.settings()?;
        // Read by the waiting module (or the system's background thread), as UDP is.
        let mut config = StreamConfig {
            driven: true,
            ..StreamConfig::default()
        };
        if let Some(max) = ip.max_message_bytes {
            config.max_message_bytes = Some(max);
        }
        if let Some(max) = ip.max_connections {
            config.max_connections = max;
        }
        let link = TcpLink::bind(request.local, &ip.endpoints, request.sink, config)?;
        let local_address = Some(format!("tcp://{}", link.local_addr()));
        Ok(Opened {
            link: std::sync::Arc::new(link),
            local_address,
        })
    }
}

fn all_loopback(endpoints: &BTreeMap<SystemId, String>) -> bool {
    use std::net::ToSocketAddrs;
    endpoints.values().all(|e| {
        e.to_socket_addrs()
            .map(|mut addrs| addrs.all(|a| a.ip().is_loopback()))
            .unwrap_or(false)
    })
}

//! The settings half of the `udp` and `tcp` kinds ([`KindSpec`]): their keys, how they are
//! read from a fleet file's transport table, and what the table check needs of them (every
//! system a pair names has an endpoint).

use std::collections::BTreeMap;

use hetcomm_core::SystemId;
use hetcomm_link::registry::config::{
    Addresses, KindSpec, RegisteredSettings, SettingsReader, TransportKind,
};

/// Settings of `udp` and `tcp` transports.
#[derive(Clone, Debug, PartialEq, Eq)]
pub struct IpSettings {
    /// Each system's listening endpoint, `host:port` (port 0: pick a free port).
    pub endpoints: BTreeMap<SystemId, String>,
    /// Largest message accepted for sending, bytes (None: the codec's limit).
    pub max_message_bytes: Option<usize>,
    /// `tcp` only: most inbound connections a system's listener keeps open at once; further
    /// ones are refused and counted (None: the link's default, 256).
    pub max_connections: Option<usize>,
}

/// Keys of `udp` transports besides the ones every transport has.
const UDP_KEYS: [&str; 2] = ["endpoints", "max_message_bytes"];
/// Keys of `tcp` transports besides the ones every transport has.
const TCP_KEYS: [&str; 3] = ["endpoints", "max_message_bytes", "max_connections"];

/// The `udp` or `tcp` kind's settings spec.
pub(crate) struct IpSpec(pub TransportKind);

impl KindSpec for IpSpec {
    fn kind(&self) -> TransportKind {
        self.0
    }

    fn keys(&self) -> &[&'static str] {
        if self.0 == TransportKind::Tcp {
            &TCP_KEYS
        } else {
            &UDP_KEYS
        }
    }

    fn parse(&self, s: &mut SettingsReader<'_, '_>) -> Option<RegisteredSettings> {
        let endpoints = s.endpoints("endpoints").unwrap_or_else(|| {
            s.missing(
                "endpoints",
                "add `endpoints = { Alpha = \"127.0.0.1:7400\", … }`: one \"host:port\" per system it carries",
            );
            BTreeMap::new()
        });
        let max_message_bytes = s
            .int_in(
                "max_message_bytes",
                1,
                i64::MAX,
                "a size in bytes, e.g. 1048576",
            )
            .map(|n| usize::try_from(n).unwrap_or(usize::MAX));
        let max_connections = s
            .int_in(
                "max_connections",
                1,
                1 << 20,
                "a number of connections, e.g. 256",
            )
            .map(|n| n as usize);
        Some(RegisteredSettings::new(IpSettings {
            endpoints,
            max_message_bytes,
            max_connections,
        }))
    }

    fn addresses(&self, settings: &RegisteredSettings) -> Option<Addresses> {
        let ip: &IpSettings = settings.downcast_ref()?;
        Some(Addresses {
            systems: ip.endpoints.keys().copied().collect(),
            what: "endpoint",
            help: "add `{system} = \"host:port\"` to `endpoints` of transport `{transport}`"
                .to_string(),
        })
    }
}

//! The settings half of the `ros1` kind ([`KindSpec`], implemented by
//! [`Ros1Factory`](crate::factory::Ros1Factory)): its keys, how they are read from a fleet
//! file's transport table, and the settings of the legacy table's `R`.

use hetcomm_config::{KindSpec, LegacyFiles, RegisteredSettings, SettingsReader, TransportKind};

use crate::factory::Ros1Factory;

/// Settings of a `ros1` transport.
#[derive(Clone, Debug, PartialEq, Eq)]
pub struct Ros1Settings {
    /// The master's XML-RPC URI, e.g. `http://127.0.0.1:11311`.
    pub master_uri: String,
    /// Optional topic namespace prepended to each system's topic.
    pub namespace: Option<String>,
    /// `connect_timeout_ms`: how long a send waits for the destination's subscriber to connect
    /// to a new publisher (None: the link's default, 500 ms).
    pub connect_timeout_ms: Option<u64>,
}

impl Default for Ros1Settings {
    /// The master of [`default_master_uri`], no namespace, the link's connect timeout.
    fn default() -> Self {
        Ros1Settings {
            master_uri: default_master_uri(),
            namespace: None,
            connect_timeout_ms: None,
        }
    }
}

/// The ROS master a `ros1` transport uses when it names none: `ROS_MASTER_URI`, as every ROS
/// 1 tool reads it, else `http://localhost:11311`.
pub fn default_master_uri() -> String {
    std::env::var("ROS_MASTER_URI")
        .ok()
        .filter(|s| !s.trim().is_empty())
        .unwrap_or_else(|| "http://localhost:11311".to_string())
}

/// Keys of `ros1` transports besides the ones every transport has.
const KEYS: [&str; 3] = ["master_uri", "namespace", "connect_timeout_ms"];

impl KindSpec for Ros1Factory {
    fn kind(&self) -> TransportKind {
        TransportKind::Ros1
    }

    fn keys(&self) -> &[&'static str] {
        &KEYS
    }

    fn parse(&self, s: &mut SettingsReader<'_, '_>) -> Option<RegisteredSettings> {
        let help = "write the master's XML-RPC URI, e.g. \"http://127.0.0.1:11311\"";
        let master_uri = match s.string("master_uri", help) {
            None => default_master_uri(),
            Some(uri) if uri.starts_with("http://") || uri.starts_with("https://") => uri,
            Some(uri) => {
                let message = format!(
                    "`transports.{}.master_uri` must be an http:// URI, found `{uri}`",
                    s.transport()
                );
                s.error("master_uri", message, help);
                uri
            }
        };
        let namespace = s.string(
            "namespace",
            "write a ROS namespace in quotes, e.g. \"/hetcomm\"",
        );
        let connect_timeout_ms = s
            .int_in(
                "connect_timeout_ms",
                1,
                600_000,
                "milliseconds a send waits for the subscriber, e.g. 500",
            )
            .map(|ms| ms as u64);
        Some(RegisteredSettings::new(Ros1Settings {
            master_uri,
            namespace,
            connect_timeout_ms,
        }))
    }

    fn implicit(&self, _legacy: &LegacyFiles<'_>) -> Option<RegisteredSettings> {
        Some(RegisteredSettings::new(Ros1Settings::default()))
    }
}

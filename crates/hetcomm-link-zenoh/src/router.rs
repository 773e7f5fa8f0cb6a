//! A Zenoh router in this process: what `hetcomm zenoh-router` runs, and what tests start when
//! they need a router. It is the `zenoh` crate's own router mode (the same routing code as
//! `zenohd`, without its plugins): peers and clients that `connect` to it reach each other
//! through it, and it forwards gossip so that peers find each other.

use zenoh::Wait;

use crate::config::check_endpoint;
use crate::OpenError;

/// A running Zenoh router session; closed when dropped.
pub struct ZenohRouter {
    session: Option<zenoh::Session>,
    listen: Vec<String>,
}

impl ZenohRouter {
    /// Starts a router listening on `listen` (e.g. `tcp/0.0.0.0:7447`), with multicast scouting
    /// on or off. Fails, naming the endpoint, when it cannot listen there.
    pub fn start(listen: &[String], multicast_scouting: bool) -> Result<ZenohRouter, OpenError> {
        Self::start_with_lease(listen, multicast_scouting, 10_000)
    }

    /// [`ZenohRouter::start`] with Zenoh's lease for the router's sessions (how long the
    /// others wait before they consider the router gone; Zenoh's default is 10 000 ms).
    pub fn start_with_lease(
        listen: &[String],
        multicast_scouting: bool,
        lease_ms: u32,
    ) -> Result<ZenohRouter, OpenError> {
        if listen.is_empty() {
            return Err(OpenError::Setting {
                key: "listen".into(),
                reason: "a router needs at least one endpoint to listen on".into(),
            });
        }
        let mut c = zenoh::Config::default();
        let mut set = |key: &str, value: String| {
            c.insert_json5(key, &value).map_err(|e| OpenError::Setting {
                key: key.to_string(),
                reason: e.to_string(),
            })
        };
        for e in listen {
            check_endpoint(e).map_err(|reason| OpenError::Setting {
                key: "listen".into(),
                reason,
            })?;
        }
        set("mode", "\"router\"".into())?;
        let quoted: Vec<String> = listen.iter().map(|e| format!("\"{e}\"")).collect();
        set("listen/endpoints", format!("[{}]", quoted.join(",")))?;
        set("listen/exit_on_failure", "true".into())?;
        set("connect/endpoints", "[]".into())?;
        set("transport/link/tx/lease", lease_ms.to_string())?;
        set("scouting/multicast/enabled", multicast_scouting.to_string())?;
        let session = zenoh::open(c).wait().map_err(|e| OpenError::Unreachable {
            mode: "router",
            endpoints: listen.join(", "),
            timeout_ms: 0,
            reason: e.to_string(),
        })?;
        Ok(ZenohRouter {
            session: Some(session),
            listen: listen.to_vec(),
        })
    }

    /// The endpoints it listens on, as given.
    pub fn listen(&self) -> &[String] {
        &self.listen
    }

    /// The router's Zenoh id.
    pub fn zenoh_id(&self) -> String {
        self.session
            .as_ref()
            .map(|s| s.zid().to_string())
            .unwrap_or_default()
    }

    /// Closes the router (every session connected through it loses it).
    pub fn close(mut self) {
        if let Some(s) = self.session.take() {
            let _ = s.close().wait();
        }
    }
}

impl Drop for ZenohRouter {
    fn drop(&mut self) {
        if let Some(s) = self.session.take() {
            let _ = s.close().wait();
        }
    }
}

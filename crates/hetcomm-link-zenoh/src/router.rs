//! A Zenoh router in this process: what `hetcomm zenoh-router` runs, and what tests start when
//! they need a router. It is the `zenoh` crate's own router mode (the same routing code as
//! `zenohd`, without its plugins): peers and clients that `connect` to it reach each other
//! through it, and it forwards gossip so that peers find each other.

use zenoh::Wait;

use crate::config::check_endpoint;
use crate::ZenohOpenError;

/// Zenoh's runtime settings for a router process, in the syntax of Zenoh's `ZENOH_RUNTIME`
/// environment variable: 32 `rx` threads instead of Zenoh's 2.
///
/// Why: when a client vanishes (its host cut off), the router drops its session once the lease
/// expires, and closing the session's TCP socket blocks the `rx` thread that does it for up to
/// 10 s (Zenoh's TCP link sets `SO_LINGER` to 10 s, and data for the dead client is never
/// acknowledged). With 2 `rx` threads, 20 clients cut at once stall all of the router's
/// receiving for about 100 s: it routes nothing, healthy clients' leases expire in turn, and
/// the clients that come back are dropped again (`docs/zenoh.md`, "Routers and vanished
/// clients"). Each `rx` thread is idle otherwise.
pub const ROUTER_RUNTIME: &str = "(rx: (worker_threads: 32))";

/// Sets `ZENOH_RUNTIME` to [`ROUTER_RUNTIME`] unless it is set already. For the start of a
/// router process's `main`: Zenoh reads the variable once, when it first starts its threads,
/// and changing the environment while other threads may read it is unsound, so call it before
/// any other thread runs and before anything of Zenoh's.
pub fn use_router_runtime() {
    if std::env::var_os("ZENOH_RUNTIME").is_none() {
        std::env::set_var("ZENOH_RUNTIME", ROUTER_RUNTIME);
    }
}

/// A running Zenoh router session; closed when dropped.
pub struct ZenohRouter {
    session: Option<zenoh::Session>,
    listen: Vec<String>,
}

impl ZenohRouter {
    /// Starts a router listening on `listen` (e.g. `tcp/0.0.0.0:7447`), with multicast scouting
    /// on or off. Fails, naming the endpoint, when it cannot listen there.
    pub fn start(
        listen: &[String],
        multicast_scouting: bool,
    ) -> Result<ZenohRouter, ZenohOpenError> {
        Self::start_with_lease(listen, multicast_scouting, 10_000)
    }

    /// [`ZenohRouter::start`] with Zenoh's lease for the router's sessions (how long the
    /// others wait before they consider the router gone; Zenoh's default is 10 000 ms).
    ///
    /// A router that serves clients which may vanish together (a host cut off) needs more of
    /// Zenoh's `rx` threads than Zenoh's default: see [`use_router_runtime`].
    pub fn start_with_lease(
        listen: &[String],
        multicast_scouting: bool,
        lease_ms: u32,
    ) -> Result<ZenohRouter, ZenohOpenError> {
        if listen.is_empty() {
            return Err(ZenohOpenError::Setting {
                key: "listen".into(),
                reason: "a router needs at least one endpoint to listen on".into(),
            });
        }
        let mut c = zenoh::Config::default();
        let mut set = |key: &str, value: String| {
            c.insert_json5(key, &value)
                .map_err(|e| ZenohOpenError::Setting {
                    key: key.to_string(),
                    reason: e.to_string(),
                })
        };
        for e in listen {
            check_endpoint(e).map_err(|reason| ZenohOpenError::Setting {
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
        let session = zenoh::open(c)
            .wait()
            .map_err(|e| ZenohOpenError::Unreachable {
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

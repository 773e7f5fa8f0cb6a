//! The transport's settings and the Zenoh configuration built from them.

use zenoh::Wait;

use crate::ZenohOpenError;

/// How a system's session takes part in the Zenoh network.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum Mode {
    /// A Zenoh peer: talks directly to the peers it finds (multicast scouting, gossip through a
    /// router, or `connect` endpoints), and through routers to the rest.
    Peer,
    /// A Zenoh client: talks only to one router (from `connect`, or found by scouting), which
    /// routes everything.
    Client,
}

impl Mode {
    /// The name Zenoh's configuration uses.
    pub fn as_str(self) -> &'static str {
        match self {
            Mode::Peer => "peer",
            Mode::Client => "client",
        }
    }
}

/// A `zenoh` transport's settings (`docs/zenoh.md`, `docs/config.md`).
#[derive(Clone, Debug, PartialEq, Eq)]
pub struct ZenohSettings {
    /// `mode`: peer (default) or client.
    pub mode: Mode,
    /// `connect`: Zenoh endpoints to connect to (`tcp/10.0.0.1:7447`), usually routers.
    pub connect: Vec<String>,
    /// `listen`: Zenoh endpoints to listen on (peers only); empty uses Zenoh's default (a
    /// peer listens on every interface, on a port the system picks).
    pub listen: Vec<String>,
    /// `multicast_scouting`: find peers and routers by UDP multicast (Zenoh's default, true).
    pub multicast_scouting: bool,
    /// `prefix`: the first chunks of every key expression of this transport (default
    /// `hetcomm`); fleets that share a Zenoh network each take their own.
    pub prefix: String,
    /// `presence_timeout_ms`: how long the first send to a destination never seen on the
    /// network waits for its liveliness token to appear; afterwards sends to it fail at once
    /// until it appears (default 5000).
    pub presence_timeout_ms: u32,
    /// `open_timeout_ms`: how long opening waits for a `connect` endpoint (default 5000).
    pub open_timeout_ms: u32,
    /// `lease_ms`: Zenoh's lease for this session (default 10000, Zenoh's): the others
    /// consider the session gone, and its token with it, when they hear nothing from it for
    /// this long (a cut link, a dead host).
    pub lease_ms: u32,
}

impl Default for ZenohSettings {
    fn default() -> Self {
        ZenohSettings {
            mode: Mode::Peer,
            connect: Vec::new(),
            listen: Vec::new(),
            multicast_scouting: true,
            prefix: "hetcomm".into(),
            presence_timeout_ms: 5000,
            open_timeout_ms: 5000,
            lease_ms: 10_000,
        }
    }
}

/// Whether `prefix` can start this transport's key expressions: a Zenoh key expression
/// without wildcards (`*`, `$*`, `**`) or `?`/`#`, no empty chunk, no `@` chunk (Zenoh's
/// admin space), no leading or trailing `/`. The error says what is wrong.
pub fn validate_prefix(prefix: &str) -> Result<(), String> {
    if prefix.is_empty() {
        return Err("the prefix is empty".into());
    }
    let probe = format!("{prefix}/sys/x");
    if let Err(e) = zenoh::key_expr::OwnedKeyExpr::try_from(probe.clone()) {
        return Err(format!("Zenoh rejects `{probe}` as a key expression: {e}"));
    }
    if prefix.contains('*') || prefix.contains('$') {
        return Err("the prefix may not contain wildcards (`*`, `**`, `$*`)".into());
    }
    if prefix.split('/').any(|c| c.starts_with('@')) {
        return Err("chunks starting with `@` are Zenoh's own (admin space)".into());
    }
    Ok(())
}

/// Checks one endpoint the way Zenoh parses it (`tcp/host:port`).
pub(crate) fn check_endpoint(endpoint: &str) -> Result<(), String> {
    let parsed: zenoh::config::EndPoint = endpoint
        .parse()
        .map_err(|e| format!("`{endpoint}` is not a Zenoh endpoint: {e}"))?;
    let protocol = parsed.protocol();
    if protocol.as_str() != "tcp" {
        return Err(format!(
            "`{endpoint}`: this build carries Zenoh over `tcp/…` endpoints only, found `{}`",
            protocol.as_str()
        ));
    }
    Ok(())
}

fn json_list(items: &[String]) -> String {
    let quoted: Vec<String> = items
        .iter()
        .map(|e| format!("\"{}\"", e.replace('\\', "\\\\").replace('"', "\\\"")))
        .collect();
    format!("[{}]", quoted.join(","))
}

/// The Zenoh configuration for `s`.
pub(crate) fn zenoh_config(s: &ZenohSettings) -> Result<zenoh::Config, ZenohOpenError> {
    let mut c = zenoh::Config::default();
    let mut set = |key: &str, value: String| {
        c.insert_json5(key, &value)
            .map_err(|e| ZenohOpenError::Setting {
                key: key.to_string(),
                reason: e.to_string(),
            })
    };
    for e in s.connect.iter().chain(&s.listen) {
        check_endpoint(e).map_err(|reason| ZenohOpenError::Setting {
            key: "endpoint".into(),
            reason,
        })?;
    }
    set("mode", format!("\"{}\"", s.mode.as_str()))?;
    set("connect/endpoints", json_list(&s.connect))?;
    if s.mode == Mode::Peer && !s.listen.is_empty() {
        set("listen/endpoints", json_list(&s.listen))?;
    }
    set(
        "scouting/multicast/enabled",
        s.multicast_scouting.to_string(),
    )?;
    set("transport/link/tx/lease", s.lease_ms.to_string())?;
    if !s.connect.is_empty() {
        // Opening fails, naming the endpoints, when none answers in time; once open, Zenoh
        // keeps reconnecting to them (a router that restarts is found again).
        set("connect/timeout_ms", s.open_timeout_ms.to_string())?;
        set("connect/exit_on_failure", "true".into())?;
    }
    Ok(c)
}

/// Zenoh's error text without the ` at /path/to/zenoh/src/file.rs:123.` it appends.
pub(crate) fn without_source_location(text: &str) -> String {
    match text.find(" at /") {
        Some(i) if text[i..].contains(".rs:") => text[..i].trim_end_matches('.').to_string(),
        _ => text.to_string(),
    }
}

/// Opens the session for `s`, turning a connect failure into [`ZenohOpenError::Unreachable`].
pub(crate) fn open_session(s: &ZenohSettings) -> Result<zenoh::Session, ZenohOpenError> {
    let config = zenoh_config(s)?;
    zenoh::open(config).wait().map_err(|e| {
        let reason = without_source_location(&e.to_string());
        let endpoints = if s.connect.is_empty() {
            s.listen.join(", ")
        } else {
            s.connect.join(", ")
        };
        if endpoints.is_empty() {
            ZenohOpenError::Zenoh(format!("open: {reason}"))
        } else {
            ZenohOpenError::Unreachable {
                mode: s.mode.as_str(),
                endpoints,
                timeout_ms: s.open_timeout_ms,
                reason,
            }
        }
    })
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn prefixes_zenoh_rejects_are_refused_with_a_reason() {
        assert_eq!(validate_prefix("hetcomm"), Ok(()));
        assert_eq!(validate_prefix("site-a/fleet 1"), Ok(()));
        for bad in [
            "", "a/*", "a/**/b", "/a", "a/", "a//b", "a?b", "a#b", "@/x", "a$*b",
        ] {
            assert!(validate_prefix(bad).is_err(), "{bad:?} accepted");
        }
    }

    #[test]
    fn endpoints_are_checked() {
        assert_eq!(check_endpoint("tcp/127.0.0.1:7447"), Ok(()));
        assert!(check_endpoint("127.0.0.1:7447").is_err());
        assert!(check_endpoint("udp/127.0.0.1:7447")
            .unwrap_err()
            .contains("tcp/"));
    }
}

//! The transport's settings: what the fleet file's keys become (`docs/mqtt.md`).

use std::path::PathBuf;

/// The QoS of the frames' publishes.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum Qos {
    /// At most once: the broker confirms nothing.
    AtMostOnce,
    /// At least once: the broker answers each publish with a PUBACK (it has the frame; the
    /// destination may not), and the client publishes again what was not acknowledged when a
    /// persistent session resumes.
    AtLeastOnce,
}

impl Qos {
    pub(crate) fn mqtt(self) -> rumqttc::v5::mqttbytes::QoS {
        match self {
            Qos::AtMostOnce => rumqttc::v5::mqttbytes::QoS::AtMostOnce,
            Qos::AtLeastOnce => rumqttc::v5::mqttbytes::QoS::AtLeastOnce,
        }
    }
}

/// One broker: where it listens and whether the connection is TLS.
#[derive(Clone, Debug, PartialEq, Eq)]
pub struct Broker {
    /// Host name or IP address.
    pub host: String,
    /// TCP port.
    pub port: u16,
    /// `mqtts://`: TLS (the CA from `ca_file`, else the operating system's roots).
    pub tls: bool,
}

impl Broker {
    /// Parses `mqtt://host:port`, `mqtts://host:port` or `host:port` (`mqtt://`); the port
    /// defaults to 1883 (8883 for `mqtts://`). The error says what is wrong.
    pub fn parse(text: &str) -> Result<Broker, String> {
        let (tls, rest) = match text.split_once("://") {
            Some(("mqtt" | "tcp", rest)) => (false, rest),
            Some(("mqtts" | "ssl" | "tls", rest)) => (true, rest),
            Some((scheme, _)) => {
                return Err(format!(
                    "`{text}`: unknown scheme `{scheme}://` (this build speaks `mqtt://` and `mqtts://`)"
                ))
            }
            None => (false, text),
        };
        let rest = rest.trim_end_matches('/');
        if rest.is_empty() || rest.contains('/') {
            return Err(format!("`{text}` is not a broker address"));
        }
        let (host, port) = match rest.rsplit_once(':') {
            Some((h, p)) if !h.ends_with(':') => {
                let port: u16 = p
                    .parse()
                    .ok()
                    .filter(|p| *p != 0)
                    .ok_or_else(|| format!("`{text}`: `{p}` is not a port from 1 to 65535"))?;
                (h, port)
            }
            _ => (rest, if tls { 8883 } else { 1883 }),
        };
        let host = host.trim_start_matches('[').trim_end_matches(']');
        if host.is_empty() {
            return Err(format!("`{text}` names no host"));
        }
        Ok(Broker {
            host: host.to_string(),
            port,
            tls,
        })
    }
}

impl std::fmt::Display for Broker {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        let scheme = if self.tls { "mqtts" } else { "mqtt" };
        match self.host.contains(':') {
            true => write!(f, "{scheme}://[{}]:{}", self.host, self.port),
            false => write!(f, "{scheme}://{}:{}", self.host, self.port),
        }
    }
}

/// An `mqtt` transport's settings (`docs/mqtt.md`).
#[derive(Clone, Debug, PartialEq, Eq)]
pub struct MqttSettings {
    /// `broker` (one) or `brokers` (several, tried in turn): where the broker listens.
    pub brokers: Vec<Broker>,
    /// `prefix`: the first topic levels (default `hetcomm`).
    pub prefix: String,
    /// `fleet`: the topic level after the prefix; None takes the fleet file's `name`, else
    /// `fleet`.
    pub fleet: Option<String>,
    /// `client_id_prefix`: a system's MQTT client id is this, the fleet level, `-` and its
    /// name (default `hetcomm-`).
    pub client_id_prefix: String,
    /// `keep_alive_s`: seconds between pings on an idle connection; the broker publishes a
    /// system's last will 1.5 times this after its connection went silent (default 10, at
    /// least 5).
    pub keep_alive_s: u16,
    /// `clean_session`: start each connection with a fresh session (default true); false
    /// keeps subscriptions and queued QoS 1 frames at the broker for `session_expiry_s`.
    pub clean_session: bool,
    /// `session_expiry_s`: how long the broker keeps a persistent session after its
    /// connection closes (default 300; only with `clean_session = false`).
    pub session_expiry_s: u32,
    /// `qos`: 0 or 1 (default 1).
    pub qos: Qos,
    /// `username`.
    pub username: Option<String>,
    /// `password` (only with `username`).
    pub password: Option<String>,
    /// `ca_file`: PEM certificates that sign the broker's (turns TLS on).
    pub ca_file: Option<PathBuf>,
    /// `client_cert_file`: this system's PEM certificate chain, for brokers that require
    /// client certificates (with `client_key_file`).
    pub client_cert_file: Option<PathBuf>,
    /// `client_key_file`: the PEM private key of `client_cert_file`.
    pub client_key_file: Option<PathBuf>,
    /// `open_timeout_ms`: how long opening waits for the broker (default 5000).
    pub open_timeout_ms: u32,
    /// `reconnect_wait_ms`: how long a send waits for the connection to come back while the
    /// broker is away before it fails (default 2000; 0 fails at once).
    pub reconnect_wait_ms: u32,
    /// `presence_timeout_ms`: how long the first send to a system not yet announced online
    /// waits for its announcement (default 3000).
    pub presence_timeout_ms: u32,
}

impl Default for MqttSettings {
    fn default() -> Self {
        MqttSettings {
            brokers: Vec::new(),
            prefix: "hetcomm".into(),
            fleet: None,
            client_id_prefix: "hetcomm-".into(),
            keep_alive_s: 10,
            clean_session: true,
            session_expiry_s: 300,
            qos: Qos::AtLeastOnce,
            username: None,
            password: None,
            ca_file: None,
            client_cert_file: None,
            client_key_file: None,
            open_timeout_ms: 5000,
            reconnect_wait_ms: 2000,
            presence_timeout_ms: 3000,
        }
    }
}

impl MqttSettings {
    /// Settings for one broker, every other key at its default.
    pub fn with_broker(broker: &str) -> Result<MqttSettings, String> {
        Ok(MqttSettings {
            brokers: vec![Broker::parse(broker)?],
            ..MqttSettings::default()
        })
    }

    /// Whether connections use TLS: an `mqtts://` broker, a CA file or a client certificate.
    pub fn tls(&self) -> bool {
        self.ca_file.is_some()
            || self.client_cert_file.is_some()
            || self.brokers.iter().any(|b| b.tls)
    }

    /// The brokers as the errors name them: `mqtt://a:1883, mqtt://b:1883`.
    pub fn broker_list(&self) -> String {
        let names: Vec<String> = self.brokers.iter().map(Broker::to_string).collect();
        names.join(", ")
    }
}

/// Whether `level` can be one or more whole topic levels of every topic: not empty, no MQTT
/// wildcard (`+`, `#`), no NUL, no empty level, no leading `$` (the broker's own topics). The
/// error says what is wrong.
pub fn validate_levels(level: &str) -> Result<(), String> {
    if level.is_empty() {
        return Err("it is empty".into());
    }
    if level.contains(['+', '#']) {
        return Err("MQTT wildcards (`+`, `#`) cannot be part of a topic name".into());
    }
    if level.contains('\0') {
        return Err("it contains a NUL character".into());
    }
    if level.split('/').any(str::is_empty) {
        return Err("it has an empty level (a leading, trailing or doubled `/`)".into());
    }
    if level.starts_with('$') {
        return Err("topics starting with `$` are the broker's own".into());
    }
    Ok(())
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn broker_addresses_parse_with_default_ports() {
        let b = |host: &str, port, tls| Broker {
            host: host.into(),
            port,
            tls,
        };
        assert_eq!(
            Broker::parse("mqtt://10.0.0.1:1884"),
            Ok(b("10.0.0.1", 1884, false))
        );
        assert_eq!(
            Broker::parse("broker.lan"),
            Ok(b("broker.lan", 1883, false))
        );
        assert_eq!(
            Broker::parse("mqtts://broker.lan"),
            Ok(b("broker.lan", 8883, true))
        );
        assert_eq!(Broker::parse("[::1]:1883"), Ok(b("::1", 1883, false)));
        assert_eq!(b("::1", 1883, false).to_string(), "mqtt://[::1]:1883");
        assert!(Broker::parse("ws://x:80")
            .unwrap_err()
            .contains("unknown scheme"));
        assert!(Broker::parse("x:0").unwrap_err().contains("not a port"));
        assert!(Broker::parse("mqtt://").is_err());
        assert!(Broker::parse("mqtt://a/b").is_err());
    }

    #[test]
    fn topic_levels_mqtt_rejects_are_refused() {
        assert_eq!(validate_levels("hetcomm/site-a"), Ok(()));
        for bad in ["", "a/+", "#", "a//b", "/a", "a/", "$SYS"] {
            assert!(validate_levels(bad).is_err(), "{bad:?} accepted");
        }
    }
}

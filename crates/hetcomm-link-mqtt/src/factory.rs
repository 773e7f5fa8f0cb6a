//! The `mqtt` transport factory: its fleet-file keys (checked by `hetcomm validate` with
//! `file:line:column`, like every kind's) and how the runtime opens a system's link.

use std::path::{Path, PathBuf};
use std::sync::Arc;

use hetcomm_config::{KindSpec, RegisteredSettings, SettingsReader, TransportKind};
use hetcomm_link::registry::{OpenFailure, OpenRequest, Opened, TransportFactory};

use crate::settings::{validate_levels, Broker, MqttSettings, Qos};
use crate::{MqttLink, MqttLinkConfig};

/// The `mqtt` kind: settings and opening.
pub struct MqttFactory;

/// The keys of an `mqtt` transport, besides the ones every transport has.
pub const KEYS: [&str; 17] = [
    CONNECTION_KEYS[0],
    CONNECTION_KEYS[1],
    "prefix",
    "fleet",
    "client_id_prefix",
    CONNECTION_KEYS[2],
    "clean_session",
    "session_expiry_s",
    CONNECTION_KEYS[3],
    CONNECTION_KEYS[4],
    CONNECTION_KEYS[5],
    CONNECTION_KEYS[6],
    CONNECTION_KEYS[7],
    CONNECTION_KEYS[8],
    CONNECTION_KEYS[9],
    CONNECTION_KEYS[10],
    "presence_timeout_ms",
];

const BROKER_HELP: &str =
    "write the broker's address, e.g. \"mqtt://192.168.1.10:1883\" (or \"mqtts://…\" for TLS)";

impl KindSpec for MqttFactory {
    fn kind(&self) -> TransportKind {
        TransportKind::Mqtt
    }

    fn keys(&self) -> &[&'static str] {
        &KEYS
    }

    fn parse(&self, s: &mut SettingsReader<'_, '_>) -> Option<RegisteredSettings> {
        let mut m = MqttSettings::default();
        let mut ok = parse_connection(s, &mut m);
        for (key, slot) in [("prefix", &mut m.prefix)] {
            if let Some(p) = read_levels(s, key, &mut ok) {
                *slot = p;
            }
        }
        m.fleet = read_levels(s, "fleet", &mut ok);
        if s.has("client_id_prefix") {
            match s.string(
                "client_id_prefix",
                "write the client-id prefix in quotes, e.g. \"site-a-\"",
            ) {
                Some(p) => m.client_id_prefix = p,
                None => ok = false,
            }
        }
        if s.has("clean_session") {
            match s.boolean("clean_session", "write true or false") {
                Some(b) => m.clean_session = b,
                None => ok = false,
            }
        }
        if s.has("session_expiry_s") {
            match s.int_in(
                "session_expiry_s",
                0,
                u32::MAX as i64,
                "seconds the broker keeps a persistent session after its connection closes",
            ) {
                Some(v) => m.session_expiry_s = v as u32,
                None => ok = false,
            }
            if m.clean_session {
                s.error(
                    "session_expiry_s",
                    "`session_expiry_s` applies to persistent sessions only",
                    "add `clean_session = false`, or leave `session_expiry_s` out",
                );
                ok = false;
            }
        }
        if s.has("presence_timeout_ms") {
            match s.int_in("presence_timeout_ms", 0, 600_000, "milliseconds, e.g. 2000") {
                Some(v) => m.presence_timeout_ms = v as u32,
                None => ok = false,
            }
        }
        ok.then(|| RegisteredSettings::new(m))
    }
}

/// The keys of the connection to the broker, which the `mqtt` and `mqtt_bridge` kinds share.
pub const CONNECTION_KEYS: [&str; 11] = [
    "broker",
    "brokers",
    "keep_alive_s",
    "qos",
    "username",
    "password",
    "ca_file",
    "client_cert_file",
    "client_key_file",
    "open_timeout_ms",
    "reconnect_wait_ms",
];

/// Reads the connection keys ([`CONNECTION_KEYS`]) into `m`, reporting problems through `s`;
/// false if there was one.
pub(crate) fn parse_connection(s: &mut SettingsReader<'_, '_>, m: &mut MqttSettings) -> bool {
    let mut ok = true;
    let texts = match (s.has("broker"), s.has("brokers")) {
        (true, true) => {
            s.error(
                "brokers",
                "`broker` and `brokers` both name brokers",
                "keep one: `broker = \"…\"` for one broker, `brokers = [\"…\", \"…\"]` for several",
            );
            None
        }
        (true, false) => s.string("broker", BROKER_HELP).map(|b| vec![b]),
        (false, true) => s.strings("brokers", BROKER_HELP),
        (false, false) => {
            s.missing("broker", "add `broker = \"mqtt://127.0.0.1:1883\"`");
            None
        }
    };
    let key = if s.has("brokers") {
        "brokers"
    } else {
        "broker"
    };
    match texts {
        Some(texts) if texts.is_empty() => {
            s.error(key, "`brokers` is empty", BROKER_HELP);
            ok = false;
        }
        Some(texts) => {
            for text in texts {
                match Broker::parse(&text) {
                    Ok(b) => m.brokers.push(b),
                    Err(why) => {
                        s.error(key, why, BROKER_HELP);
                        ok = false;
                    }
                }
            }
        }
        None => ok = false,
    }
    if s.has("keep_alive_s") {
        match s.int_in(
            "keep_alive_s",
            5,
            65535,
            "seconds; the broker declares a silent system gone after 1.5 times this",
        ) {
            Some(v) => m.keep_alive_s = v as u16,
            None => ok = false,
        }
    }
    if s.has("qos") {
        match s.int_in(
            "qos",
            0,
            1,
            "0 (at most once) or 1 (at least once; the broker acknowledges each publish)",
        ) {
            Some(0) => m.qos = Qos::AtMostOnce,
            Some(_) => m.qos = Qos::AtLeastOnce,
            None => ok = false,
        }
    }
    for key in ["username", "password"] {
        if s.has(key) {
            match s.string(key, "write it in quotes") {
                Some(v) if key == "username" => m.username = Some(v),
                Some(v) => m.password = Some(v),
                None => ok = false,
            }
        }
    }
    if m.password.is_some() && !s.has("username") {
        s.error(
            "password",
            "a `password` without a `username`",
            "add `username = \"…\"`",
        );
        ok = false;
    }
    for key in ["ca_file", "client_cert_file", "client_key_file"] {
        if !s.has(key) {
            continue;
        }
        let Some(path) = s.string(key, "write the path of a PEM file in quotes") else {
            ok = false;
            continue;
        };
        let path = Some(PathBuf::from(path));
        match key {
            "ca_file" => m.ca_file = path,
            "client_cert_file" => m.client_cert_file = path,
            _ => m.client_key_file = path,
        }
    }
    if m.client_cert_file.is_some() != m.client_key_file.is_some() {
        let (key, other) = match m.client_cert_file.is_some() {
            true => ("client_cert_file", "client_key_file"),
            false => ("client_key_file", "client_cert_file"),
        };
        s.error(
                key,
                format!("`{key}` without `{other}`"),
                format!("add `{other}`: a client certificate needs its private key, and the other way round"),
            );
        ok = false;
    }
    for (key, slot, min) in [
        ("open_timeout_ms", &mut m.open_timeout_ms, 1),
        ("reconnect_wait_ms", &mut m.reconnect_wait_ms, 0),
    ] {
        if s.has(key) {
            match s.int_in(key, min, 600_000, "milliseconds, e.g. 2000") {
                Some(v) => *slot = v as u32,
                None => ok = false,
            }
        }
    }
    ok
}

/// Reads `key` as topic levels (`prefix`, `fleet`), reporting what MQTT would refuse.
fn read_levels(s: &mut SettingsReader<'_, '_>, key: &str, ok: &mut bool) -> Option<String> {
    if !s.has(key) {
        return None;
    }
    let Some(text) = s.string(key, "write the topic levels in quotes, e.g. \"site-a\"") else {
        *ok = false;
        return None;
    };
    match validate_levels(&text) {
        Ok(()) => Some(text),
        Err(why) => {
            s.error(
                key,
                format!("`{key}` is not usable in MQTT topics: {why}"),
                "use levels of letters, digits, `-`, `_` and `.` separated by `/`, e.g. \"hetcomm/site-a\"",
            );
            *ok = false;
            None
        }
    }
}

/// `path` against the fleet file's directory when it is relative.
fn resolve(path: &mut Option<PathBuf>, base: Option<&Path>) {
    if let (Some(p), Some(base)) = (path.as_mut(), base) {
        if p.is_relative() {
            *p = base.join(&*p);
        }
    }
}

/// The TLS files of `settings` against the directory of `fleet`'s file, where relative.
pub(crate) fn resolve_files(settings: &mut MqttSettings, fleet: &hetcomm_config::Fleet) {
    let base = fleet.source.as_deref().and_then(Path::parent);
    for path in [
        &mut settings.ca_file,
        &mut settings.client_cert_file,
        &mut settings.client_key_file,
    ] {
        resolve(path, base);
    }
}

/// The topic level after the prefix: the transport's `fleet`, else the fleet file's `name`,
/// else `fleet`.
fn fleet_level(settings: &MqttSettings, fleet_name: Option<&str>) -> Result<String, String> {
    match (&settings.fleet, fleet_name) {
        (Some(f), _) => Ok(f.clone()),
        (None, Some(name)) => {
            validate_levels(name).map_err(|why| {
                format!("the fleet's name `{name}` cannot be an MQTT topic level ({why}): set `fleet = \"…\"` in the transport")
            })?;
            Ok(name.to_string())
        }
        (None, None) => Ok("fleet".into()),
    }
}

impl TransportFactory for MqttFactory {
    fn kind(&self) -> TransportKind {
        TransportKind::Mqtt
    }

    fn spec(self: Arc<Self>) -> Option<Arc<dyn KindSpec>> {
        Some(self)
    }

    fn open(&self, request: OpenRequest<'_>) -> Result<Opened, OpenFailure> {
        let mut settings: MqttSettings = request.settings::<MqttSettings>()?.clone();
        resolve_files(&mut settings, request.fleet);
        let fleet = fleet_level(&settings, request.fleet.name.as_deref())?;
        // Two transports on one broker under the same topics would each carry every frame of
        // the other (a system's links both subscribe to its one topic), and their clients would
        // share an id and push each other off.
        for other in &request.fleet.transports {
            let Some(o) = other.settings.registered::<MqttSettings>() else {
                continue;
            };
            if other.name != request.transport.name
                && o.brokers == settings.brokers
                && o.prefix == settings.prefix
                && fleet_level(o, request.fleet.name.as_deref()).ok().as_ref() == Some(&fleet)
            {
                return Err(format!(
                    "transports `{}` and `{}` are both on {} under `{}/{fleet}`: give one its own `fleet` (or `prefix`)",
                    request.transport.name,
                    other.name,
                    settings.broker_list(),
                    settings.prefix
                )
                .into());
            }
        }
        let systems = request
            .fleet
            .systems
            .iter()
            .map(|s| (s.id, s.name.clone()))
            .collect();
        let link = MqttLink::open(
            MqttLinkConfig {
                local: request.local,
                systems,
                fleet,
                settings,
            },
            request.sink,
        )?;
        let local_address = Some(link.address());
        Ok(Opened {
            link: Arc::new(link),
            local_address,
        })
    }
}

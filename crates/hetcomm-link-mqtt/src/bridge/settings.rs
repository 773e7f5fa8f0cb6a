//! An `mqtt_bridge` table: the connection keys the `mqtt` kind has, the `robot`, and the
//! `publish` / `subscribe` mappings (`"TOPIC" = "MODULE TYPE_ID [FIELD:TYPE …] [+CAPTURE …]"`),
//! checked by `hetcomm validate` at `file:line:column`.

use hetcomm_config::SettingsReader;

use super::json::{Field, TYPE_NAMES};
use crate::factory::{parse_connection, CONNECTION_KEYS};
use crate::settings::MqttSettings;

/// The keys of an `mqtt_bridge` transport, besides the ones every transport has.
pub const KEYS: [&str; 15] = [
    CONNECTION_KEYS[0],
    CONNECTION_KEYS[1],
    CONNECTION_KEYS[2],
    CONNECTION_KEYS[3],
    CONNECTION_KEYS[4],
    CONNECTION_KEYS[5],
    CONNECTION_KEYS[6],
    CONNECTION_KEYS[7],
    CONNECTION_KEYS[8],
    CONNECTION_KEYS[9],
    CONNECTION_KEYS[10],
    "client_id_prefix",
    "robot",
    "publish",
    "subscribe",
];

/// One mapping between a hetcomm (module, message type) and an MQTT topic of JSON payloads.
#[derive(Clone, Debug, PartialEq, Eq)]
pub struct JsonMapping {
    /// The MQTT topic (publish) or topic filter with `+` and a final `#` (subscribe).
    pub topic: String,
    /// The hetcomm module: on the robot (publish) or on this system (subscribe).
    pub module: String,
    /// The hetcomm message type id.
    pub message: u32,
    /// The JSON members every payload has (checked both ways, per message).
    pub fields: Vec<Field>,
    /// Subscribe only: the fields the topic's `+` levels go into, in order
    /// (`+serialNumber`), as strings.
    pub captures: Vec<String>,
}

impl JsonMapping {
    /// The topic levels `topic` (a published topic) gives this mapping's filter: its captures
    /// by name, or None if it does not match.
    pub fn matches(&self, topic: &str) -> Option<Vec<(String, String)>> {
        let mut captured = Vec::new();
        let mut names = self.captures.iter();
        let mut levels = topic.split('/');
        for f in self.topic.split('/') {
            if f == "#" {
                return Some(captured);
            }
            let level = levels.next()?;
            match f {
                "+" => {
                    if let Some(name) = names.next() {
                        captured.push((name.clone(), level.to_string()));
                    }
                }
                f if f == level => {}
                _ => return None,
            }
        }
        levels.next().is_none().then_some(captured)
    }
}

/// An `mqtt_bridge` transport's settings (`docs/mqtt.md`, "Plain MQTT JSON clients").
#[derive(Clone, Debug, PartialEq, Eq)]
pub struct BridgeSettings {
    /// The connection to the broker: `broker(s)`, credentials, TLS, `keep_alive_s`, `qos`,
    /// `open_timeout_ms`, `reconnect_wait_ms`, `client_id_prefix`.
    pub connection: MqttSettings,
    /// The external system (a plain MQTT client, not hetcomm): `robot = "Tango"`.
    pub robot: String,
    /// `[transports.x.publish]`: sends to (robot, module) of a message type become JSON
    /// publishes on a topic.
    pub publish: Vec<JsonMapping>,
    /// `[transports.x.subscribe]`: JSON publishes on a topic (filter) become messages of a
    /// type from the robot, to this system's module.
    pub subscribe: Vec<JsonMapping>,
}

const MAPPING_HELP: &str = "write \"MODULE TYPE_ID FIELD:TYPE …\", e.g. \
     \"Drive 50 orderId:string orderUpdateId:integer nodes:array\"";

/// Why `topic` cannot be a mapping's topic (`filter`: a subscribe mapping's, which may have
/// `+` levels and a final `#`).
pub fn check_topic(topic: &str, filter: bool) -> Result<(), String> {
    if topic.is_empty() {
        return Err("it is empty".into());
    }
    if topic.starts_with('$') {
        return Err("topics starting with `$` are the broker's own".into());
    }
    if topic.contains('\0') {
        return Err("it contains a NUL character".into());
    }
    let levels: Vec<&str> = topic.split('/').collect();
    for (i, level) in levels.iter().enumerate() {
        let wild = level.contains(['+', '#']);
        if wild && !filter {
            return Err("a published topic has no wildcards (`+`, `#`)".into());
        }
        if wild && *level != "+" && !(*level == "#" && i == levels.len() - 1) {
            return Err("`+` must be a whole level and `#` the whole last level".into());
        }
    }
    Ok(())
}

fn mappings(s: &mut SettingsReader<'_, '_>, key: &str, ok: &mut bool) -> Vec<JsonMapping> {
    let Some(entries) = s.string_table(key, MAPPING_HELP) else {
        *ok &= !s.has(key);
        return Vec::new();
    };
    let subscribe = key == "subscribe";
    let mut out = Vec::new();
    for (topic, text) in entries {
        let bad = |s: &mut SettingsReader<'_, '_>, message: String, help: &str| {
            s.error_entry(key, &topic, message, help);
        };
        if let Err(why) = check_topic(&topic, subscribe) {
            bad(
                s,
                format!("`{topic}` is not an MQTT topic {key} can use: {why}"),
                "write the topic's levels, e.g. \"uagv/v2/acme/tango/order\"",
            );
            *ok = false;
            continue;
        }
        let parts: Vec<&str> = text.split_whitespace().collect();
        let (module, id, rest) = match parts[..] {
            [module, id, ref rest @ ..] => (module, id, rest),
            _ => {
                let m = format!(
                    "mapping of `{topic}` must start with MODULE and TYPE_ID, found {text:?}"
                );
                bad(s, m, MAPPING_HELP);
                *ok = false;
                continue;
            }
        };
        let Ok(message) = id.parse::<u32>() else {
            let m = format!("mapping of `{topic}`: `{id}` is not a message type id");
            bad(s, m, "the number in the message's #[message(id = N)]");
            *ok = false;
            continue;
        };
        let mut fields = Vec::new();
        let mut captures = Vec::new();
        let mut good = true;
        for part in rest {
            if let Some(name) = part.strip_prefix('+') {
                if !subscribe || name.is_empty() {
                    let m = format!(
                        "mapping of `{topic}`: `{part}` captures a topic level, which only a \
                         subscribe mapping with `+` levels has"
                    );
                    bad(
                        s,
                        m,
                        "write `+FIELD` in a subscribe mapping whose topic has a `+` level",
                    );
                    good = false;
                    break;
                }
                captures.push(name.to_string());
                continue;
            }
            match Field::parse(part) {
                Ok(f) => fields.push(f),
                Err(why) => {
                    let help =
                        format!("fields are FIELD:TYPE or FIELD:TYPE? with a type of {TYPE_NAMES}");
                    bad(s, format!("mapping of `{topic}`: {why}"), &help);
                    good = false;
                    break;
                }
            }
        }
        let pluses = topic.split('/').filter(|l| *l == "+").count();
        if good && captures.len() > pluses {
            let m = format!(
                "mapping of `{topic}` names {} captures, but the topic has {pluses} `+` level(s)",
                captures.len()
            );
            bad(s, m, "one `+FIELD` per `+` level, in order");
            good = false;
        }
        if !good {
            *ok = false;
            continue;
        }
        out.push(JsonMapping {
            topic,
            module: module.to_string(),
            message,
            fields,
            captures,
        });
    }
    out
}

/// Reads an `mqtt_bridge` table; problems are reported through `s`, None if there was one.
pub fn parse(s: &mut SettingsReader<'_, '_>) -> Option<BridgeSettings> {
    let mut connection = MqttSettings::default();
    let mut ok = parse_connection(s, &mut connection);
    if s.has("client_id_prefix") {
        match s.string("client_id_prefix", "write the client-id prefix in quotes") {
            Some(p) => connection.client_id_prefix = p,
            None => ok = false,
        }
    }
    let robot = match s.has("robot") {
        true => s.string(
            "robot",
            "the name of the MQTT robot's system in quotes, e.g. \"Tango\"",
        ),
        false => {
            s.missing(
                "robot",
                "add `robot = \"NAME\"`: the system that is a plain MQTT client",
            );
            None
        }
    };
    ok &= robot.is_some();
    // A plain MQTT client neither acknowledges hetcomm messages nor opens secured sessions.
    if s.string("delivery", "").as_deref() != Some("unacknowledged") {
        s.error(
            "delivery",
            format!(
                "transport `{}` (kind mqtt_bridge) carries plain JSON publishes, which nobody \
                 acknowledges",
                s.transport()
            ),
            "add `delivery = \"unacknowledged\"`: sends end as Sent (without confirmation)",
        );
        ok = false;
    }
    if s.string("security", "").as_deref() != Some("none") {
        s.error(
            "security",
            format!(
                "transport `{}` (kind mqtt_bridge) carries plain JSON publishes: a plain MQTT \
                 client cannot open hetcomm's secured sessions",
                s.transport()
            ),
            "add `security = \"none\"` (see docs/mqtt.md, \"Plain MQTT JSON clients\")",
        );
        ok = false;
    }
    let publish = mappings(s, "publish", &mut ok);
    let subscribe = mappings(s, "subscribe", &mut ok);
    if ok && publish.is_empty() && subscribe.is_empty() {
        s.error(
            "publish",
            "an mqtt_bridge maps no topic",
            "add a [transports.NAME.publish] or [transports.NAME.subscribe] section",
        );
        ok = false;
    }
    ok.then_some(BridgeSettings {
        connection,
        robot: robot?,
        publish,
        subscribe,
    })
}

#[cfg(test)]
mod tests {
    use super::*;

    fn mapping(topic: &str, captures: &[&str]) -> JsonMapping {
        JsonMapping {
            topic: topic.into(),
            module: "M".into(),
            message: 1,
            fields: vec![],
            captures: captures.iter().map(|c| c.to_string()).collect(),
        }
    }

    #[test]
    fn filters_match_topics_and_capture_their_levels() {
        let m = mapping("uagv/v2/+/+/state", &["manufacturer", "serial"]);
        assert_eq!(
            m.matches("uagv/v2/acme/tango/state"),
            Some(vec![
                ("manufacturer".into(), "acme".into()),
                ("serial".into(), "tango".into())
            ])
        );
        assert_eq!(m.matches("uagv/v2/acme/tango/order"), None);
        assert_eq!(m.matches("uagv/v2/acme/tango/state/x"), None);
        assert_eq!(m.matches("uagv/v2/acme/state"), None);
        let all = mapping("uagv/#", &[]);
        assert_eq!(all.matches("uagv/v2/a"), Some(vec![]));
        assert_eq!(mapping("a/b", &[]).matches("a/b"), Some(vec![]));
    }

    #[test]
    fn topics_are_checked() {
        assert_eq!(check_topic("uagv/v2/a/b/order", false), Ok(()));
        assert!(check_topic("uagv/+/x", false).is_err());
        assert_eq!(check_topic("uagv/+/x/#", true), Ok(()));
        assert!(check_topic("uagv/a+/x", true).is_err());
        assert!(check_topic("uagv/#/x", true).is_err());
        assert!(check_topic("$SYS/x", true).is_err());
    }
}

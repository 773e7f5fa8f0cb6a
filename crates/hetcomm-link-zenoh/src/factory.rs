//! The `zenoh` transport factory: its fleet-file keys (checked by `hetcomm validate` with
//! `file:line:column`, like every kind's) and how the runtime opens a system's link.

use std::sync::Arc;

use hetcomm_config::{KindSpec, RegisteredSettings, SettingsReader, TransportKind};
use hetcomm_link::registry::{OpenFailure, OpenRequest, Opened, TransportFactory};

use crate::config::check_endpoint;
use crate::{validate_prefix, Mode, ZenohLink, ZenohLinkConfig, ZenohSettings};

/// The `zenoh` kind: settings and opening.
pub struct ZenohFactory;

/// The keys of a `zenoh` transport, besides the ones every transport has.
pub const KEYS: [&str; 8] = [
    "mode",
    "connect",
    "listen",
    "multicast_scouting",
    "prefix",
    "presence_timeout_ms",
    "open_timeout_ms",
    "lease_ms",
];

impl KindSpec for ZenohFactory {
    fn kind(&self) -> TransportKind {
        TransportKind::Zenoh
    }

    fn keys(&self) -> &[&'static str] {
        &KEYS
    }

    fn parse(&self, s: &mut SettingsReader<'_, '_>) -> Option<RegisteredSettings> {
        let mut ok = true;
        let mut z = ZenohSettings::default();
        if s.has("mode") {
            match s.choice("mode", ("mode", "modes"), &["peer", "client"]) {
                Some(0) => z.mode = Mode::Peer,
                Some(_) => z.mode = Mode::Client,
                None => ok = false,
            }
        }
        let endpoint_help = "a list of Zenoh endpoints, e.g. [\"tcp/192.168.1.10:7447\"]";
        for key in ["connect", "listen"] {
            if !s.has(key) {
                continue;
            }
            let Some(list) = s.strings(key, endpoint_help) else {
                ok = false;
                continue;
            };
            for e in &list {
                if let Err(why) = check_endpoint(e) {
                    s.error(key, why, endpoint_help);
                    ok = false;
                }
            }
            match key {
                "connect" => z.connect = list,
                _ => z.listen = list,
            }
        }
        if z.mode == Mode::Client && !z.listen.is_empty() {
            s.error(
                "listen",
                "a Zenoh client does not listen",
                "leave `listen` out, or use `mode = \"peer\"`",
            );
            ok = false;
        }
        if s.has("multicast_scouting") {
            match s.boolean("multicast_scouting", "write true or false") {
                Some(b) => z.multicast_scouting = b,
                None => ok = false,
            }
        }
        if z.mode == Mode::Client && z.connect.is_empty() && !z.multicast_scouting {
            s.error(
                "connect",
                "a Zenoh client needs a router: `connect` is empty and multicast scouting is off",
                "add `connect = [\"tcp/ROUTER:7447\"]`",
            );
            ok = false;
        }
        if s.has("prefix") {
            match s.string("prefix", "write the key-expression prefix in quotes") {
                Some(p) => match validate_prefix(&p) {
                    Ok(()) => z.prefix = p,
                    Err(why) => {
                        s.error(
                            "prefix",
                            format!("`prefix` is not a usable Zenoh key expression: {why}"),
                            "use chunks of letters, digits, `-`, `_` and `.` separated by `/`, e.g. \"hetcomm/site-a\"",
                        );
                        ok = false;
                    }
                },
                None => ok = false,
            }
        }
        for (key, slot) in [
            ("presence_timeout_ms", &mut z.presence_timeout_ms),
            ("open_timeout_ms", &mut z.open_timeout_ms),
        ] {
            if s.has(key) {
                match s.int_in(key, 1, 600_000, "milliseconds, e.g. 2000") {
                    Some(v) => *slot = v as u32,
                    None => ok = false,
                }
            }
        }
        if s.has("lease_ms") {
            match s.int_in(
                "lease_ms",
                500,
                600_000,
                "milliseconds; Zenoh's default is 10000",
            ) {
                Some(v) => z.lease_ms = v as u32,
                None => ok = false,
            }
        }
        ok.then(|| RegisteredSettings::new(z))
    }
}

impl TransportFactory for ZenohFactory {
    fn kind(&self) -> TransportKind {
        TransportKind::Zenoh
    }

    fn spec(self: Arc<Self>) -> Option<Arc<dyn KindSpec>> {
        Some(self)
    }

    fn open(&self, request: OpenRequest<'_>) -> Result<Opened, OpenFailure> {
        let settings: ZenohSettings = request.settings::<ZenohSettings>()?.clone();
        let systems = request
            .fleet
            .systems
            .iter()
            .map(|s| (s.id, s.name.clone()))
            .collect();
        let local_address = Some(format!(
            "zenoh://{}",
            crate::data_key(
                &settings.prefix,
                &request
                    .fleet
                    .systems
                    .iter()
                    .find(|s| s.id == request.local)
                    .map(|s| s.name.clone())
                    .unwrap_or_default()
            )
        ));
        let link = ZenohLink::open(
            ZenohLinkConfig {
                local: request.local,
                systems,
                settings,
            },
            request.sink,
        )?;
        Ok(Opened {
            link: Arc::new(link),
            local_address,
        })
    }
}

//! The `shm` transport factory: its fleet-file keys (checked by `hetcomm validate` with
//! `file:line:column`, like every kind's) and how the runtime opens a system's link.

use std::sync::Arc;

use hetcomm_config::{KindSpec, RegisteredSettings, SettingsReader, TransportKind};
use hetcomm_link::registry::{OpenFailure, OpenRequest, Opened, TransportFactory};

use crate::settings::{service_name, validate_part, ShmSettings};
use crate::{ShmLink, ShmLinkConfig};

/// The `shm` kind: settings and opening.
pub struct ShmFactory;

/// The kind's name in fleet files.
pub const KIND: &str = "shm";

/// The keys of an `shm` transport, besides the ones every transport has.
pub const KEYS: [&str; 9] = [
    "prefix",
    "fleet",
    "max_frame",
    "initial_frame",
    "queue_depth",
    "max_publishers",
    "max_subscribers",
    "liveness_ms",
    "send_wait_ms",
];

impl KindSpec for ShmFactory {
    fn kind(&self) -> TransportKind {
        TransportKind::new(KIND)
    }

    fn keys(&self) -> &[&'static str] {
        &KEYS
    }

    fn parse(&self, s: &mut SettingsReader<'_, '_>) -> Option<RegisteredSettings> {
        let mut ok = true;
        let mut m = ShmSettings::default();
        for key in ["prefix", "fleet"] {
            if !s.has(key) {
                continue;
            }
            let help = "letters, digits, `-`, `_` and `.`, parts separated by `/`";
            match s.string(key, help) {
                Some(p) => match validate_part(&p) {
                    Ok(()) if key == "prefix" => m.prefix = p,
                    Ok(()) => m.fleet = Some(p),
                    Err(why) => {
                        s.error(key, format!("`{key}` `{p}`: {why}"), help);
                        ok = false;
                    }
                },
                None => ok = false,
            }
        }
        let max_frame_limit =
            (hetcomm_core::wire::HEADER_LEN + hetcomm_core::wire::MAX_PAYLOAD) as i64;
        let ints: [(&str, i64, i64, &str); 7] = [
            (
                "max_frame",
                64,
                max_frame_limit,
                "bytes, the largest frame a send takes (default 1 MiB + 64 KiB)",
            ),
            (
                "initial_frame",
                64,
                max_frame_limit,
                "bytes each sample of a publisher starts with (default 66560)",
            ),
            (
                "queue_depth",
                1,
                4096,
                "frames a destination's queue holds (default 16)",
            ),
            (
                "max_publishers",
                1,
                1024,
                "publishers per destination (default: the fleet's systems and one more)",
            ),
            (
                "max_subscribers",
                1,
                64,
                "subscribers per destination (default 1, the destination itself)",
            ),
            (
                "liveness_ms",
                10,
                60_000,
                "milliseconds between looks for peers that died (default 100)",
            ),
            (
                "send_wait_ms",
                0,
                60_000,
                "milliseconds a send waits for room in a full queue (default 200)",
            ),
        ];
        for (key, min, max, help) in ints {
            if !s.has(key) {
                continue;
            }
            let Some(v) = s.int_in(key, min, max, help) else {
                ok = false;
                continue;
            };
            match key {
                "max_frame" => m.max_frame = v as usize,
                "initial_frame" => m.initial_frame = v as usize,
                "queue_depth" => m.queue_depth = v as usize,
                "max_publishers" => m.max_publishers = Some(v as usize),
                "max_subscribers" => m.max_subscribers = v as usize,
                "liveness_ms" => m.liveness_ms = v as u32,
                _ => m.send_wait_ms = v as u32,
            }
        }
        if !s.has("initial_frame") {
            // The default start fits the largest frame when that is smaller.
            m.initial_frame = m.initial_frame.min(m.max_frame);
        }
        if ok && m.initial_frame > m.max_frame {
            s.error(
                "initial_frame",
                format!(
                    "`initial_frame` ({}) is larger than `max_frame` ({})",
                    m.initial_frame, m.max_frame
                ),
                "make `initial_frame` at most `max_frame`",
            );
            ok = false;
        }
        ok.then(|| RegisteredSettings::new(m))
    }
}

impl TransportFactory for ShmFactory {
    fn kind(&self) -> TransportKind {
        TransportKind::new(KIND)
    }

    fn spec(self: Arc<Self>) -> Option<Arc<dyn KindSpec>> {
        Some(self)
    }

    /// True: shared memory never leaves the host (docs/shm.md, "Security").
    fn host_local(&self) -> bool {
        true
    }

    fn open(&self, request: OpenRequest<'_>) -> Result<Opened, OpenFailure> {
        let settings: ShmSettings = request.settings::<ShmSettings>()?.clone();
        let fleet = settings
            .fleet
            .clone()
            .or_else(|| request.fleet.name.clone())
            .unwrap_or_else(|| "fleet".into());
        validate_part(&fleet).map_err(|why| format!("fleet name `{fleet}`: {why}"))?;
        let systems: Vec<_> = request
            .fleet
            .systems
            .iter()
            .map(|s| (s.id, s.name.clone()))
            .collect();
        let local_name = systems
            .iter()
            .find(|(id, _)| *id == request.local)
            .map(|(_, n)| n.clone())
            .unwrap_or_default();
        let local_address = Some(format!(
            "shm://{}",
            service_name(&settings.prefix, &fleet, &local_name)
        ));
        let link = ShmLink::open(
            ShmLinkConfig {
                local: request.local,
                systems,
                fleet,
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

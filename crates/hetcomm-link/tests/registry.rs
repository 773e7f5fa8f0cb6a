//! A transport kind added from outside the fleet loader, as a link crate adds one: a toy
//! `loopback` kind with its own keys registers its factory, a fleet file using it parses (and
//! its mistakes are reported at file:line:column like any other), and the registry opens it.

use std::sync::Arc;

use hetcomm_config::{parse_str, parse_str_with, KindSpec, RegisteredSettings, SettingsReader};
use hetcomm_config::{TransportKind, TransportSettings};
use hetcomm_core::SystemId;
use hetcomm_link::conformance::CollectSink;
use hetcomm_link::inproc::InprocHub;
use hetcomm_link::registry::{OpenFailure, OpenRequest, Opened, Registry, TransportFactory};

/// The toy kind's settings.
#[derive(Debug, PartialEq)]
struct LoopbackSettings {
    capacity: u32,
    label: Option<String>,
}

/// The toy kind's factory: settings and opening in one place, as a link crate writes it.
#[derive(Default)]
struct Loopback {
    hub: InprocHub,
}

fn loopback() -> TransportKind {
    TransportKind::new("loopback")
}

impl KindSpec for Loopback {
    fn kind(&self) -> TransportKind {
        loopback()
    }

    fn keys(&self) -> &[&'static str] {
        &["capacity", "label"]
    }

    fn parse(&self, s: &mut SettingsReader<'_, '_>) -> Option<RegisteredSettings> {
        let capacity = match s.has("capacity") {
            true => s.int_in("capacity", 1, 1024, "frames held at once, e.g. 64")?,
            false => {
                s.missing("capacity", "add `capacity = 64`");
                return None;
            }
        };
        let label = s.string("label", "write a label in quotes");
        if label.as_deref() == Some("") {
            s.error("label", "`label` cannot be empty", "leave it out instead");
            return None;
        }
        Some(RegisteredSettings::new(LoopbackSettings {
            capacity: capacity as u32,
            label,
        }))
    }
}

impl TransportFactory for Loopback {
    fn kind(&self) -> TransportKind {
        loopback()
    }

    fn spec(self: Arc<Self>) -> Option<Arc<dyn KindSpec>> {
        Some(self)
    }

    fn open(&self, request: OpenRequest<'_>) -> Result<Opened, OpenFailure> {
        let TransportSettings::Registered(settings) = &request.transport.settings else {
            return Err("not loopback settings".into());
        };
        let settings: &LoopbackSettings =
            settings.downcast_ref().ok_or("settings of another kind")?;
        Ok(Opened {
            link: Arc::new(self.hub.open(request.local, request.sink)),
            local_address: Some(format!("loopback:{}", settings.capacity)),
        })
    }
}

/// The crate's one registration function, as `hetcomm_link_ip::register_transports` is.
fn register_transports(registry: &mut Registry) {
    registry.register(Loopback::default());
}

fn fleet_text(settings: &str) -> String {
    format!(
        r#"[systems]
Alpha = 0
Bravo = 1

[transports.lo]
kind = "loopback"
{settings}

[table]
columns = ["Alpha", "Bravo"]
Alpha = ["X", "lo"]
Bravo = ["lo", "X"]
"#
    )
}

#[test]
fn a_registered_kind_parses_reports_located_errors_and_opens() {
    let mut registry = Registry::new();
    register_transports(&mut registry);
    assert_eq!(registry.registered().collect::<Vec<_>>(), [loopback()]);

    // Parses, with typed settings the factory reads back.
    let text = fleet_text("capacity = 64\nlabel = \"bench\"");
    let fleet = parse_str_with(&text, "lo.toml", None, registry.kinds()).expect("valid");
    let t = fleet.transport("lo").expect("lo");
    assert_eq!(t.kind, loopback());
    assert_eq!(t.kind.to_string(), "loopback");
    let TransportSettings::Registered(settings) = &t.settings else {
        panic!("registered settings expected, got {:?}", t.settings);
    };
    assert_eq!(
        settings.downcast_ref::<LoopbackSettings>(),
        Some(&LoopbackSettings {
            capacity: 64,
            label: Some("bench".into())
        })
    );

    // Mistakes in its keys are located, worded like the built-in kinds', and listed together
    // with the file's other problems.
    let text = fleet_text("capacity = 0\ncapacty = 3\nattempts = 0");
    let errors = parse_str_with(&text, "lo.toml", None, registry.kinds()).unwrap_err();
    assert_eq!(
        errors.to_string(),
        "lo.toml:7:12: `transports.lo.capacity` must be from 1 to 1024, found 0\n  \
         help: frames held at once, e.g. 64\n\
         lo.toml:8:1: unknown key `capacty` in `transports.lo`\n  \
         help: did you mean `capacity`?\n\
         lo.toml:9:12: `transports.lo.attempts` must be at least 1, found 0\n  \
         help: attempts counts the first transmission too; the thesis used 3"
    );
    let errors = parse_str_with(&fleet_text(""), "lo.toml", None, registry.kinds()).unwrap_err();
    assert_eq!(
        errors.to_string(),
        "lo.toml:5:1: transport `lo` (kind loopback) is missing required setting `capacity`\n  \
         help: add `capacity = 64`"
    );

    // Opens through the registry, and carries frames.
    let sink_b = CollectSink::new();
    let open = |local: u16, sink| {
        registry
            .open(OpenRequest {
                fleet: &fleet,
                transport: t,
                local: SystemId(local),
                sink,
                shapes: &hetcomm_link::shape::NO_SHAPES,
                host: hetcomm_link::registry::STANDALONE,
            })
            .expect("loopback is registered")
            .expect("opens")
    };
    let a = open(0, CollectSink::new());
    let _b = open(1, sink_b.clone());
    assert_eq!(a.local_address.as_deref(), Some("loopback:64"));
    a.link.send(SystemId(1), b"frame").expect("sent");
    assert_eq!(sink_b.frames()[0].bytes, b"frame");
}

#[test]
fn without_its_registration_the_kind_is_unknown_and_unopenable() {
    let text = fleet_text("capacity = 64");
    let errors = parse_str(&text, "lo.toml", None).unwrap_err();
    assert!(
        errors
            .to_string()
            .starts_with("lo.toml:6:8: unknown transport kind `loopback`"),
        "{errors}"
    );

    // A kind the fleet file knows but no factory opens: the registry says so with None.
    let text = r#"[systems]
Alpha = 0
Bravo = 1
[transports.z]
kind = "zenoh"
[table]
columns = ["Alpha", "Bravo"]
Alpha = ["X", "z"]
Bravo = ["z", "X"]
"#;
    let fleet = parse_str(text, "z.toml", None).expect("zenoh keys are kept raw");
    let registry = Registry::new();
    let opened = registry.open(OpenRequest {
        fleet: &fleet,
        transport: &fleet.transports[0],
        local: SystemId(0),
        sink: CollectSink::new(),
        shapes: &hetcomm_link::shape::NO_SHAPES,
        host: hetcomm_link::registry::STANDALONE,
    });
    assert!(opened.is_none());
}

#[test]
fn a_kind_not_built_stays_known_by_name_and_names_its_feature() {
    let mut registry = Registry::new();
    registry.not_built(loopback(), "loopback");
    assert_eq!(registry.feature_for(loopback()), Some("loopback"));
    assert_eq!(registry.registered().count(), 0);
    // The loader knows the name; its keys, unchecked, are kept raw, as zenoh's are.
    let text = fleet_text("capacity = 0");
    let fleet = parse_str_with(&text, "lo.toml", None, registry.kinds()).expect("known by name");
    let t = fleet.transport("lo").expect("lo");
    assert_eq!(t.kind, loopback());
    let TransportSettings::Raw(keys) = &t.settings else {
        panic!("raw keys expected, got {:?}", t.settings);
    };
    assert_eq!(keys.get("capacity").map(String::as_str), Some("0"));
    // Nothing opens it.
    let opened = registry.open(OpenRequest {
        fleet: &fleet,
        transport: t,
        local: SystemId(0),
        sink: CollectSink::new(),
        shapes: &hetcomm_link::shape::NO_SHAPES,
        host: hetcomm_link::registry::STANDALONE,
    });
    assert!(opened.is_none());
}

//! Transport kinds from outside this crate: the settings half of a transport factory.
//!
//! The fleet loader models no kind itself. Every kind, `inproc`, `emulated`, `udp`, `tcp`,
//! `ros1` and `bluetooth` included, is described by a [`KindSpec`], written in the kind's own
//! crate: its name, its keys, a `parse` function and
//! what the table check needs to know of its settings ([`KindSpec::addresses`]). A program collects the specs of the kinds compiled into it in a
//! [`Kinds`] table (the `hetcomm` crate does this from its transport registry, one line per
//! kind) and passes it to [`crate::load_with`] / [`crate::parse_str_with`].
//!
//! Why parsing happens here, in the loader's own pass, rather than later over a copy of the
//! keys: a spec's `parse` reads the transport's table through a [`SettingsReader`], which
//! reports through the same helpers, with the same wording, as the built-in kinds do, at the
//! `file:line:column` of the offending value, into the same list of errors. One run of `hetcomm
//! validate` therefore lists a registered kind's problems together with every other problem
//! of the file, sorted by position.
//!
//! The loader itself checks the keys every transport shares (`kind`, `delivery`, `attempts`,
//! …) and reports keys that are neither shared nor in [`KindSpec::keys`], with a "did you
//! mean". The other names of [`TransportKind::ALL`] (`udp`, `tcp`, `ros1`, `bluetooth`,
//! `zenoh`, `mqtt`, `dds`) are known without a spec: their keys are kept raw
//! ([`crate::TransportSettings::Raw`]) until a crate registers a spec for them, which then
//! takes over. A program that opens links loads through its registry's [`Kinds`] (the
//! `hetcomm` crate's `hetcomm::config::parse_str` does), so it sees every kind compiled in.

use std::collections::{BTreeMap, BTreeSet};
use std::sync::Arc;

pub use crate::fleet_toml::SettingsReader;
use crate::model::{RegisteredSettings, TransportKind};

/// The settings half of a transport kind: its keys and how to read them. Implemented by the
/// kind's crate next to the code that opens it (`hetcomm_link::registry::TransportFactory`).
pub trait KindSpec: Send + Sync {
    /// The kind, as written in `kind = "…"`.
    fn kind(&self) -> TransportKind;

    /// The kind's own keys, besides the ones every transport shares. Any other key of the
    /// transport's table is reported as unknown before [`KindSpec::parse`] is called.
    fn keys(&self) -> &[&'static str];

    /// Reads and validates the kind's keys. Report every problem through `settings` (it
    /// locates them) and return None when there was one; the loader then keeps the transport
    /// as defined but without settings, so the table does not report it again.
    fn parse(&self, settings: &mut SettingsReader<'_, '_>) -> Option<RegisteredSettings>;

    /// The systems a transport of this kind has an address for, when the kind needs one for
    /// every system it carries (`udp`'s `endpoints`): the loader then reports each system at
    /// an end of a table pair that has none, in the kind's words. The default, None, is for
    /// kinds that need no address per system (a broker, a master, a shared segment).
    fn addresses(&self, settings: &RegisteredSettings) -> Option<Addresses> {
        let _ = settings;
        None
    }

    /// The settings of the transport a legacy table's default letter stands for when the
    /// fleet defines no transport of that name (`R`: `ros1` on the default master; `B`:
    /// `bluetooth` with the addresses of the thesis's address file; see
    /// [`crate::load_legacy`]). The default, None, is for kinds no legacy letter names.
    fn implicit(&self, legacy: &LegacyFiles<'_>) -> Option<RegisteredSettings> {
        let _ = legacy;
        None
    }

    /// Whether a transport of this kind, unless layered over another
    /// ([`SettingsReader::layered_over`]), keeps its frames in the process (`emulated`'s
    /// private hub): the fleet's [`crate::Fleet::leaves_process`] and the default of its
    /// security follow it. The default, false, is for kinds whose frames leave the process.
    fn in_process(&self) -> bool {
        false
    }
}

/// What the thesis's files give the transport of a default letter ([`KindSpec::implicit`]).
#[derive(Clone, Copy, Debug)]
pub struct LegacyFiles<'a> {
    /// The Bluetooth address file's addresses (Tables 3, 8, 18), and the file's name as
    /// errors give it; None when no such file was given.
    pub bluetooth: Option<(&'a BTreeMap<hetcomm_core::SystemId, crate::BdAddr>, &'a str)>,
}

/// What [`KindSpec::addresses`] tells the loader: which systems a transport can address and
/// how to tell a user to add one.
#[derive(Clone, Debug, PartialEq, Eq)]
pub struct Addresses {
    /// The systems the transport has an address for.
    pub systems: BTreeSet<hetcomm_core::SystemId>,
    /// What one address is called in the error, e.g. "endpoint".
    pub what: &'static str,
    /// How to add one, with `{system}` standing for the system's name, `{id}` for its number
    /// and `{transport}` for the transport's name, e.g. "add `{system} = \"host:port\"` to
    /// `endpoints` of transport `{transport}`".
    pub help: String,
}

impl Addresses {
    /// The help for `system` (named `name`) on transport `transport`.
    pub fn help_for(&self, system: hetcomm_core::SystemId, name: &str, transport: &str) -> String {
        self.help
            .replace("{system}", name)
            .replace("{id}", &system.0.to_string())
            .replace("{transport}", transport)
    }
}

/// The kinds a program knows beyond the built-in ones: one [`KindSpec`] per kind.
#[derive(Clone, Default)]
pub struct Kinds {
    specs: BTreeMap<TransportKind, Arc<dyn KindSpec>>,
    /// Kinds known by name only (their crate is not compiled in): keys kept raw.
    unbuilt: BTreeSet<TransportKind>,
}

impl Kinds {
    /// Only the built-in kinds.
    pub fn new() -> Kinds {
        Kinds::default()
    }

    /// Adds a kind's spec, replacing an earlier one of the same kind. A spec for a built-in
    /// name (`inproc`, `udp`, `emulated`, …) replaces its raw keys.
    pub fn add(&mut self, spec: Arc<dyn KindSpec>) {
        self.specs.insert(spec.kind(), spec);
    }

    /// Makes `kind` known by name although its crate is not compiled into this program: a
    /// fleet file may use it (its keys are kept raw, as `zenoh`'s are), and opening it says
    /// it is not available in this build instead of the loader calling it unknown.
    pub fn add_unbuilt(&mut self, kind: TransportKind) {
        self.unbuilt.insert(kind);
    }

    /// The spec that reads `kind`'s settings, if a crate registered one.
    pub fn spec(&self, kind: TransportKind) -> Option<&dyn KindSpec> {
        self.specs.get(&kind).map(|s| &**s)
    }

    /// Every kind name a fleet file may use: the built-in ones in documentation order, then
    /// the registered ones by name, then the ones known by name only.
    pub fn names(&self) -> Vec<&'static str> {
        let mut names: Vec<&'static str> = TransportKind::ALL.iter().map(|k| k.as_str()).collect();
        for k in self.specs.keys().chain(&self.unbuilt) {
            if !names.contains(&k.as_str()) {
                names.push(k.as_str());
            }
        }
        names
    }
}

impl std::fmt::Debug for Kinds {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        f.debug_set()
            .entries(self.specs.keys().chain(&self.unbuilt))
            .finish()
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    /// A spec that accepts one key, `broker`, for whichever kind it is made for.
    struct Broker(TransportKind);

    impl KindSpec for Broker {
        fn kind(&self) -> TransportKind {
            self.0
        }

        fn keys(&self) -> &[&'static str] {
            &["broker"]
        }

        fn parse(&self, s: &mut SettingsReader<'_, '_>) -> Option<RegisteredSettings> {
            let broker = s.string("broker", "write the broker's address in quotes");
            if broker.is_none() && !s.has("broker") {
                s.missing("broker", "add `broker = \"tcp://localhost:1883\"`");
            }
            broker.map(RegisteredSettings::new)
        }
    }

    fn fleet(kind: &str, keys: &str) -> String {
        format!(
            "[systems]\nA = 0\nB = 1\n[transports.t]\nkind = \"{kind}\"\n{keys}\n\
             [table]\ncolumns = [\"A\", \"B\"]\nA = [\"X\", \"t\"]\nB = [\"t\", \"X\"]\n"
        )
    }

    #[test]
    fn a_spec_for_a_raw_kind_takes_over_its_keys() {
        let mut kinds = Kinds::new();
        kinds.add(Arc::new(Broker(TransportKind::Mqtt)));
        // Without the spec, mqtt's keys are kept raw, whatever they are.
        let raw = crate::parse_str(&fleet("mqtt", "brokr = 1"), "m.toml", None).expect("raw");
        assert!(matches!(
            &raw.transports[0].settings,
            crate::TransportSettings::Raw(keys) if keys.get("brokr").map(String::as_str) == Some("1")
        ));
        // With it, they are checked.
        let errors = crate::parse_str_with(&fleet("mqtt", "brokr = 1"), "m.toml", None, &kinds)
            .unwrap_err()
            .to_string();
        assert_eq!(
            errors,
            "m.toml:4:1: transport `t` (kind mqtt) is missing required setting `broker`\n  \
             help: add `broker = \"tcp://localhost:1883\"`\n\
             m.toml:6:1: unknown key `brokr` in `transports.t`\n  help: did you mean `broker`?"
        );
        let ok = crate::parse_str_with(&fleet("mqtt", "broker = \"b\""), "m.toml", None, &kinds)
            .expect("valid");
        assert_eq!(
            ok.transports[0].settings,
            crate::TransportSettings::Registered(RegisteredSettings::new("b".to_string()))
        );
    }

    #[test]
    fn every_kind_takes_its_spec_and_new_names_are_listed_last() {
        let mut kinds = Kinds::new();
        kinds.add(Arc::new(Broker(TransportKind::new("ros2"))));
        assert_eq!(TransportKind::new("udp"), TransportKind::Udp);
        assert_eq!(
            kinds.names().join(", "),
            "inproc, udp, tcp, ros1, bluetooth, zenoh, mqtt, dds, emulated, ros2"
        );
        // No kind is modelled by the loader: `inproc` and `emulated` too are read by their
        // crate's spec, and kept raw without one.
        for kind in ["inproc", "emulated"] {
            let raw =
                crate::parse_str(&fleet(kind, "broker = \"b\""), "u.toml", None).expect("raw keys");
            assert!(
                matches!(&raw.transports[0].settings, crate::TransportSettings::Raw(k) if k.contains_key("broker")),
                "{kind}: {:?}",
                raw.transports[0].settings
            );
            let mut with = kinds.clone();
            with.add(Arc::new(Broker(TransportKind::new(kind))));
            assert!(with.spec(TransportKind::new(kind)).is_some(), "{kind}");
            let ok = crate::parse_str_with(&fleet(kind, "broker = \"b\""), "u.toml", None, &with)
                .expect("valid");
            assert_eq!(
                ok.transports[0].settings,
                crate::TransportSettings::Registered(RegisteredSettings::new("b".to_string()))
            );
        }
        let errors = crate::parse_str_with(&fleet("ros3", ""), "r.toml", None, &kinds)
            .unwrap_err()
            .to_string();
        assert!(
            errors.starts_with("r.toml:5:8: unknown transport kind `ros3`\n  help: did you mean")
                && errors.ends_with(
                    "valid transport kinds: inproc, udp, tcp, ros1, bluetooth, zenoh, mqtt, dds, emulated, ros2"
                ),
            "{errors}"
        );
    }
}

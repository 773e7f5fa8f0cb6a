//! `[transports.<name>]`: the keys every kind shares, and the raw keys of a kind without a
//! spec (`emulated`'s settings are in `emulation.rs`). A kind registered by a link crate
//! (`crate::kinds::KindSpec`: `udp`, `tcp`, `ros1`, `bluetooth`, …) reads its own keys
//! through a [`SettingsReader`] handed out here, after its unknown keys were reported.

use super::*;

impl P<'_> {
    pub(super) fn letter(&mut self, s: &str, loc: &Loc) -> Option<u8> {
        match s.as_bytes() {
            [b] if b.is_ascii_graphic() && *b != b'X' => Some(*b),
            _ => {
                self.diag.err_help(
                    loc,
                    format!("`{s}` is not a usable table letter"),
                    "a letter is one ASCII character other than X (X means no traffic), e.g. `R`",
                );
                None
            }
        }
    }

    pub(super) fn transport(
        &mut self,
        name: &str,
        item: &Item,
        nloc: &Loc,
        systems: &Systems,
    ) -> Option<TransportSpec> {
        let path = format!("transports.{}", key_part(name));
        let tloc = self.vloc(item, nloc);
        let t = self.table(item, &path, &tloc)?;
        if name.is_empty() || name == "X" {
            self.diag.err_help(
                nloc,
                format!("`{name}` cannot be a transport name"),
                "X means no traffic in the table and an empty name has no tag byte; pick another name",
            );
        }
        let kind = match t.get("kind") {
            None => {
                self.diag.err_help(
                    &tloc,
                    format!("transport `{name}` has no `kind`"),
                    format!("add `kind = \"…\"`, one of: {}", kind_list(self.kinds)),
                );
                None
            }
            Some(v) => {
                let vl = self.vloc(v, &tloc);
                let names = self.kinds.names();
                self.choice(
                    v,
                    &format!("{path}.kind"),
                    &vl,
                    ("transport kind", "transport kinds"),
                    &names,
                )
                .map(|i| TransportKind::new(names[i]))
            }
        };
        let delivery = match t.get("delivery") {
            None => DeliveryMode::Acknowledged,
            Some(v) => {
                let vl = self.vloc(v, &tloc);
                match self.choice(
                    v,
                    &format!("{path}.delivery"),
                    &vl,
                    ("delivery mode", "delivery modes"),
                    &DELIVERIES,
                ) {
                    Some(1) => DeliveryMode::Unacknowledged,
                    _ => DeliveryMode::Acknowledged,
                }
            }
        };
        let attempts = match t.get("attempts") {
            None => 3,
            Some(v) => {
                let vl = self.vloc(v, &tloc);
                self.int_in(
                    v,
                    &format!("{path}.attempts"),
                    &vl,
                    1,
                    i64::from(u32::MAX),
                    "attempts counts the first transmission too; the thesis used 3",
                )
                .map_or(3, |a| u32::try_from(a).unwrap_or(3))
            }
        };
        let default_window = crate::model::DEFAULT_MAX_IN_FLIGHT;
        let max_in_flight = match t.get("max_in_flight") {
            None => default_window,
            Some(v) => {
                let vl = self.vloc(v, &tloc);
                self.int_in(
                    v,
                    &format!("{path}.max_in_flight"),
                    &vl,
                    1,
                    1_000_000,
                    &format!("sends to one destination that may await their outcome at once; the default is {default_window}"),
                )
                .map_or(default_window, |a| u32::try_from(a).unwrap_or(default_window))
            }
        };
        let default_bytes = crate::model::DEFAULT_MAX_IN_FLIGHT_BYTES;
        let max_in_flight_bytes = match t.get("max_in_flight_bytes") {
            None => default_bytes,
            Some(v) => {
                let vl = self.vloc(v, &tloc);
                self.int_in(
                    v,
                    &format!("{path}.max_in_flight_bytes"),
                    &vl,
                    1,
                    i64::MAX,
                    &format!("bytes of frames to one destination that may await their outcome at once; the default is {default_bytes}"),
                )
                .map_or(default_bytes, |a| usize::try_from(a).unwrap_or(usize::MAX))
            }
        };
        let ordered = match t.get("ordered") {
            None => false,
            Some(v) => {
                let vl = self.vloc(v, &tloc);
                self.boolean(
                    v,
                    &format!("{path}.ordered"),
                    &vl,
                    "write `ordered = true` to deliver each sender's messages in the order sent",
                )
                .unwrap_or(false)
            }
        };
        let default_linger = crate::model::DEFAULT_BATCH_LINGER_US;
        let batch_linger_us = match t.get("batch_linger_us") {
            None => default_linger,
            Some(v) => {
                let vl = self.vloc(v, &tloc);
                self.int_in(
                    v,
                    &format!("{path}.batch_linger_us"),
                    &vl,
                    0,
                    1_000_000,
                    "microseconds a small frame may wait to share a write with the next; 0 turns batching off",
                )
                .map_or(default_linger, |a| u32::try_from(a).unwrap_or(default_linger))
            }
        };
        let security = match t.get("security") {
            None => SecurityMode::Keys,
            Some(v) => {
                let vl = self.vloc(v, &tloc);
                match self.choice(
                    v,
                    &format!("{path}.security"),
                    &vl,
                    ("security mode", "security modes"),
                    &SECURITY_MODES,
                ) {
                    Some(1) => SecurityMode::None,
                    _ => SecurityMode::Keys,
                }
            }
        };
        let letter = t.get("letter").and_then(|v| {
            let vl = self.vloc(v, &tloc);
            let s = self.string(
                v,
                &format!("{path}.letter"),
                &vl,
                "write one letter in quotes, e.g. `letter = \"R\"`",
            )?;
            self.letter(s, &vl).map(|b| (b, vl))
        });
        let mut spec = TransportSpec {
            name: crate::names::nfc(name).into_owned(),
            name_loc: nloc.clone(),
            kind,
            delivery,
            attempts,
            max_in_flight,
            max_in_flight_bytes,
            ordered,
            batch_linger_us,
            letter,
            security,
            settings: None,
            over: None,
            in_process: false,
            addresses: None,
        };
        let Some(kind) = kind else {
            return Some(spec); // kind already reported; its keys cannot be judged
        };
        let errors_before = self.diag.errors.len();
        let kinds = self.kinds;
        if let Some(registered) = kinds.spec(kind) {
            let allowed: Vec<&str> = COMMON_KEYS
                .iter()
                .chain(registered.keys())
                .copied()
                .collect();
            self.unknown_keys(t, &allowed, Some(&path), &tloc);
            let mut reader =
                SettingsReader::new(self, t, (path.clone(), tloc.clone()), (name, kind), systems);
            let settings = registered.parse(&mut reader);
            spec.over = reader.take_over();
            spec.in_process = registered.in_process();
            if self.diag.errors.len() == errors_before {
                spec.addresses = settings.as_ref().and_then(|s| registered.addresses(s));
                spec.settings = settings.map(TransportSettings::Registered);
            }
            return Some(spec);
        }
        // A kind without a registered spec (not compiled into this program): its keys are
        // kept raw.
        let raw = t
            .iter()
            .filter(|(k, _)| !COMMON_KEYS.contains(k))
            .map(|(k, v)| (k.to_string(), self.stringify(v, false)))
            .collect();
        let settings = TransportSettings::Raw(raw);
        if self.diag.errors.len() == errors_before {
            spec.settings = Some(settings);
        }
        Some(spec)
    }

    /// `endpoints = { System = "host:port", … }`.
    pub(super) fn endpoints(
        &mut self,
        item: &Item,
        path: &str,
        tloc: &Loc,
        (transport, kind): (&str, TransportKind),
        systems: &Systems,
    ) -> BTreeMap<hetcomm_core::SystemId, String> {
        let mut out = BTreeMap::new();
        let loc = self.vloc(item, tloc);
        let Some(t) = self.table(item, path, &loc) else {
            return out;
        };
        for (k, v) in t.iter() {
            let kl = self.kloc(t, k, &loc);
            let vl = self.vloc(v, &kl);
            let sys = systems.resolve(&label(k, &kl), &format!("`{path}`"), &[], &mut self.diag);
            let help = "write \"host:port\", e.g. \"127.0.0.1:7400\" (port 0 picks a free port)";
            let Some(s) = self.string(v, &format!("{path}.{}", key_part(k)), &vl, help) else {
                continue;
            };
            let split = s.rsplit_once(':').filter(|(h, p)| {
                !h.is_empty() && !p.is_empty() && p.bytes().all(|b| b.is_ascii_digit())
            });
            let Some((host, digits)) = split else {
                self.diag
                    .err_help(&vl, format!("malformed endpoint `{s}` for `{k}`"), help);
                continue;
            };
            let Ok(port) = digits.parse::<u16>() else {
                self.diag.err_help(
                    &vl,
                    format!("port {digits} of endpoint `{s}` for `{k}` is out of range"),
                    "a port is 0 to 65535 (0 picks a free port)",
                );
                continue;
            };
            // One socket per protocol, address and port: a second system there (on this
            // transport or another of the same kind) could not be opened. Port 0 picks a free
            // port each time.
            if port != 0 {
                let key = (kind, host.to_ascii_lowercase(), port);
                if let Some(first) = self.endpoints_seen.get(&key) {
                    let (what, whose) = if first.transport == transport {
                        (
                            format!("`{k}` and `{}`", first.system),
                            format!("on transport `{transport}`"),
                        )
                    } else {
                        (
                            format!(
                                "`{k}` (transport `{transport}`) and `{}` (transport `{}`)",
                                first.system, first.transport
                            ),
                            format!("({kind})"),
                        )
                    };
                    self.diag.err_help(
                        &vl,
                        format!("{what} have the same endpoint `{s}` {whose}"),
                        format!(
                            "give each system its own address or port (`{}` has `{}` at {}); \
                             port 0 picks a free one",
                            first.system,
                            first.endpoint,
                            assemble::at(&first.loc)
                        ),
                    );
                } else {
                    self.endpoints_seen.insert(
                        key,
                        SeenEndpoint {
                            transport: transport.to_string(),
                            system: k.to_string(),
                            endpoint: s.to_string(),
                            loc: vl.clone(),
                        },
                    );
                }
            }
            if let Some(sys) = sys {
                out.insert(sys, s.to_string());
            }
        }
        out
    }

    /// `addresses = { System = "XX:XX:XX:XX:XX:XX", … }`.
    pub(super) fn addresses(
        &mut self,
        item: &Item,
        path: &str,
        tloc: &Loc,
        systems: &Systems,
    ) -> BTreeMap<hetcomm_core::SystemId, BdAddr> {
        let loc = self.vloc(item, tloc);
        let Some(t) = self.table(item, path, &loc) else {
            return BTreeMap::new();
        };
        let mut lines = Vec::new();
        for (k, v) in t.iter() {
            let kl = self.kloc(t, k, &loc);
            let vl = self.vloc(v, &kl);
            if let Some(s) = self.string(
                v,
                &format!("{path}.{}", key_part(k)),
                &vl,
                "write the address in quotes, e.g. \"68:A3:C4:4A:B3:BA\"",
            ) {
                lines.push(BtLine {
                    key: label(k, &kl),
                    addr: s.to_string(),
                    addr_loc: vl,
                });
            }
        }
        assemble::bt_addresses(lines, systems, &format!("`{path}`"), &mut self.diag)
    }

    /// `[table]`: `columns = [...]` and one `Row = [...]` per source system.
    /// A value as a string for `Raw` settings: strings unquoted, everything else as TOML.
    pub(super) fn stringify(&self, item: &Item, nested: bool) -> String {
        match item {
            Item::Value(Value::String(s)) if !nested => s.value().clone(),
            Item::Value(Value::InlineTable(_)) | Item::Table(_) => {
                let Some(t) = item.as_table_like() else {
                    return String::new();
                };
                let inner: Vec<String> = t
                    .iter()
                    .map(|(k, v)| format!("{} = {}", key_part(k), self.stringify(v, true)))
                    .collect();
                format!("{{ {} }}", inner.join(", "))
            }
            Item::Value(v) => match item.span().and_then(|r| self.text.get(r)) {
                Some(s) => s.trim().to_string(),
                None => v.to_string().trim().to_string(),
            },
            Item::ArrayOfTables(a) => {
                let inner: Vec<String> = a
                    .iter()
                    .map(|t| {
                        let kv: Vec<String> = t
                            .iter()
                            .map(|(k, v)| format!("{} = {}", key_part(k), self.stringify(v, true)))
                            .collect();
                        format!("{{ {} }}", kv.join(", "))
                    })
                    .collect();
                format!("[{}]", inner.join(", "))
            }
            Item::None => String::new(),
        }
    }
}

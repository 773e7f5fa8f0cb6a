//! The fleet file walker. It reads the document with `toml_edit`'s span-keeping parser and
//! checks every key by hand instead of deriving serde structs: derived errors can neither
//! collect more than one problem nor say "did you mean", and their wording is not ours.

use std::collections::BTreeMap;
use std::ops::Range;
use std::path::{Path, PathBuf};
use std::rc::Rc;
use std::time::Duration;

use toml_edit::{ImDocument, Item, TableLike, Value};

use crate::assemble::{
    self, AddrSource, BtLine, Label, LegacyBt, LetterSpec, ModSpec, Parts, RawCell, RawTable,
    SysSpec, Systems, TransportSpec, DEFAULT_MODULES,
};
use crate::error::{ConfigErrors, Diag, LineIndex, Loc};
use crate::legacy;
use crate::model::*;
use crate::suggest;

/// Keys allowed at the top level.
pub(crate) const TOP_KEYS: [&str; 8] = [
    "name",
    "systems",
    "modules",
    "inbox",
    "transports",
    "table",
    "legacy",
    "letters",
];
/// Keys of `[inbox]`.
pub(crate) const INBOX_KEYS: [&str; 3] = ["capacity", "overflow", "block_timeout_ms"];
/// Keys of a module's long form.
pub(crate) const MODULE_KEYS: [&str; 4] = ["id", "inbox_capacity", "overflow", "block_timeout_ms"];
/// Keys of a system's long form.
pub(crate) const SYSTEM_KEYS: [&str; 2] = ["id", "modules"];
/// Keys of `[legacy]`.
pub(crate) const LEGACY_KEYS: [&str; 3] = ["ids", "table", "bluetooth"];
/// Keys every transport accepts.
pub(crate) const COMMON_KEYS: [&str; 7] = [
    "kind",
    "delivery",
    "attempts",
    "max_in_flight",
    "letter",
    "ordered",
    "batch_linger_us",
];
/// Keys of `udp` / `tcp` transports besides the common ones.
pub(crate) const IP_KEYS: [&str; 2] = ["endpoints", "max_message_bytes"];
/// Keys of `ros1` transports besides the common ones.
pub(crate) const ROS1_KEYS: [&str; 3] = ["master_uri", "namespace", "connect_timeout_ms"];
/// Keys of `bluetooth` transports besides the common ones.
pub(crate) const BLUETOOTH_KEYS: [&str; 3] = ["channel", "addresses", "addresses_file"];
/// Non-numeric keys of `emulated` transports besides the common ones.
pub(crate) const EMULATED_KEYS: [&str; 3] = ["profile", "over", "seed"];
/// Numeric model parameters an `emulated` transport accepts (kept in
/// `EmulatedSettings::params`; the emulation layer interprets them and documents their units
/// in docs/emulation.md). The last four were added by the emulation layer beyond the
/// original list, so a fleet file may use every key that layer understands.
pub const EMULATED_PARAMS: [&str; 24] = [
    "loss_percent",
    "burst_loss_percent",
    "burst_length_mean",
    "latency_ms",
    "jitter_ms",
    "bandwidth_kbps",
    "queue_frames",
    "mtu_bytes",
    "duplicate_percent",
    "reorder_percent",
    "corrupt_percent",
    "range_m",
    "path_loss_exponent",
    "reference_loss_db",
    "reference_distance_m",
    "tx_power_dbm",
    "sensitivity_dbm",
    "outage_start_ms",
    "outage_duration_ms",
    "outage_period_ms",
    "delay_tail_ms",
    "preserve_order",
    "reorder_delay_ms",
    "margin_slope_db",
];
/// Built-in emulation profiles.
pub(crate) const PROFILES: [&str; 3] = ["wired", "wifi", "bluetooth-classic"];
/// Overflow policy names.
pub(crate) const OVERFLOWS: [&str; 3] = ["drop-oldest", "drop-newest", "block"];
/// Delivery mode names.
pub(crate) const DELIVERIES: [&str; 2] = ["acknowledged", "unacknowledged"];

/// A `[legacy]` path: as written, as resolved, and where it was written.
struct LegacyPath {
    path: PathBuf,
    display: Rc<str>,
    loc: Loc,
}

/// Inbox defaults from `[inbox]`, kept as parts because a module may override any one.
#[derive(Clone, Copy)]
struct InboxDefaults {
    capacity: usize,
    overflow: usize, // index into OVERFLOWS
    timeout_ms: u64,
}

/// The walker's state: the text (for spans and quoting values) and the errors so far.
struct P<'a> {
    file: Rc<str>,
    text: &'a str,
    idx: LineIndex,
    diag: Diag,
    base_dir: Option<&'a Path>,
}

/// Parses and validates a fleet file's text.
pub(crate) fn parse(
    text: &str,
    origin: &str,
    base_dir: Option<&Path>,
    source: Option<PathBuf>,
) -> Result<Fleet, ConfigErrors> {
    let mut p = P {
        file: Rc::from(origin),
        text,
        idx: LineIndex::new(text),
        diag: Diag::default(),
        base_dir,
    };
    let doc = match ImDocument::parse(text) {
        Ok(d) => d,
        Err(e) => {
            let loc = p.at(e.span(), &Loc::start(&p.file));
            // toml_edit's message may span lines ("invalid string\nexpected …"); one line
            // keeps our "file:line:col: message" shape.
            let msg = e
                .message()
                .lines()
                .map(str::trim)
                .filter(|l| !l.is_empty())
                .collect::<Vec<_>>()
                .join("; ");
            p.diag.err_help(
                &loc,
                format!("TOML syntax error: {msg}"),
                "fix the TOML syntax at this spot; see docs/config.md for the file format",
            );
            return Err(ConfigErrors(p.diag.errors));
        }
    };
    let parts = p.walk(doc.as_table(), source);
    assemble::finish(parts, p.diag)
}

/// Quotes a key for a dotted path when it is not a bare key.
fn key_part(k: &str) -> String {
    if !k.is_empty()
        && k.bytes()
            .all(|b| b.is_ascii_alphanumeric() || b == b'_' || b == b'-')
    {
        k.to_string()
    } else {
        format!("{k:?}")
    }
}

fn type_name(item: &Item) -> &'static str {
    match item {
        Item::None => "nothing",
        Item::Table(_) | Item::Value(Value::InlineTable(_)) => "a table",
        Item::ArrayOfTables(_) => "an array of tables",
        Item::Value(Value::String(_)) => "string",
        Item::Value(Value::Integer(_)) => "integer",
        Item::Value(Value::Float(_)) => "float",
        Item::Value(Value::Boolean(_)) => "boolean",
        Item::Value(Value::Datetime(_)) => "date-time",
        Item::Value(Value::Array(_)) => "array",
    }
}

impl P<'_> {
    fn at(&self, span: Option<Range<usize>>, fallback: &Loc) -> Loc {
        match span {
            Some(r) => {
                let (line, column) = self.idx.locate(self.text, r.start);
                Loc {
                    file: self.file.clone(),
                    line,
                    column,
                }
            }
            None => fallback.clone(),
        }
    }

    /// Location of `key` inside `t`.
    fn kloc(&self, t: &dyn TableLike, key: &str, fallback: &Loc) -> Loc {
        let span = t.get_key_value(key).and_then(|(k, _)| k.span());
        self.at(span, fallback)
    }

    /// Location of a value (for a table: its header or opening brace).
    fn vloc(&self, item: &Item, fallback: &Loc) -> Loc {
        self.at(item.span(), fallback)
    }

    /// The value as written, for messages.
    fn raw(&self, item: &Item) -> String {
        let s = item
            .span()
            .and_then(|r| self.text.get(r))
            .map(|s| s.trim().to_string())
            .unwrap_or_default();
        if s.chars().count() > 40 {
            let cut: String = s.chars().take(37).collect();
            format!("{cut}...")
        } else {
            s
        }
    }

    /// "string `\"one\"`" or "a table": what was found instead of what was expected.
    fn found(&self, item: &Item) -> String {
        match item {
            Item::Value(Value::InlineTable(_))
            | Item::Table(_)
            | Item::ArrayOfTables(_)
            | Item::None => type_name(item).to_string(),
            _ => format!("{} `{}`", type_name(item), self.raw(item)),
        }
    }

    fn wrong_type(&mut self, loc: &Loc, path: &str, expected: &str, item: &Item, help: &str) {
        let found = self.found(item);
        self.diag.err_help(
            loc,
            format!("`{path}` must be {expected}, found {found}"),
            help,
        );
    }

    fn table<'t>(&mut self, item: &'t Item, path: &str, loc: &Loc) -> Option<&'t dyn TableLike> {
        let t = item.as_table_like();
        if t.is_none() {
            self.wrong_type(
                loc,
                path,
                "a table",
                item,
                "write it as a [section] or an inline table `{ key = value }`",
            );
        }
        t
    }

    fn string<'t>(&mut self, item: &'t Item, path: &str, loc: &Loc, help: &str) -> Option<&'t str> {
        let s = item.as_str();
        if s.is_none() {
            self.wrong_type(loc, path, "a string", item, help);
        }
        s
    }

    fn boolean(&mut self, item: &Item, path: &str, loc: &Loc, help: &str) -> Option<bool> {
        let v = item.as_bool();
        if v.is_none() {
            self.wrong_type(loc, path, "true or false", item, help);
        }
        v
    }

    fn int(&mut self, item: &Item, path: &str, loc: &Loc, help: &str) -> Option<i64> {
        let v = item.as_integer();
        if v.is_none() {
            self.wrong_type(loc, path, "an integer", item, help);
        }
        v
    }

    /// An integer in `min..=max`, reporting either kind of problem.
    fn int_in(
        &mut self,
        item: &Item,
        path: &str,
        loc: &Loc,
        min: i64,
        max: i64,
        help: &str,
    ) -> Option<i64> {
        let v = self.int(item, path, loc, help)?;
        if v < min || v > max {
            // Huge maxima are type limits, not advice: only mention them when exceeded.
            let range = if max >= i64::from(u32::MAX) && v < min {
                format!("at least {min}")
            } else {
                format!("from {min} to {max}")
            };
            self.diag
                .err_help(loc, format!("`{path}` must be {range}, found {v}"), help);
            return None;
        }
        Some(v)
    }

    /// A u16 id (system or module).
    fn id16(&mut self, item: &Item, path: &str, loc: &Loc, what: &str) -> Option<u16> {
        let help = "ids are whole numbers from 0 to 65535";
        let v = self.int(item, path, loc, help)?;
        match u16::try_from(v) {
            Ok(id) => Some(id),
            Err(_) => {
                self.diag
                    .err_help(loc, format!("{what} id {v} is out of range"), help);
                None
            }
        }
    }

    /// Reports keys of `t` not in `allowed`, suggesting the nearest.
    fn unknown_keys(
        &mut self,
        t: &dyn TableLike,
        allowed: &[&str],
        section: Option<&str>,
        fallback: &Loc,
    ) {
        for (k, _) in t.iter() {
            if allowed.contains(&k) {
                continue;
            }
            let loc = self.kloc(t, k, fallback);
            let place = match section {
                Some(s) => format!("in `{s}`"),
                None => "at the top level".to_string(),
            };
            self.diag.err_help(
                &loc,
                format!("unknown key `{k}` {place}"),
                suggest::help(k, allowed, "valid keys here"),
            );
        }
    }

    /// One of a fixed set of words (kinds, policies, profiles), reporting anything else.
    fn choice(
        &mut self,
        item: &Item,
        path: &str,
        loc: &Loc,
        what: (&str, &str),
        options: &[&str],
    ) -> Option<usize> {
        let (what, plural) = what;
        let list = options.join(", ");
        let s = self.string(item, path, loc, &format!("one of: {list}"))?;
        if let Some(i) = options.iter().position(|o| *o == s) {
            return Some(i);
        }
        let help = match suggest::closest(s, options) {
            Some(c) => format!("did you mean `{c}`? valid {plural}: {list}"),
            None => format!("valid {plural}: {list}"),
        };
        self.diag
            .err_help(loc, format!("unknown {what} `{s}`"), help);
        None
    }

    fn walk(&mut self, root: &dyn TableLike, source: Option<PathBuf>) -> Parts {
        let top = Loc::start(&self.file);
        self.unknown_keys(root, &TOP_KEYS, None, &top);
        let get = |k: &str| root.get(k).filter(|i| !i.is_none());

        let name = get("name").and_then(|item| {
            let loc = self.vloc(item, &top);
            self.string(
                item,
                "name",
                &loc,
                "write the fleet's name in quotes, e.g. `name = \"demo\"`",
            )
            .map(str::to_string)
        });

        // [legacy] first: it decides where systems and the table come from.
        let (mut l_ids, mut l_table, mut l_bt) = (None, None, None);
        if let Some(item) = get("legacy") {
            let loc = self.vloc(item, &top);
            if let Some(t) = self.table(item, "legacy", &loc) {
                self.unknown_keys(t, &LEGACY_KEYS, Some("legacy"), &loc);
                for (k, v) in t.iter() {
                    let vl = self.vloc(v, &loc);
                    let Some(s) = self.string(
                        v,
                        &format!("legacy.{k}"),
                        &vl,
                        "write a path in quotes, relative to the fleet file",
                    ) else {
                        continue;
                    };
                    let path = match self.base_dir {
                        Some(d) => d.join(s),
                        None => PathBuf::from(s),
                    };
                    let lp = LegacyPath {
                        display: Rc::from(path.display().to_string()),
                        path,
                        loc: vl,
                    };
                    match k {
                        "ids" => l_ids = Some(lp),
                        "table" => l_table = Some(lp),
                        "bluetooth" => l_bt = Some(lp),
                        _ => {}
                    }
                }
            }
        }

        // Systems.
        let specs = match (&l_ids, get("systems")) {
            (Some(lp), other) => {
                if other.is_some() {
                    let loc = self.kloc(root, "systems", &top);
                    self.diag.err_help(
                        &loc,
                        "[systems] cannot be combined with `ids` under [legacy]",
                        "keep one source of systems: remove [systems], or remove `ids` from [legacy]",
                    );
                }
                self.read_legacy(lp)
                    .map(|text| {
                        legacy::parse_ids(&lp.display, &text, &mut self.diag)
                            .into_iter()
                            .map(|l| SysSpec {
                                id: l.id,
                                id_loc: l.id_loc,
                                name: l.name,
                                name_loc: l.name_loc,
                                modules: None,
                            })
                            .collect()
                    })
                    .unwrap_or_default()
            }
            (None, Some(item)) => self.systems(item, &top),
            (None, None) => {
                self.diag.err_help(
                    &top,
                    "the fleet defines no systems",
                    "add a [systems] table (e.g. `Alpha = 0`), or `ids = \"ids.txt\"` under [legacy]",
                );
                Vec::new()
            }
        };
        let systems = Systems::new(specs, &mut self.diag);

        // Inbox defaults, then modules.
        let mut defaults = InboxDefaults {
            capacity: 1024,
            overflow: 0,
            timeout_ms: 100,
        };
        if let Some(item) = get("inbox") {
            let loc = self.vloc(item, &top);
            if let Some(t) = self.table(item, "inbox", &loc) {
                self.unknown_keys(t, &INBOX_KEYS, Some("inbox"), &loc);
                defaults = self.inbox_fields(t, "inbox", "capacity", defaults, &loc);
            }
        }
        let module_specs = match get("modules") {
            Some(item) => self.modules(item, defaults, &top),
            None => DEFAULT_MODULES
                .iter()
                .map(|&(n, id)| ModSpec {
                    id,
                    id_loc: top.clone(),
                    name: n.to_string(),
                    inbox: policy(defaults),
                })
                .collect(),
        };
        let modules = assemble::modules(module_specs, &mut self.diag);

        // Transports.
        let mut transports = Vec::new();
        if let Some(item) = get("transports") {
            let loc = self.kloc(root, "transports", &top);
            if let Some(t) = self.table(item, "transports", &loc) {
                for (name, v) in t.iter() {
                    let nloc = self.kloc(t, name, &loc);
                    if let Some(spec) = self.transport(name, v, &nloc, &systems) {
                        transports.push(spec);
                    }
                }
            }
        }

        // Letters.
        let mut letters = Vec::new();
        if let Some(item) = get("letters") {
            let loc = self.vloc(item, &top);
            if let Some(t) = self.table(item, "letters", &loc) {
                for (k, v) in t.iter() {
                    let kl = self.kloc(t, k, &loc);
                    let vl = self.vloc(v, &kl);
                    let letter = self.letter(k, &kl);
                    let target = self.string(
                        v,
                        &format!("letters.{}", key_part(k)),
                        &vl,
                        "write the transport's name in quotes, e.g. `R = \"wired\"`",
                    );
                    if let (Some(letter), Some(target)) = (letter, target) {
                        letters.push(LetterSpec {
                            letter,
                            letter_loc: kl,
                            target: target.to_string(),
                            target_loc: vl,
                        });
                    }
                }
            }
        }

        // The table.
        let table = match (&l_table, get("table")) {
            (Some(lp), other) => {
                if other.is_some() {
                    let loc = self.kloc(root, "table", &top);
                    self.diag.err_help(
                        &loc,
                        "[table] cannot be combined with `table` under [legacy]",
                        "keep one communication table: remove [table], or remove `table` from [legacy]",
                    );
                }
                self.read_legacy(lp)
                    .and_then(|text| legacy::parse_table(&lp.display, &text, &mut self.diag))
            }
            (None, Some(item)) => self.comm_table(item, &top),
            (None, None) => None,
        };

        let legacy_bt = l_bt.as_ref().and_then(|lp| {
            let text = self.read_legacy(lp)?;
            let lines = legacy::parse_bluetooth(&lp.display, &text, &mut self.diag);
            Some(LegacyBt {
                addresses: assemble::bt_addresses(lines, &systems, &lp.display, &mut self.diag),
                file: lp.display.clone(),
            })
        });

        Parts {
            name,
            source,
            systems,
            modules,
            transports,
            letters,
            table,
            legacy_bt,
            fallback: top,
        }
    }

    fn read_legacy(&mut self, lp: &LegacyPath) -> Option<String> {
        match std::fs::read_to_string(&lp.path) {
            Ok(t) => Some(t),
            Err(e) => {
                let rel = match self.base_dir {
                    Some(_) => "relative to the fleet file's directory",
                    None => "relative to the current directory (no fleet file directory is known)",
                };
                self.diag.err_help(
                    &lp.loc,
                    format!("cannot read `{}`: {e}", lp.display),
                    format!("check the path; paths under [legacy] are {rel}"),
                );
                None
            }
        }
    }

    fn systems(&mut self, item: &Item, top: &Loc) -> Vec<SysSpec> {
        let loc = self.vloc(item, top);
        let Some(t) = self.table(item, "systems", &loc) else {
            return Vec::new();
        };
        let mut out = Vec::new();
        for (name, v) in t.iter() {
            let nloc = self.kloc(t, name, &loc);
            let vl = self.vloc(v, &nloc);
            let path = format!("systems.{}", key_part(name));
            let (id, modules) = if v.is_integer() || !v.is_table_like() {
                if !v.is_integer() {
                    self.wrong_type(
                        &vl,
                        &path,
                        "an id or a table `{ id = …, modules = […] }`",
                        v,
                        "write `Name = 0` or `Name = { id = 0, modules = [\"Plan\"] }`",
                    );
                    continue;
                }
                (
                    self.id16(v, &path, &vl, "system")
                        .map(|id| (id, vl.clone())),
                    None,
                )
            } else {
                let Some(st) = v.as_table_like() else {
                    continue;
                };
                self.unknown_keys(st, &SYSTEM_KEYS, Some(&path), &vl);
                let id = match st.get("id") {
                    Some(i) => {
                        let il = self.vloc(i, &vl);
                        self.id16(i, &format!("{path}.id"), &il, "system")
                            .map(|id| (id, il))
                    }
                    None => {
                        self.diag.err_help(
                            &vl,
                            format!("system `{name}` has no `id`"),
                            "add `id = <number>`",
                        );
                        None
                    }
                };
                let modules = st.get("modules").and_then(|m| {
                    let ml = self.vloc(m, &vl);
                    self.name_list(m, &format!("{path}.modules"), &ml)
                });
                (id, modules)
            };
            if let Some((id, id_loc)) = id {
                out.push(SysSpec {
                    id,
                    id_loc,
                    name: name.to_string(),
                    name_loc: nloc,
                    modules,
                });
            }
        }
        out
    }

    /// An array of strings with their locations.
    fn name_list(&mut self, item: &Item, path: &str, loc: &Loc) -> Option<Vec<(String, Loc)>> {
        let Some(arr) = item.as_array() else {
            self.wrong_type(
                loc,
                path,
                "an array of module names",
                item,
                "e.g. `modules = [\"Plan\", \"Act\"]`",
            );
            return None;
        };
        let mut out = Vec::new();
        for v in arr.iter() {
            let vl = self.at(v.span(), loc);
            match v.as_str() {
                Some(s) => out.push((s.to_string(), vl)),
                None => {
                    let found = format!(
                        "{} `{}`",
                        type_name(&Item::Value(v.clone())),
                        v.span().and_then(|r| self.text.get(r)).unwrap_or("").trim()
                    );
                    self.diag.err_help(
                        &vl,
                        format!("`{path}` must list names in quotes, found {found}"),
                        "e.g. `modules = [\"Plan\", \"Act\"]`",
                    );
                }
            }
        }
        Some(out)
    }

    /// Reads capacity / overflow / block_timeout_ms over `base`.
    fn inbox_fields(
        &mut self,
        t: &dyn TableLike,
        path: &str,
        cap_key: &str,
        base: InboxDefaults,
        loc: &Loc,
    ) -> InboxDefaults {
        let mut out = base;
        if let Some(v) = t.get(cap_key) {
            let vl = self.vloc(v, loc);
            if let Some(c) = self.int_in(
                v,
                &format!("{path}.{cap_key}"),
                &vl,
                1,
                i64::MAX,
                "an inbox holds at least one message, e.g. 1024",
            ) {
                out.capacity = usize::try_from(c).unwrap_or(usize::MAX);
            }
        }
        if let Some(v) = t.get("overflow") {
            let vl = self.vloc(v, loc);
            if let Some(i) = self.choice(
                v,
                &format!("{path}.overflow"),
                &vl,
                ("overflow policy", "overflow policies"),
                &OVERFLOWS,
            ) {
                out.overflow = i;
            }
        }
        if let Some(v) = t.get("block_timeout_ms") {
            let vl = self.vloc(v, loc);
            if let Some(ms) = self.int_in(
                v,
                &format!("{path}.block_timeout_ms"),
                &vl,
                0,
                i64::MAX,
                "a wait in milliseconds, e.g. 100",
            ) {
                out.timeout_ms = ms.unsigned_abs();
            }
        }
        out
    }

    fn modules(&mut self, item: &Item, defaults: InboxDefaults, top: &Loc) -> Vec<ModSpec> {
        let loc = self.vloc(item, top);
        let Some(t) = self.table(item, "modules", &loc) else {
            return Vec::new();
        };
        let mut out = Vec::new();
        for (name, v) in t.iter() {
            let nloc = self.kloc(t, name, &loc);
            let vl = self.vloc(v, &nloc);
            let path = format!("modules.{}", key_part(name));
            let (id, inbox) = if let Some(mt) = v.as_table_like() {
                self.unknown_keys(mt, &MODULE_KEYS, Some(&path), &vl);
                let id = match mt.get("id") {
                    Some(i) => {
                        let il = self.vloc(i, &vl);
                        self.id16(i, &format!("{path}.id"), &il, "module")
                            .map(|id| (id, il))
                    }
                    None => {
                        self.diag.err_help(
                            &vl,
                            format!("module `{name}` has no `id`"),
                            "add `id = <number>`",
                        );
                        None
                    }
                };
                (
                    id,
                    self.inbox_fields(mt, &path, "inbox_capacity", defaults, &vl),
                )
            } else if v.is_integer() {
                (
                    self.id16(v, &path, &vl, "module")
                        .map(|id| (id, vl.clone())),
                    defaults,
                )
            } else {
                self.wrong_type(
                    &vl,
                    &path,
                    "an id or a table `{ id = …, inbox_capacity = … }`",
                    v,
                    "write `Name = 1` or `Name = { id = 1, inbox_capacity = 64 }`",
                );
                continue;
            };
            if let Some((id, id_loc)) = id {
                out.push(ModSpec {
                    id,
                    id_loc,
                    name: name.to_string(),
                    inbox: policy(inbox),
                });
            }
        }
        out
    }

    /// A table letter: one ASCII character other than X.
    fn letter(&mut self, s: &str, loc: &Loc) -> Option<u8> {
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

    fn transport(
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
                    format!("add `kind = \"…\"`, one of: {}", kind_list()),
                );
                None
            }
            Some(v) => {
                let vl = self.vloc(v, &tloc);
                let names: Vec<&str> = TransportKind::ALL.iter().map(|k| k.as_str()).collect();
                self.choice(
                    v,
                    &format!("{path}.kind"),
                    &vl,
                    ("transport kind", "transport kinds"),
                    &names,
                )
                .map(|i| TransportKind::ALL[i])
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
            name: name.to_string(),
            name_loc: nloc.clone(),
            kind,
            delivery,
            attempts,
            max_in_flight,
            ordered,
            batch_linger_us,
            letter,
            settings: None,
            over: None,
            addr_source: AddrSource::Inline,
        };
        let Some(kind) = kind else {
            return Some(spec); // kind already reported; its keys cannot be judged
        };
        let errors_before = self.diag.errors.len();
        let extra: &[&str] = match kind {
            TransportKind::Inproc => &[],
            TransportKind::Udp | TransportKind::Tcp => &IP_KEYS,
            TransportKind::Ros1 => &ROS1_KEYS,
            TransportKind::Bluetooth => &BLUETOOTH_KEYS,
            TransportKind::Emulated => &EMULATED_KEYS,
            TransportKind::Zenoh | TransportKind::Mqtt | TransportKind::Dds => &[],
        };
        let raw_kind = matches!(
            kind,
            TransportKind::Zenoh | TransportKind::Mqtt | TransportKind::Dds
        );
        if !raw_kind {
            let mut allowed: Vec<&str> = COMMON_KEYS.iter().chain(extra).copied().collect();
            if kind == TransportKind::Emulated {
                allowed.extend(EMULATED_PARAMS);
            }
            self.unknown_keys(t, &allowed, Some(&path), &tloc);
        }
        let settings = match kind {
            TransportKind::Inproc => TransportSettings::Inproc,
            TransportKind::Udp | TransportKind::Tcp => {
                let endpoints = match t.get("endpoints") {
                    None => {
                        self.diag.err_help(
                            &tloc,
                            format!("transport `{name}` (kind {kind}) is missing required setting `endpoints`"),
                            "add `endpoints = { Alpha = \"127.0.0.1:7400\", … }`: one \"host:port\" per system it carries",
                        );
                        BTreeMap::new()
                    }
                    Some(v) => self.endpoints(v, &format!("{path}.endpoints"), &tloc, systems),
                };
                let max_message_bytes = t.get("max_message_bytes").and_then(|v| {
                    let vl = self.vloc(v, &tloc);
                    self.int_in(
                        v,
                        &format!("{path}.max_message_bytes"),
                        &vl,
                        1,
                        i64::MAX,
                        "a size in bytes, e.g. 1048576",
                    )
                    .map(|n| usize::try_from(n).unwrap_or(usize::MAX))
                });
                TransportSettings::Ip(IpSettings {
                    endpoints,
                    max_message_bytes,
                })
            }
            TransportKind::Ros1 => {
                let master_uri = match t.get("master_uri") {
                    None => assemble::default_master_uri(),
                    Some(v) => {
                        let vl = self.vloc(v, &tloc);
                        let help =
                            "write the master's XML-RPC URI, e.g. \"http://127.0.0.1:11311\"";
                        let s = self
                            .string(v, &format!("{path}.master_uri"), &vl, help)
                            .unwrap_or_default();
                        if !(s.starts_with("http://") || s.starts_with("https://")) && v.is_str() {
                            self.diag.err_help(
                                &vl,
                                format!("`{path}.master_uri` must be an http:// URI, found `{s}`"),
                                help,
                            );
                        }
                        s.to_string()
                    }
                };
                let namespace = t.get("namespace").and_then(|v| {
                    let vl = self.vloc(v, &tloc);
                    self.string(
                        v,
                        &format!("{path}.namespace"),
                        &vl,
                        "write a ROS namespace in quotes, e.g. \"/hetcomm\"",
                    )
                    .map(str::to_string)
                });
                let connect_timeout_ms = t.get("connect_timeout_ms").and_then(|v| {
                    let (vl, p) = (self.vloc(v, &tloc), format!("{path}.connect_timeout_ms"));
                    let help = "milliseconds a send waits for the subscriber, e.g. 500";
                    self.int_in(v, &p, &vl, 1, 600_000, help)
                        .map(|ms| ms as u64)
                });
                TransportSettings::Ros1(Ros1Settings {
                    master_uri,
                    namespace,
                    connect_timeout_ms,
                })
            }
            TransportKind::Bluetooth => {
                let channel = t.get("channel").map_or(1, |v| {
                    let vl = self.vloc(v, &tloc);
                    self.int_in(
                        v,
                        &format!("{path}.channel"),
                        &vl,
                        1,
                        30,
                        "RFCOMM channels are 1 to 30",
                    )
                    .map_or(1, |c| u8::try_from(c).unwrap_or(1))
                });
                let addresses = match (t.get("addresses"), t.get("addresses_file")) {
                    (Some(_), Some(f)) => {
                        let fl = self.vloc(f, &tloc);
                        self.diag.err_help(
                            &fl,
                            format!("transport `{name}` has both `addresses` and `addresses_file`"),
                            "keep one of them",
                        );
                        BTreeMap::new()
                    }
                    (Some(a), None) => {
                        self.addresses(a, &format!("{path}.addresses"), &tloc, systems)
                    }
                    (None, Some(f)) => {
                        let fl = self.vloc(f, &tloc);
                        match self.string(
                            f,
                            &format!("{path}.addresses_file"),
                            &fl,
                            "write a path in quotes, relative to the fleet file",
                        ) {
                            Some(s) => {
                                let p = match self.base_dir {
                                    Some(d) => d.join(s),
                                    None => PathBuf::from(s),
                                };
                                let lp = LegacyPath {
                                    display: Rc::from(p.display().to_string()),
                                    path: p,
                                    loc: fl,
                                };
                                spec.addr_source = AddrSource::File(lp.display.clone());
                                match self.read_legacy(&lp) {
                                    Some(text) => {
                                        let lines = legacy::parse_bluetooth(
                                            &lp.display,
                                            &text,
                                            &mut self.diag,
                                        );
                                        assemble::bt_addresses(
                                            lines,
                                            systems,
                                            &lp.display,
                                            &mut self.diag,
                                        )
                                    }
                                    None => BTreeMap::new(),
                                }
                            }
                            None => BTreeMap::new(),
                        }
                    }
                    (None, None) => {
                        self.diag.err_help(
                            &tloc,
                            format!("transport `{name}` (kind bluetooth) is missing required setting `addresses`"),
                            "add `addresses = { Alpha = \"68:A3:C4:4A:B3:BA\", … }`, or `addresses_file = \"bt.txt\"` in the Table 3 format",
                        );
                        BTreeMap::new()
                    }
                };
                TransportSettings::Bluetooth(BluetoothSettings { channel, addresses })
            }
            TransportKind::Emulated => self.emulated(t, &path, &tloc, &mut spec),
            TransportKind::Zenoh | TransportKind::Mqtt | TransportKind::Dds => {
                let raw = t
                    .iter()
                    .filter(|(k, _)| !COMMON_KEYS.contains(k))
                    .map(|(k, v)| (k.to_string(), self.stringify(v, false)))
                    .collect();
                TransportSettings::Raw(raw)
            }
        };
        if self.diag.errors.len() == errors_before {
            spec.settings = Some(settings);
        }
        Some(spec)
    }

    fn emulated(
        &mut self,
        t: &dyn TableLike,
        path: &str,
        tloc: &Loc,
        spec: &mut TransportSpec,
    ) -> TransportSettings {
        let profile = t.get("profile").and_then(|v| {
            let vl = self.vloc(v, tloc);
            self.choice(
                v,
                &format!("{path}.profile"),
                &vl,
                ("profile", "profiles"),
                &PROFILES,
            )
            .map(|i| PROFILES[i].to_string())
        });
        spec.over = t.get("over").and_then(|v| {
            let vl = self.vloc(v, tloc);
            self.string(
                v,
                &format!("{path}.over"),
                &vl,
                "write the wrapped transport's name in quotes",
            )
            .map(|s| (s.to_string(), vl))
        });
        let seed = t.get("seed").map_or(0, |v| {
            let vl = self.vloc(v, tloc);
            self.int_in(
                v,
                &format!("{path}.seed"),
                &vl,
                0,
                i64::MAX,
                "a whole number, e.g. 1",
            )
            .map_or(0, i64::unsigned_abs)
        });
        let mut params = BTreeMap::new();
        for (k, v) in t.iter() {
            if !EMULATED_PARAMS.contains(&k) {
                continue;
            }
            let vl = self.vloc(v, tloc);
            let kpath = format!("{path}.{k}");
            let n = match v.as_value() {
                Some(Value::Integer(i)) => *i.value() as f64,
                Some(Value::Float(f)) => *f.value(),
                _ => {
                    self.wrong_type(
                        &vl,
                        &kpath,
                        "a number",
                        v,
                        "write a number without quotes, e.g. 5.0",
                    );
                    continue;
                }
            };
            // Percentages are bounded; decibel-milliwatt levels may be negative; everything
            // else (times, sizes, distances, rates) may not.
            let ok = n.is_finite()
                && if k.ends_with("_percent") {
                    (0.0..=100.0).contains(&n)
                } else if k.ends_with("_dbm") {
                    true
                } else {
                    n >= 0.0
                };
            if !ok {
                let want = if k.ends_with("_percent") {
                    "from 0 to 100"
                } else if k.ends_with("_dbm") {
                    "a finite number"
                } else {
                    "0 or more"
                };
                self.diag.err_help(
                    &vl,
                    format!("`{kpath}` must be {want}, found {}", self.raw(v)),
                    "see docs/config.md for each parameter's unit",
                );
                continue;
            }
            params.insert(k.to_string(), n);
        }
        TransportSettings::Emulated(EmulatedSettings {
            over: spec.over.as_ref().map(|(s, _)| s.clone()),
            profile,
            seed,
            params,
        })
    }

    /// `endpoints = { System = "host:port", … }`.
    fn endpoints(
        &mut self,
        item: &Item,
        path: &str,
        tloc: &Loc,
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
            let ok = s.rsplit_once(':').is_some_and(|(h, p)| {
                !h.is_empty()
                    && !p.is_empty()
                    && p.bytes().all(|b| b.is_ascii_digit())
                    && p.parse::<u16>().is_ok()
            });
            if !ok {
                self.diag
                    .err_help(&vl, format!("malformed endpoint `{s}` for `{k}`"), help);
                continue;
            }
            if let Some(sys) = sys {
                out.insert(sys, s.to_string());
            }
        }
        out
    }

    /// `addresses = { System = "XX:XX:XX:XX:XX:XX", … }`.
    fn addresses(
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
    fn comm_table(&mut self, item: &Item, top: &Loc) -> Option<RawTable> {
        let loc = self.vloc(item, top);
        let t = self.table(item, "table", &loc)?;
        let mut columns = Vec::new();
        let Some(c) = t.get("columns") else {
            // A typo of `columns` would otherwise read as a row of an unknown system.
            let mut typo = false;
            for (k, _) in t.iter() {
                if suggest::closest(k, &["columns"]).is_some() {
                    let kl = self.kloc(t, k, &loc);
                    self.diag.err_help(
                        &kl,
                        format!("unknown key `{k}` in `table`"),
                        "did you mean `columns`?",
                    );
                    typo = true;
                }
            }
            if !typo && t.iter().next().is_some() {
                self.diag.err_help(
                    &loc,
                    "the table has no `columns`",
                    "add `columns = [\"Alpha\", …]`: the destination systems, in cell order",
                );
            }
            return None;
        };
        let cl = self.vloc(c, &loc);
        let Some(arr) = c.as_array() else {
            self.wrong_type(
                &cl,
                "table.columns",
                "an array of system names",
                c,
                "e.g. `columns = [\"Alpha\", \"Charlie\"]`",
            );
            return None; // without columns, every row would be reported as ragged
        };
        let mut columns_ok = true;
        for v in arr.iter() {
            let vl = self.at(v.span(), &cl);
            match v {
                Value::String(s) => columns.push(label(s.value(), &vl)),
                Value::Integer(i) => columns.push(Label {
                    text: i.value().to_string(),
                    loc: vl,
                    by_id: true,
                }),
                other => {
                    let found = format!(
                        "{} `{}`",
                        type_name(&Item::Value(other.clone())),
                        other
                            .span()
                            .and_then(|r| self.text.get(r))
                            .unwrap_or("")
                            .trim()
                    );
                    self.diag.err_help(
                        &vl,
                        format!("`table.columns` must list system names, found {found}"),
                        "e.g. `columns = [\"Alpha\", \"Charlie\"]`",
                    );
                    columns_ok = false;
                }
            }
        }
        if !columns_ok {
            return None;
        }
        let mut rows = Vec::new();
        for (k, v) in t.iter() {
            if k == "columns" {
                continue;
            }
            let kl = self.kloc(t, k, &loc);
            let vl = self.vloc(v, &kl);
            let path = format!("table.{}", key_part(k));
            let Some(arr) = v.as_array() else {
                self.wrong_type(
                    &vl,
                    &path,
                    "an array of cells",
                    v,
                    "e.g. `Alpha = [\"X\", \"wired\"]`: one transport name, letter or X per column",
                );
                continue;
            };
            let mut cells = Vec::new();
            for c in arr.iter() {
                let cl = self.at(c.span(), &vl);
                match c.as_str() {
                    Some(s) => cells.push(RawCell {
                        text: s.to_string(),
                        loc: cl,
                    }),
                    None => {
                        let found = format!(
                            "{} `{}`",
                            type_name(&Item::Value(c.clone())),
                            c.span().and_then(|r| self.text.get(r)).unwrap_or("").trim()
                        );
                        self.diag.err_help(
                            &cl,
                            format!("`{path}` cells must be strings, found {found}"),
                            "write a transport name, a letter or \"X\" in quotes",
                        );
                        // A placeholder keeps the row's length right for the shape checks.
                        cells.push(RawCell {
                            text: "X".to_string(),
                            loc: cl,
                        });
                    }
                }
            }
            rows.push((label(k, &kl), cells));
        }
        Some(RawTable {
            header_loc: loc,
            columns,
            rows,
        })
    }

    /// A value as a string for `Raw` settings: strings unquoted, everything else as TOML.
    fn stringify(&self, item: &Item, nested: bool) -> String {
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

/// A system named by a fleet-file key or string.
fn label(text: &str, loc: &Loc) -> Label {
    Label {
        text: text.to_string(),
        loc: loc.clone(),
        by_id: false,
    }
}

fn kind_list() -> String {
    TransportKind::ALL
        .iter()
        .map(|k| k.as_str())
        .collect::<Vec<_>>()
        .join(", ")
}

/// Turns inbox parts into the model's policy.
fn policy(d: InboxDefaults) -> InboxConfig {
    InboxConfig {
        capacity: d.capacity,
        overflow: match d.overflow {
            1 => OverflowPolicy::DropNewest,
            2 => OverflowPolicy::Block {
                timeout: Duration::from_millis(d.timeout_ms),
            },
            _ => OverflowPolicy::DropOldest,
        },
    }
}

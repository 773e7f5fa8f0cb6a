//! The fleet file walker. It reads the document with `toml_edit`'s span-keeping parser and
//! checks every key by hand instead of deriving serde structs: derived errors can neither
//! collect more than one problem nor say "did you mean", and their wording is not ours.

mod modules;
mod reader;
mod scan;
mod security;
mod systems;
mod table;
mod transports;
mod values;

use modules::policy;
pub use reader::SettingsReader;

use std::collections::BTreeMap;
use std::ops::Range;
use std::path::{Path, PathBuf};
use std::rc::Rc;
use std::time::Duration;

use rustc_hash::FxHashMap;
use toml_edit::{ImDocument, Item, TableLike, Value};

use crate::assemble::{
    self, BtLine, Label, LegacyBt, LetterSpec, ModSpec, Parts, RawTable, SysSpec, Systems,
    TransportSpec, DEFAULT_MODULES,
};
use crate::error::{ConfigErrors, Diag, LineIndex, Loc};
use crate::kinds::Kinds;
use crate::legacy;
use crate::model::*;
use crate::suggest;

/// Keys allowed at the top level.
pub(crate) const TOP_KEYS: [&str; 10] = [
    "name",
    "security",
    "systems",
    "modules",
    "inbox",
    "transports",
    "table",
    "legacy",
    "letters",
    "tap",
];
/// Keys of `[inbox]`.
pub(crate) const INBOX_KEYS: [&str; 3] = ["capacity", "overflow", "block_timeout_ms"];
/// Keys of a module's long form.
pub(crate) const MODULE_KEYS: [&str; 4] = ["id", "inbox_capacity", "overflow", "block_timeout_ms"];
/// Keys of a system's long form.
pub(crate) const SYSTEM_KEYS: [&str; 5] = [
    "id",
    "modules",
    "public_key",
    "public_key_file",
    "private_key_file",
];
/// Keys of `[security]`.
pub(crate) const SECURITY_KEYS: [&str; 2] = ["keys", "in_process"];
/// Values of a transport's `security`, in `SecurityMode` order.
pub(crate) const SECURITY_MODES: [&str; 2] = ["keys", "none"];
/// Keys of `[legacy]`.
pub(crate) const LEGACY_KEYS: [&str; 3] = ["ids", "table", "bluetooth"];
/// Keys every transport accepts.
pub(crate) const COMMON_KEYS: [&str; 9] = [
    "kind",
    "delivery",
    "attempts",
    "max_in_flight",
    "max_in_flight_bytes",
    "letter",
    "ordered",
    "batch_linger_us",
    "security",
];
/// Overflow policy names.
pub(crate) const OVERFLOWS: [&str; 3] = ["drop-oldest", "drop-newest", "block"];
/// Delivery mode names.
pub(crate) const DELIVERIES: [&str; 2] = ["acknowledged", "unacknowledged"];

/// Which key files a load reads.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub(crate) enum KeyReading {
    /// Every one: `[security] keys` and `public_key_file`s.
    All,
    /// `public_key_file`s, not the `[security] keys` directory (another directory replaces it).
    NotDir,
    /// None (`hetcomm keygen`, run to create them).
    Nothing,
}

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
    /// The kinds registered beyond the built-in ones.
    kinds: &'a Kinds,
    /// Which key files are read.
    read_keys: KeyReading,
    /// Systems of `[systems]` left out for an error in their entry (a bad or missing id).
    unusable_systems: Vec<String>,
    /// Every `udp` / `tcp` endpoint so far, by (kind, host in lower case, port).
    endpoints_seen: FxHashMap<(TransportKind, String, u16), SeenEndpoint>,
}

/// Where an endpoint was first given, for the error about a second system using it.
struct SeenEndpoint {
    transport: String,
    system: String,
    endpoint: String,
    loc: Loc,
}

/// Parses and validates a fleet file's text.
pub(crate) fn parse(
    text: &str,
    origin: &str,
    base_dir: Option<&Path>,
    source: Option<PathBuf>,
    kinds: &Kinds,
    read_keys: KeyReading,
) -> Result<Fleet, ConfigErrors> {
    parse_with(text, origin, base_dir, source, kinds, read_keys, true).0
}

/// [`parse`], reading a plain `[table]` with [`scan`] when `fast` (and it can); also says
/// whether it did.
fn parse_with(
    text: &str,
    origin: &str,
    base_dir: Option<&Path>,
    source: Option<PathBuf>,
    kinds: &Kinds,
    read_keys: KeyReading,
    fast: bool,
) -> (Result<Fleet, ConfigErrors>, bool) {
    let file: Rc<str> = Rc::from(origin);
    if let Some(scanned) = fast.then(|| scan::scan(text, &file)).flatten() {
        // The rest must not define `table` again (that is an error the long way reports) nor
        // `[legacy]` (which decides whether `[table]` is allowed at all).
        if let Ok(doc) = ImDocument::parse(scanned.rest.as_str()) {
            let root = doc.as_table();
            if !root.contains_key("table") && !root.contains_key("legacy") {
                let mut p = P {
                    file,
                    text: &scanned.rest,
                    idx: LineIndex::new(&scanned.rest),
                    diag: Diag::default(),
                    base_dir,
                    kinds,
                    read_keys,
                    unusable_systems: Vec::new(),
                    endpoints_seen: FxHashMap::default(),
                };
                let parts = p.walk(root, source, Some(scanned.table));
                let fleet = assemble::finish(parts, kinds, p.diag);
                return (with_taps(fleet, root, &scanned.rest, origin), true);
            }
        }
    }
    let mut p = P {
        file,
        text,
        idx: LineIndex::new(text),
        diag: Diag::default(),
        base_dir,
        kinds,
        read_keys,
        unusable_systems: Vec::new(),
        endpoints_seen: FxHashMap::default(),
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
            return (Err(ConfigErrors(p.diag.errors)), false);
        }
    };
    let parts = p.walk(doc.as_table(), source, None);
    let fleet = assemble::finish(parts, kinds, p.diag);
    (with_taps(fleet, doc.as_table(), text, origin), false)
}

/// Reads the fleet file's `[[tap]]` tables with the scenario file's parser, checked against
/// the fleet the rest of the file built (so only once that is valid).
fn with_taps(
    fleet: Result<Fleet, ConfigErrors>,
    root: &toml_edit::Table,
    text: &str,
    origin: &str,
) -> Result<Fleet, ConfigErrors> {
    let mut fleet = fleet?;
    if root.contains_key("tap") {
        fleet.taps = crate::scenario::parse_fleet_taps(root, text, origin, &fleet)?;
    }
    Ok(fleet)
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
    /// Walks the document's sections in dependency order. `table` is the `[table]` section
    /// when [`scan`] already read it (the document then has none).
    fn walk(
        &mut self,
        root: &dyn TableLike,
        source: Option<PathBuf>,
        table: Option<RawTable>,
    ) -> Parts {
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
                                keys: Default::default(),
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
        let mut systems = Systems::new(specs, &mut self.diag);
        systems.mark_reported(std::mem::take(&mut self.unusable_systems));
        let keys_dir = get("security").and_then(|item| self.security(item, &top, &mut systems));
        let secure_in_process = get("security")
            .and_then(|item| self.security_in_process(item, &top))
            .unwrap_or(false);

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
                        // TOML keeps keys apart that Unicode spells two ways; names do not.
                        if let Some(first) = transports
                            .iter()
                            .find(|t: &&assemble::TransportSpec| t.name == spec.name)
                        {
                            self.diag.err_help(
                                &nloc,
                                format!(
                                    "duplicate transport name `{}` (spelled differently in Unicode)",
                                    spec.name
                                ),
                                format!(
                                    "give each transport its own name (the first is at {})",
                                    assemble::at(&first.name_loc)
                                ),
                            );
                            continue;
                        }
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
                            target: crate::names::nfc(target).into_owned(),
                            target_loc: vl,
                        });
                    }
                }
            }
        }

        // The table.
        let table = match (&l_table, get("table")) {
            _ if table.is_some() => table,
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
            keys_dir,
            secure_in_process,
            fallback: top,
            b_help: "add `bluetooth = \"bt.txt\"` (the Table 3 format) under [legacy], or map B \
                     to a transport in [letters]",
        }
    }

    /// A path written in the fleet file, resolved against its directory.
    fn resolve(&self, written: &str) -> PathBuf {
        match self.base_dir {
            Some(d) => d.join(written),
            None => PathBuf::from(written),
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
}

/// A system named by a fleet-file key or string.
fn label(text: &str, loc: &Loc) -> Label {
    Label {
        text: text.to_string(),
        loc: loc.clone(),
        by_id: false,
    }
}

fn kind_list(kinds: &Kinds) -> String {
    kinds.names().join(", ")
}

//! The checks shared by the TOML loader and the legacy-only loader: both first turn their
//! files into the located "raw" parts below, then [`finish`] resolves names, letters and the
//! table into a [`Fleet`]. Keeping one path means a legacy table gets exactly the same
//! validation whether it is loaded alone or through a fleet file's `[legacy]` section.

use std::borrow::Cow;
use std::collections::{BTreeMap, HashMap};
use std::path::PathBuf;
use std::rc::Rc;

use hetcomm_core::{ModuleId, SystemId};
use rustc_hash::{FxHashMap, FxHashSet};

use crate::error::{ConfigErrors, Diag, Loc};
use crate::legacy::check_id;
use crate::model::*;
use crate::{names, suggest};

/// One `<id> <name>` line of a legacy id file.
pub(crate) struct IdLine {
    pub id: u16,
    pub id_loc: Loc,
    pub name: String,
    pub name_loc: Loc,
}

/// A reference to a system as written: a name (fleet file) or an id token (legacy files).
pub(crate) struct Label {
    pub text: String,
    pub loc: Loc,
    /// True when `text` must be a numeric id (legacy files), false when it is a name (a
    /// numeric id is still accepted if no system has that name).
    pub by_id: bool,
}

/// One table cell as written: which of the table's distinct texts it is, and where. Tables
/// can hold millions of cells, so a cell is 12 bytes: its text is interned and its file is
/// the table's.
#[derive(Clone, Copy, Debug)]
pub(crate) struct RawCell {
    /// Index into [`RawTable::texts`].
    pub text: u32,
    /// 1-based line.
    pub line: u32,
    /// 1-based column, in characters.
    pub column: u32,
}

/// One row of a table: the source system as written and its cells, in column order.
pub(crate) struct RawRow {
    pub label: Label,
    /// Where the row's cells are in [`RawTable::cells`].
    pub cells: std::ops::Range<usize>,
}

/// A communication table before its systems and letters are resolved.
pub(crate) struct RawTable {
    /// The file every cell is in.
    pub file: Rc<str>,
    pub header_loc: Loc,
    pub columns: Vec<Label>,
    pub rows: Vec<RawRow>,
    /// The distinct cell texts, in order of first appearance.
    pub texts: Vec<String>,
    /// Every row's cells, row after row.
    pub cells: Vec<RawCell>,
    /// `texts` by text, while cells are added.
    index: FxHashMap<String, u32>,
}

impl RawTable {
    /// An empty table with these columns; rows are added with [`RawTable::start_row`] and
    /// [`RawTable::push_cell`].
    pub fn new(file: Rc<str>, header_loc: Loc, columns: Vec<Label>) -> RawTable {
        RawTable {
            file,
            header_loc,
            columns,
            rows: Vec::new(),
            texts: Vec::new(),
            cells: Vec::new(),
            index: FxHashMap::default(),
        }
    }

    /// Starts a row; the cells pushed next belong to it.
    pub fn start_row(&mut self, label: Label) {
        let at = self.cells.len();
        self.rows.push(RawRow {
            label,
            cells: at..at,
        });
    }

    /// Adds a cell to the last row started.
    pub fn push_cell(&mut self, text: &str, line: usize, column: usize) {
        let id = match self.index.get(text) {
            Some(&id) => id,
            None => {
                let id = u32::try_from(self.texts.len()).unwrap_or(u32::MAX);
                self.texts.push(text.to_string());
                self.index.insert(text.to_string(), id);
                id
            }
        };
        self.cells.push(RawCell {
            text: id,
            line: u32::try_from(line).unwrap_or(u32::MAX),
            column: u32::try_from(column).unwrap_or(u32::MAX),
        });
        if let Some(row) = self.rows.last_mut() {
            row.cells.end = self.cells.len();
        }
    }

    /// Where a cell is.
    pub fn loc(&self, c: &RawCell) -> Loc {
        Loc {
            file: self.file.clone(),
            line: c.line as usize,
            column: c.column as usize,
        }
    }

    /// A cell's text.
    pub fn text(&self, c: &RawCell) -> &str {
        &self.texts[c.text as usize]
    }
}

/// One `<id> <address>` entry (legacy file) or `name = "address"` entry (fleet file).
pub(crate) struct BtLine {
    pub key: Label,
    pub addr: String,
    pub addr_loc: Loc,
}

/// A system before duplicate checks.
pub(crate) struct SysSpec {
    pub id: u16,
    pub id_loc: Loc,
    pub name: String,
    pub name_loc: Loc,
    /// The `modules = [...]` list, names with their locations.
    pub modules: Option<Vec<(String, Loc)>>,
}

/// A module before duplicate checks.
pub(crate) struct ModSpec {
    pub id: u16,
    pub id_loc: Loc,
    pub name: String,
    pub inbox: InboxConfig,
}

/// Where a Bluetooth transport's addresses came from, so a missing one can be fixed in the
/// right place.
#[derive(Clone)]
pub(crate) enum AddrSource {
    /// `addresses = { … }` in the fleet file.
    Inline,
    /// A file in the Table 3 format.
    File(Rc<str>),
}

/// A transport before letters and the table are resolved.
pub(crate) struct TransportSpec {
    pub name: String,
    pub name_loc: Loc,
    pub kind: Option<TransportKind>,
    pub delivery: DeliveryMode,
    pub attempts: u32,
    pub max_in_flight: u32,
    pub ordered: bool,
    pub batch_linger_us: u32,
    pub letter: Option<(u8, Loc)>,
    /// None when the transport had errors; it still counts as defined so the table does not
    /// report it a second time as unknown.
    pub settings: Option<TransportSettings>,
    /// The `over` name of an emulated transport, with its location.
    pub over: Option<(String, Loc)>,
    pub addr_source: AddrSource,
}

/// One `[letters]` entry.
pub(crate) struct LetterSpec {
    pub letter: u8,
    pub letter_loc: Loc,
    pub target: String,
    pub target_loc: Loc,
}

/// The addresses of a legacy Bluetooth file, for the implicit `B` transport.
pub(crate) struct LegacyBt {
    pub addresses: BTreeMap<SystemId, BdAddr>,
    pub file: Rc<str>,
}

/// Everything a loader gathered, ready for [`finish`].
pub(crate) struct Parts {
    pub name: Option<String>,
    pub source: Option<PathBuf>,
    pub systems: Systems,
    pub modules: Vec<ModuleDef>,
    pub transports: Vec<TransportSpec>,
    pub letters: Vec<LetterSpec>,
    pub table: Option<RawTable>,
    pub legacy_bt: Option<LegacyBt>,
    /// Where to report "B needs addresses" when no cell location is better.
    pub fallback: Loc,
}

/// The fleet's systems after duplicate checks, with name and id lookups.
pub(crate) struct Systems {
    /// Sorted by id.
    pub list: Vec<SysSpec>,
    /// Index into `list` by name (in NFC).
    by_name: FxHashMap<String, usize>,
    /// Names dropped as duplicates or for their characters: already reported, so references
    /// to them stay quiet.
    rejected: FxHashSet<String>,
    /// Ids of dropped systems that no kept system has, likewise.
    rejected_ids: FxHashSet<u16>,
}

/// The modules the thesis's framework uses, for fleets that do not list their own.
pub(crate) const DEFAULT_MODULES: [(&str, u16); 4] =
    [("Sense", 0), ("Plan", 1), ("Act", 2), ("World", 3)];

/// The valid Bluetooth address shape, quoted in help texts.
const BDADDR_HELP: &str =
    "write six two-digit hex bytes separated by colons, e.g. 68:A3:C4:4A:B3:BA";

impl Systems {
    /// Normalises names to NFC, checks their characters, checks ids and names for duplicates
    /// (reporting the later one) and sorts by id.
    pub fn new(mut list: Vec<SysSpec>, diag: &mut Diag) -> Systems {
        for s in &mut list {
            if let Cow::Owned(n) = names::nfc(&s.name) {
                s.name = n;
            }
        }
        let mut ids: FxHashMap<u16, usize> = FxHashMap::default();
        let mut by_name: FxHashMap<&str, usize> = FxHashMap::default();
        let mut keep = vec![true; list.len()];
        for (i, s) in list.iter().enumerate() {
            if s.name.is_empty() {
                diag.err_help(
                    &s.name_loc,
                    "a system name cannot be empty",
                    "give the system a name, e.g. `Alpha`",
                );
            } else if let Some(c) = names::bad_char(&s.name) {
                diag.err_help(
                    &s.name_loc,
                    format!(
                        "system name `{}` contains {}, which a name cannot contain",
                        names::visible(&s.name),
                        names::describe(c)
                    ),
                    format!("a name may contain {}", names::NAME_CHARS),
                );
                keep[i] = false;
            }
            if let Some(&j) = ids.get(&s.id) {
                let first = &list[j];
                diag.err_help(
                    &s.id_loc,
                    format!(
                        "duplicate system id {}: `{}` and `{}` both use it",
                        s.id, first.name, s.name
                    ),
                    format!(
                        "give each system its own id (`{}` has it at {})",
                        first.name,
                        at(&first.id_loc)
                    ),
                );
                keep[i] = false;
            } else if keep[i] {
                ids.insert(s.id, i);
            }
            if let Some(&j) = by_name.get(s.name.as_str()) {
                let first = &list[j];
                diag.err_help(
                    &s.name_loc,
                    format!(
                        "duplicate system name `{}`: ids {} and {} both use it",
                        s.name, first.id, s.id
                    ),
                    format!(
                        "give each system its own name (the first is at {})",
                        at(&first.name_loc)
                    ),
                );
                keep[i] = false;
            } else if keep[i] {
                by_name.insert(&s.name, i);
            }
        }
        // A dropped system's name and id stay known as "already reported", unless a kept
        // system has them, so the table and the address lists do not report them again.
        let kept_ids: FxHashSet<u16> = list
            .iter()
            .zip(&keep)
            .filter(|(_, k)| **k)
            .map(|(s, _)| s.id)
            .collect();
        let kept_names: FxHashSet<&str> = list
            .iter()
            .zip(&keep)
            .filter(|(_, k)| **k)
            .map(|(s, _)| s.name.as_str())
            .collect();
        let mut rejected = FxHashSet::default();
        let mut rejected_ids = FxHashSet::default();
        for (s, _) in list.iter().zip(&keep).filter(|(_, k)| !**k) {
            if !kept_names.contains(s.name.as_str()) {
                rejected.insert(s.name.clone());
            }
            if !kept_ids.contains(&s.id) {
                rejected_ids.insert(s.id);
            }
        }
        drop(by_name);
        let mut it = keep.into_iter();
        list.retain(|_| it.next().unwrap_or(false));
        list.sort_by_key(|s| s.id);
        let by_name = list
            .iter()
            .enumerate()
            .map(|(i, s)| (s.name.clone(), i))
            .collect();
        Systems {
            list,
            by_name,
            rejected,
            rejected_ids,
        }
    }

    /// The position in `list` of the system with this id.
    pub fn index_of(&self, id: SystemId) -> Option<usize> {
        self.list.binary_search_by_key(&id.0, |s| s.id).ok()
    }

    fn has_id(&self, id: u16) -> bool {
        self.index_of(SystemId(id)).is_some()
    }

    /// The name of a system, for messages.
    pub fn name(&self, id: SystemId) -> &str {
        self.index_of(id)
            .map_or("?", |i| self.list[i].name.as_str())
    }

    fn names(&self) -> Vec<&str> {
        self.list.iter().map(|s| s.name.as_str()).collect()
    }

    /// Resolves a written system reference, reporting an unknown one. `context` says where it
    /// was written ("the table's columns"); `extra` are other words that are valid at that
    /// spot, so a typo of them is suggested too (but they are not listed as systems).
    pub fn resolve(
        &self,
        label: &Label,
        context: &str,
        extra: &[&str],
        diag: &mut Diag,
    ) -> Option<SystemId> {
        if label.by_id {
            let id = check_id(diag, &label.text, &label.loc, "system", "a system id")?;
            if self.has_id(id) {
                return Some(SystemId(id));
            }
            if self.rejected_ids.contains(&id) {
                return None;
            }
            let known: Vec<String> = self.list.iter().map(|s| s.id.to_string()).collect();
            diag.err_help(
                &label.loc,
                format!("unknown system id {id} in {context}"),
                if known.is_empty() {
                    "no systems are defined".to_string()
                } else {
                    format!("known system ids: {}", known.join(", "))
                },
            );
            return None;
        }
        let name = names::nfc(&label.text);
        if let Some(&i) = self.by_name.get(name.as_ref()) {
            return Some(SystemId(self.list[i].id));
        }
        if self.rejected.contains(name.as_ref()) {
            return None;
        }
        // A numeric key is taken as an id, so `addresses = { 1 = "…" }` works like Table 3.
        if let Ok(id) = label.text.parse::<u16>() {
            if label.text.bytes().all(|b| b.is_ascii_digit()) {
                if self.has_id(id) {
                    return Some(SystemId(id));
                }
                if self.rejected_ids.contains(&id) {
                    return None;
                }
            }
        }
        let names = self.names();
        let mut cands = names.clone();
        cands.extend_from_slice(extra);
        let help = match suggest::closest(&name, &cands) {
            Some(c) => format!("did you mean `{c}`?"),
            None if names.is_empty() => "there are no known systems".to_string(),
            None => format!("known systems: {}", names.join(", ")),
        };
        diag.err_help(
            &label.loc,
            format!("unknown system `{}` in {context}", label.text),
            help,
        );
        None
    }
}

/// "1 cell", "2 cells".
fn plural(n: usize, word: &str) -> String {
    if n == 1 {
        format!("1 {word}")
    } else {
        format!("{n} {word}s")
    }
}

/// "file:line:column", for help texts that point at a second place.
pub(crate) fn at(loc: &Loc) -> String {
    format!("{}:{}:{}", loc.file, loc.line, loc.column)
}

/// Checks module ids for duplicates and sorts by id.
pub(crate) fn modules(mut list: Vec<ModSpec>, diag: &mut Diag) -> Vec<ModuleDef> {
    let mut seen: HashMap<u16, usize> = HashMap::new();
    let mut by_name: HashMap<&str, usize> = HashMap::new();
    let mut keep = vec![true; list.len()];
    for (i, m) in list.iter().enumerate() {
        if let Some(c) = names::bad_char(&m.name) {
            diag.err_help(
                &m.id_loc,
                format!(
                    "module name `{}` contains {}, which a name cannot contain",
                    names::visible(&m.name),
                    names::describe(c)
                ),
                format!("a name may contain {}", names::NAME_CHARS),
            );
        }
        if let Some(&j) = by_name.get(m.name.as_str()) {
            diag.err_help(
                &m.id_loc,
                format!(
                    "duplicate module name `{}` (spelled differently in Unicode)",
                    m.name
                ),
                format!(
                    "give each module its own name (the first has its id at {})",
                    at(&list[j].id_loc)
                ),
            );
            keep[i] = false;
            continue;
        }
        by_name.insert(&m.name, i);
        if let Some(&j) = seen.get(&m.id) {
            let first = &list[j];
            diag.err_help(
                &m.id_loc,
                format!(
                    "duplicate module id {}: `{}` and `{}` both use it",
                    m.id, first.name, m.name
                ),
                format!(
                    "give each module its own id (`{}` has it at {})",
                    first.name,
                    at(&first.id_loc)
                ),
            );
            keep[i] = false;
        } else {
            seen.insert(m.id, i);
        }
    }
    let mut it = keep.into_iter();
    list.retain(|_| it.next().unwrap_or(false));
    list.sort_by_key(|m| m.id);
    list.into_iter()
        .map(|m| ModuleDef {
            id: ModuleId(m.id),
            name: m.name,
            inbox: m.inbox,
        })
        .collect()
}

/// Parses `XX:XX:XX:XX:XX:XX` (hex digits in either case).
pub(crate) fn parse_bdaddr(s: &str) -> Option<BdAddr> {
    let mut out = [0u8; 6];
    let mut parts = s.split(':');
    for byte in &mut out {
        let p = parts.next()?;
        if p.len() != 2 || !p.bytes().all(|b| b.is_ascii_hexdigit()) {
            return None;
        }
        *byte = u8::from_str_radix(p, 16).ok()?;
    }
    parts.next().is_none().then_some(BdAddr(out))
}

/// Resolves Bluetooth address entries: known systems, well-formed and unique addresses.
pub(crate) fn bt_addresses(
    lines: Vec<BtLine>,
    systems: &Systems,
    context: &str,
    diag: &mut Diag,
) -> BTreeMap<SystemId, BdAddr> {
    let mut out = BTreeMap::new();
    let mut by_addr: HashMap<BdAddr, SystemId> = HashMap::new();
    for l in lines {
        let sys = systems.resolve(&l.key, context, &[], diag);
        let Some(addr) = parse_bdaddr(&l.addr) else {
            diag.err_help(
                &l.addr_loc,
                format!("malformed Bluetooth address `{}`", l.addr),
                BDADDR_HELP,
            );
            continue;
        };
        let Some(sys) = sys else { continue };
        if out.contains_key(&sys) {
            diag.err_help(
                &l.key.loc,
                format!("system `{}` has two Bluetooth addresses", systems.name(sys)),
                "keep one address per system",
            );
            continue;
        }
        if let Some(&other) = by_addr.get(&addr) {
            diag.err_help(
                &l.addr_loc,
                format!(
                    "Bluetooth address {addr} is already used by system `{}`",
                    systems.name(other)
                ),
                "each system has its own adapter; check for a copy-paste slip",
            );
            continue;
        }
        by_addr.insert(addr, sys);
        out.insert(sys, addr);
    }
    out
}

/// The ROS master URI when the file gives none: the environment's, as ROS tools do.
pub(crate) fn default_master_uri() -> String {
    std::env::var("ROS_MASTER_URI")
        .ok()
        .filter(|s| !s.trim().is_empty())
        .unwrap_or_else(|| "http://localhost:11311".to_string())
}

/// Resolves the table, letters and transport cross-references, and builds the [`Fleet`].
pub(crate) fn finish(p: Parts, mut diag: Diag) -> Result<Fleet, ConfigErrors> {
    let Parts {
        name,
        source,
        systems,
        modules,
        mut transports,
        letters,
        table,
        legacy_bt,
        fallback,
    } = p;

    // Letters: from transports' own `letter` first (file order), then [letters]. A letter may
    // be given twice only if both agree.
    let mut letter_map: BTreeMap<u8, (usize, Loc)> = BTreeMap::new();
    let mut tag_of: Vec<Option<u8>> = transports
        .iter()
        .map(|t| t.letter.as_ref().map(|l| l.0))
        .collect();
    for (i, t) in transports.iter().enumerate() {
        if let Some((l, loc)) = &t.letter {
            define_letter(&mut letter_map, *l, i, loc, &transports, &mut diag);
        }
    }
    for l in &letters {
        let Some(i) = transports.iter().position(|t| t.name == l.target) else {
            let names: Vec<&str> = transports.iter().map(|t| t.name.as_str()).collect();
            diag.err_help(
                &l.target_loc,
                format!(
                    "letter `{}` maps to `{}`, which is not a transport",
                    l.letter as char, l.target
                ),
                suggest::help(&l.target, &names, "defined transports"),
            );
            continue;
        };
        define_letter(
            &mut letter_map,
            l.letter,
            i,
            &l.letter_loc,
            &transports,
            &mut diag,
        );
        tag_of[i].get_or_insert(l.letter);
    }

    // Emulated transports must wrap a defined, non-emulated-cycle transport.
    check_over(&transports, &mut diag);

    // The table. Pairs are collected in file order (so that each problem is reported at the
    // first cell showing it) and sorted into the map only once the fleet is known to be valid.
    let mut pairs: Vec<((SystemId, SystemId), usize)> = Vec::new();
    if let Some(table) = table.as_ref().filter(|t| {
        let empty = t.columns.is_empty() && !t.rows.is_empty();
        if empty {
            diag.err_help(
                &t.header_loc,
                "the table has rows but no columns",
                "list the destination systems as columns",
            );
        }
        !empty
    }) {
        pairs = table_pairs(
            table,
            &systems,
            &letter_map,
            &mut transports,
            &mut tag_of,
            legacy_bt.as_ref(),
            &mut diag,
        );
    }
    drop(table);

    // Systems' module lists.
    let mut system_defs = Vec::new();
    for s in &systems.list {
        let mods = s.modules.as_ref().map(|list| {
            let mut ids = Vec::new();
            for (m, loc) in list {
                match modules.iter().find(|d| &d.name == m) {
                    Some(d) if ids.contains(&d.id) => diag.err_help(
                        loc,
                        format!("module `{m}` is listed twice for system `{}`", s.name),
                        "list each module once",
                    ),
                    Some(d) => ids.push(d.id),
                    None => {
                        let names: Vec<&str> = modules.iter().map(|d| d.name.as_str()).collect();
                        diag.err_help(
                            loc,
                            format!("unknown module `{m}` in the modules of system `{}`", s.name),
                            suggest::help(m, &names, "known modules"),
                        );
                    }
                }
            }
            ids.sort();
            ids
        });
        system_defs.push(SystemDef {
            id: SystemId(s.id),
            name: s.name.clone(),
            modules: mods,
        });
    }

    if !diag.errors.is_empty() {
        return Err(diag.into_sorted());
    }
    let mut defs = Vec::new();
    for (t, tag) in transports.into_iter().zip(tag_of) {
        let (Some(kind), Some(settings)) = (t.kind, t.settings) else {
            // Only reachable with errors recorded, which returned above; reported rather than
            // panicking in case a loader ever forgets to record one.
            return Err(ConfigErrors(vec![crate::ConfigError {
                file: fallback.file.to_string(),
                line: t.name_loc.line,
                column: t.name_loc.column,
                message: format!("transport `{}` is incomplete", t.name),
                help: None,
            }]));
        };
        defs.push(TransportDef {
            tag: tag.unwrap_or_else(|| t.name.as_bytes().first().copied().unwrap_or(b'?')),
            name: t.name,
            kind,
            delivery: t.delivery,
            attempts: t.attempts,
            max_in_flight: t.max_in_flight,
            ordered: t.ordered,
            batch_linger_us: t.batch_linger_us,
            settings,
        });
    }
    // Sorting is linear when the rows and columns are already in id order; building the map
    // from sorted pairs fills its nodes.
    pairs.sort_unstable_by_key(|&(k, _)| k);
    Ok(Fleet {
        name,
        source,
        systems: system_defs,
        modules,
        transports: defs,
        table: pairs.into_iter().collect(),
    })
}

/// Resolves the table's rows, columns and cells: reports unknown or repeated systems, a
/// non-square table, ragged rows, self-pairs, cells naming nothing and systems a transport has
/// no endpoint or address for; returns the (source, destination) → transport pairs in file
/// order.
fn table_pairs(
    table: &RawTable,
    systems: &Systems,
    letter_map: &BTreeMap<u8, (usize, Loc)>,
    transports: &mut Vec<TransportSpec>,
    tag_of: &mut Vec<Option<u8>>,
    legacy_bt: Option<&LegacyBt>,
    diag: &mut Diag,
) -> Vec<((SystemId, SystemId), usize)> {
    let cols: Vec<Option<SystemId>> = table
        .columns
        .iter()
        .map(|c| systems.resolve(c, "the table's columns", &[], diag))
        .collect();
    let rows: Vec<Option<SystemId>> = table
        .rows
        .iter()
        .map(|r| systems.resolve(&r.label, "the table's rows", &["columns"], diag))
        .collect();
    // With an unresolved label, "no matching row/column" would only repeat that error.
    let cols_ok = cols.iter().all(Option::is_some);
    let rows_ok = rows.iter().all(Option::is_some);
    let mut col_set = vec![false; systems.list.len()];
    for (c, label) in cols.iter().zip(&table.columns) {
        if let Some(i) = c.and_then(|id| systems.index_of(id)) {
            if std::mem::replace(&mut col_set[i], true) {
                diag.err_help(
                    &label.loc,
                    format!("column `{}` appears twice", label.text),
                    "list each system once among the columns",
                );
            }
        }
    }
    let mut row_set = vec![false; systems.list.len()];
    for (r, row) in rows.iter().zip(&table.rows) {
        let label = &row.label;
        if let Some(i) = r.and_then(|id| systems.index_of(id)) {
            if std::mem::replace(&mut row_set[i], true) {
                diag.err_help(
                    &label.loc,
                    format!("row `{}` appears twice", label.text),
                    "give each system one row",
                );
            } else if cols_ok && !col_set[i] {
                diag.err_help(
                    &label.loc,
                    format!("row `{}` has no matching column", label.text),
                    "the table is square: add this system to the columns too",
                );
            }
        }
    }
    for (c, label) in cols.iter().zip(&table.columns) {
        if let Some(i) = c.and_then(|id| systems.index_of(id)) {
            if rows_ok && !row_set[i] {
                diag.err_help(
                    &label.loc,
                    format!("column `{}` has no matching row", label.text),
                    format!("the table is square: add a row for `{}`", label.text),
                );
            }
        }
    }

    let is_x: Vec<bool> = table.texts.iter().map(|t| t == "X").collect();
    // Each distinct text is resolved once; a text that names nothing is resolved (and
    // reported) again at each cell, as every such cell is an error of its own.
    let mut resolved: Vec<Option<usize>> = vec![None; table.texts.len()];
    let mut implicit: HashMap<&'static str, usize> = HashMap::new();
    let mut b_reported = false;
    let mut addresses = AddressCheck::default();
    let mut pairs = Vec::with_capacity(table.cells.len());
    // Positions in `systems.list`, looked up once rather than per cell.
    let col_pos: Vec<usize> = cols
        .iter()
        .map(|c| c.and_then(|id| systems.index_of(id)).unwrap_or(0))
        .collect();
    for (r, row) in rows.iter().zip(&table.rows) {
        let Some(src) = *r else { continue };
        let src_pos = systems.index_of(src).unwrap_or(0);
        let label = &row.label;
        let cells = &table.cells[row.cells.clone()];
        if cells.len() != table.columns.len() {
            diag.err_help(
                &label.loc,
                format!(
                    "row `{}` has {} but there {} {}",
                    label.text,
                    plural(cells.len(), "cell"),
                    if table.columns.len() == 1 {
                        "is"
                    } else {
                        "are"
                    },
                    plural(table.columns.len(), "column"),
                ),
                "give every row one cell per column, in column order (X for no traffic)",
            );
            continue;
        }
        for ((cell, c), &dst_pos) in cells.iter().zip(&cols).zip(&col_pos) {
            let Some(dst) = *c else { continue };
            if is_x[cell.text as usize] {
                continue;
            }
            if src == dst {
                let n = systems.name(src);
                diag.err_help(
                    &table.loc(cell),
                    format!(
                        "system `{n}` cannot send to itself: its own cell is `{}`",
                        table.text(cell)
                    ),
                    format!("write X in row `{}`, column `{}`", label.text, label.text),
                );
                continue;
            }
            let i = match resolved[cell.text as usize] {
                Some(i) => i,
                None => {
                    let Some(i) = resolve_cell(
                        table.text(cell),
                        &table.loc(cell),
                        letter_map,
                        transports,
                        tag_of,
                        &mut implicit,
                        legacy_bt,
                        &mut b_reported,
                        diag,
                    ) else {
                        continue;
                    };
                    resolved[cell.text as usize] = Some(i);
                    i
                }
            };
            addresses.check(
                i,
                (src, src_pos),
                (dst, dst_pos),
                || table.loc(cell),
                transports,
                systems,
                diag,
            );
            pairs.push(((src, dst), i));
        }
    }
    pairs
}

/// Checks that every system at either end of a pair has an endpoint / address on each
/// transport carrying the pair (including the ones an emulated transport wraps). Each missing
/// (transport, system) is reported once, at the first cell needing it. Per transport it keeps
/// which systems are fully addressed along the transport's chain, so a cell costs two
/// look-ups in a vector.
#[derive(Default)]
struct AddressCheck {
    /// By transport index: per system position in `Systems::list`, whether every transport of its chain has an
    /// endpoint or address for it. Built when the transport is first seen in the table.
    ready: Vec<Option<Vec<bool>>>,
    reported: FxHashSet<(usize, SystemId)>,
}

impl AddressCheck {
    #[allow(clippy::too_many_arguments)]
    fn check(
        &mut self,
        first: usize,
        (src, src_pos): (SystemId, usize),
        (dst, dst_pos): (SystemId, usize),
        loc: impl Fn() -> Loc,
        transports: &[TransportSpec],
        systems: &Systems,
        diag: &mut Diag,
    ) {
        if self.ready.len() <= first {
            self.ready.resize(first + 1, None);
        }
        let ok = self.ready[first].get_or_insert_with(|| {
            let chain = chain(first, transports);
            systems
                .list
                .iter()
                .map(|s| {
                    chain
                        .iter()
                        .all(|&i| has_address(&transports[i], SystemId(s.id)) != Some(false))
                })
                .collect()
        });
        if ok[src_pos] && ok[dst_pos] {
            return;
        }
        let loc = loc();
        for i in chain(first, transports) {
            let t = &transports[i];
            for sys in [src, dst] {
                if has_address(t, sys) != Some(false) || !self.reported.insert((i, sys)) {
                    continue;
                }
                let sname = systems.name(sys);
                let (what, help) = match &t.settings {
                    Some(TransportSettings::Bluetooth(_)) => (
                        "Bluetooth address",
                        match &t.addr_source {
                            AddrSource::File(f) => {
                                format!("add a line `{} XX:XX:XX:XX:XX:XX` to {f}", sys.0)
                            }
                            AddrSource::Inline => format!(
                                "add `{sname} = \"XX:XX:XX:XX:XX:XX\"` to `addresses` of transport `{}`",
                                t.name
                            ),
                        },
                    ),
                    _ => (
                        "endpoint",
                        format!(
                            "add `{sname} = \"host:port\"` to `endpoints` of transport `{}`",
                            t.name
                        ),
                    ),
                };
                diag.err_help(
                    &loc,
                    format!(
                        "transport `{}` carries `{}` → `{}` but has no {what} for `{sname}`",
                        t.name,
                        systems.name(src),
                        systems.name(dst)
                    ),
                    help,
                );
            }
        }
    }
}

/// A transport and the ones it wraps, in order, each once.
fn chain(first: usize, transports: &[TransportSpec]) -> Vec<usize> {
    let mut out = vec![first];
    let mut cur = first;
    while let Some(next) = transports[cur]
        .over
        .as_ref()
        .and_then(|(n, _)| transports.iter().position(|o| &o.name == n))
    {
        if out.contains(&next) {
            break;
        }
        out.push(next);
        cur = next;
    }
    out
}

/// Whether a transport has an endpoint / address for `sys`; None for kinds that need none.
fn has_address(t: &TransportSpec, sys: SystemId) -> Option<bool> {
    match &t.settings {
        Some(TransportSettings::Ip(ip)) => Some(ip.endpoints.contains_key(&sys)),
        Some(TransportSettings::Bluetooth(bt)) => Some(bt.addresses.contains_key(&sys)),
        _ => None,
    }
}

/// Records that `letter` means transport `i`, reporting a conflicting earlier definition.
fn define_letter(
    map: &mut BTreeMap<u8, (usize, Loc)>,
    letter: u8,
    i: usize,
    loc: &Loc,
    transports: &[TransportSpec],
    diag: &mut Diag,
) {
    match map.get(&letter) {
        Some((j, first)) if *j != i => diag.err_help(
            loc,
            format!(
                "letter `{}` is defined twice: for `{}` and for `{}`",
                letter as char, transports[*j].name, transports[i].name
            ),
            format!("keep one definition (the first is at {})", at(first)),
        ),
        Some(_) => {}
        None => {
            map.insert(letter, (i, loc.clone()));
        }
    }
}

/// Resolves one non-X cell: a letter, a transport name, or a default letter (`R`, `B`).
/// None when it names nothing usable (already reported).
#[allow(clippy::too_many_arguments)]
fn resolve_cell(
    text: &str,
    loc: &Loc,
    letter_map: &BTreeMap<u8, (usize, Loc)>,
    transports: &mut Vec<TransportSpec>,
    tag_of: &mut Vec<Option<u8>>,
    implicit: &mut HashMap<&'static str, usize>,
    legacy_bt: Option<&LegacyBt>,
    b_reported: &mut bool,
    diag: &mut Diag,
) -> Option<usize> {
    if let [b] = text.as_bytes() {
        if let Some((i, _)) = letter_map.get(b) {
            return Some(*i);
        }
    }
    let name = names::nfc(text);
    if let Some(i) = transports.iter().position(|t| t.name == name) {
        return Some(i);
    }
    let key: &'static str = match text {
        "R" => "R",
        "B" => "B",
        _ => {
            let mut cands: Vec<&str> = transports.iter().map(|t| t.name.as_str()).collect();
            let letters: Vec<String> = letter_map
                .keys()
                .map(|&b| (b as char).to_string())
                .collect();
            cands.extend(letters.iter().map(String::as_str));
            cands.push("R");
            if legacy_bt.is_some() {
                cands.push("B");
            }
            cands.push("X");
            // A transport named by one letter, or a letter defined twice alike, is one
            // candidate.
            let mut seen = FxHashSet::default();
            cands.retain(|c| seen.insert(*c));
            let help = match suggest::closest(text, &cands) {
                Some(c) => format!("did you mean `{c}`?"),
                None => format!(
                    "defined transports and letters: {}; a new letter needs a [letters] entry, e.g. `{} = \"<transport>\"`",
                    cands.join(", "),
                    if text.chars().count() == 1 { text } else { "Q" }
                ),
            };
            diag.err_help(loc, format!("`{text}` names no transport or letter"), help);
            return None;
        }
    };
    if let Some(&i) = implicit.get(key) {
        return Some(i);
    }
    let settings = if key == "R" {
        TransportSettings::Ros1(Ros1Settings {
            master_uri: default_master_uri(),
            namespace: None,
        })
    } else {
        let Some(bt) = legacy_bt else {
            if !*b_reported {
                *b_reported = true;
                diag.err_help(
                    loc,
                    "letter `B` means a Bluetooth transport, which needs Bluetooth addresses, but none are given",
                    "add `bluetooth = \"bt.txt\"` (the Table 3 format) under [legacy], or map B to a transport in [letters]",
                );
            }
            return None;
        };
        TransportSettings::Bluetooth(BluetoothSettings {
            channel: 1,
            addresses: bt.addresses.clone(),
        })
    };
    let kind = if key == "R" {
        TransportKind::Ros1
    } else {
        TransportKind::Bluetooth
    };
    transports.push(TransportSpec {
        name: key.to_string(),
        name_loc: loc.clone(),
        kind: Some(kind),
        delivery: DeliveryMode::Acknowledged,
        attempts: 3,
        max_in_flight: crate::model::DEFAULT_MAX_IN_FLIGHT,
        ordered: false,
        batch_linger_us: crate::model::DEFAULT_BATCH_LINGER_US,
        letter: None,
        settings: Some(settings),
        over: None,
        addr_source: match legacy_bt {
            Some(bt) => AddrSource::File(bt.file.clone()),
            None => AddrSource::Inline,
        },
    });
    tag_of.push(Some(key.as_bytes()[0]));
    let i = transports.len() - 1;
    implicit.insert(key, i);
    Some(i)
}

/// Checks every emulated transport's `over`: it names a transport, not itself, and the chain
/// of wrappers ends.
fn check_over(transports: &[TransportSpec], diag: &mut Diag) {
    let index = |n: &str| transports.iter().position(|t| t.name == n);
    for (i, t) in transports.iter().enumerate() {
        let Some((over, loc)) = &t.over else { continue };
        let Some(j) = index(over) else {
            let names: Vec<&str> = transports
                .iter()
                .filter(|o| o.name != t.name)
                .map(|o| o.name.as_str())
                .collect();
            diag.err_help(
                loc,
                format!(
                    "transport `{}` wraps `{over}`, which is not a transport",
                    t.name
                ),
                suggest::help(over, &names, "defined transports"),
            );
            continue;
        };
        if j == i {
            diag.err_help(
                loc,
                format!("transport `{}` cannot wrap itself", t.name),
                "name another transport in `over`, or remove `over` for a private in-process link",
            );
            continue;
        }
        // Walk the chain; report a loop once, at the first transport of it in file order.
        let mut chain = vec![i];
        let mut cur = j;
        loop {
            if cur == i {
                if chain.iter().all(|&k| k >= i) {
                    let names: Vec<&str> = chain
                        .iter()
                        .chain(std::iter::once(&i))
                        .map(|&k| transports[k].name.as_str())
                        .collect();
                    diag.err_help(
                        loc,
                        format!(
                            "transports wrap each other in a loop: {}",
                            names.join(" → ")
                        ),
                        "the last wrapper in a chain must wrap a transport without `over`",
                    );
                }
                break;
            }
            if chain.contains(&cur) {
                break; // a loop further down, reported from its own members
            }
            chain.push(cur);
            match transports[cur].over.as_ref().and_then(|(n, _)| index(n)) {
                Some(next) => cur = next,
                None => break,
            }
        }
    }
}

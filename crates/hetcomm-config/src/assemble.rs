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
use crate::kinds::{Addresses, Kinds};
use crate::legacy::check_id;
use crate::model::*;
use crate::{names, suggest};

pub(crate) use crate::table::RawTable;
use crate::table::{table_pairs, DefaultLetters};

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
    /// Its public key and private key file, as far as known.
    pub keys: SysKeys,
}

/// A system's keys as the fleet file gives them (inline, by file, or from `[security] keys`).
#[derive(Default)]
pub(crate) struct SysKeys {
    /// The system gives its own public key (`public_key` or `public_key_file`), which the
    /// keys directory does not override (even when it was reported as wrong).
    pub public_given: bool,
    pub public_key: Option<[u8; 32]>,
    pub private_key_file: Option<PathBuf>,
}

/// A module before duplicate checks.
pub(crate) struct ModSpec {
    pub id: u16,
    pub id_loc: Loc,
    pub name: String,
    pub inbox: InboxConfig,
}

/// A transport before letters and the table are resolved.
pub(crate) struct TransportSpec {
    pub name: String,
    pub name_loc: Loc,
    pub kind: Option<TransportKind>,
    pub delivery: DeliveryMode,
    pub attempts: u32,
    pub max_in_flight: u32,
    pub max_in_flight_bytes: usize,
    pub ordered: bool,
    pub batch_linger_us: u32,
    pub letter: Option<(u8, Loc)>,
    pub security: SecurityMode,
    /// None when the transport had errors; it still counts as defined so the table does not
    /// report it a second time as unknown.
    pub settings: Option<TransportSettings>,
    /// The transport it is layered over (`over`, read by its kind's spec through
    /// [`crate::SettingsReader::layered_over`]), with its location.
    pub over: Option<(String, Loc)>,
    /// Its own link never leaves the process (its kind says so).
    pub in_process: bool,
    /// The systems it has an address for, when its kind needs one per system (checked
    /// against the table's pairs); None for kinds that need none.
    pub addresses: Option<Addresses>,
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
    /// `[security] keys`, resolved.
    pub keys_dir: Option<PathBuf>,
    /// `[security] in_process`.
    pub secure_in_process: bool,
    /// Where to report "B needs addresses" when no cell location is better.
    pub fallback: Loc,
    /// How to give those addresses, in the loader's own terms (a fleet-file key, or the
    /// command line's flag).
    pub b_help: &'static str,
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

    /// Records systems that were left out for an error already reported (a bad id), so that
    /// references to them stay quiet too.
    pub fn mark_reported(&mut self, names: Vec<String>) {
        for n in names {
            let n = names::nfc(&n).into_owned();
            if !self.by_name.contains_key(&n) {
                self.rejected.insert(n);
            }
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

/// Resolves the table, letters and transport cross-references, and builds the [`Fleet`].
pub(crate) fn finish(p: Parts, kinds: &Kinds, mut diag: Diag) -> Result<Fleet, ConfigErrors> {
    let Parts {
        name,
        source,
        systems,
        modules,
        mut transports,
        letters,
        table,
        legacy_bt,
        keys_dir,
        secure_in_process,
        fallback,
        b_help,
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

    // A transport layered over another must name a defined one, and the chain must end.
    check_over(&transports, &mut diag);

    // The table. Pairs are collected in file order (so that each problem is reported at the
    // first cell showing it) and sorted into the map only once the fleet is known to be valid.
    let mut pairs: Vec<((SystemId, SystemId), usize)> = Vec::new();
    let mut fallbacks: Vec<((SystemId, SystemId), Vec<usize>)> = Vec::new();
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
        (pairs, fallbacks) = table_pairs(
            table,
            &systems,
            &letter_map,
            &mut transports,
            &mut tag_of,
            DefaultLetters {
                legacy_bt: legacy_bt.as_ref(),
                b_help,
                kinds,
            },
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
            public_key: s.keys.public_key,
            private_key_file: s.keys.private_key_file.clone(),
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
            max_in_flight_bytes: t.max_in_flight_bytes,
            ordered: t.ordered,
            batch_linger_us: t.batch_linger_us,
            security: t.security,
            settings,
            over: t.over.map(|(name, _)| name),
            in_process: t.in_process,
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
        fallbacks: fallbacks.into_iter().collect(),
        keys_dir,
        secure_in_process,
        taps: Vec::new(),
    })
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

/// Checks every layered transport's `over`: it names a transport, not itself, and the chain
/// of layers ends.
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

//! The communication table, from its raw cells to (source, destination) → transport pairs:
//! the compact form both readers fill (a table can hold millions of cells), and the checks
//! [`finish`](crate::assemble::finish) runs on it: systems named by rows and columns, the
//! table's shape, each cell's transport or letter, and the endpoints or addresses each pair
//! needs.

use std::collections::{BTreeMap, HashMap};
use std::rc::Rc;

use hetcomm_core::SystemId;
use rustc_hash::{FxHashMap, FxHashSet};

use crate::assemble::{Label, LegacyBt, Systems, TransportSpec};
use crate::error::{Diag, Loc};
use crate::kinds::{Kinds, LegacyFiles};
use crate::model::*;
use crate::{names, suggest};

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

/// What the default letters stand for when no transport of their name is defined: `R` is a
/// `ros1` transport (settings from its kind's spec among `kinds`), `B` a `bluetooth` one with
/// the legacy Bluetooth file's addresses (and how to give them when there are none).
pub(crate) struct DefaultLetters<'a> {
    pub legacy_bt: Option<&'a LegacyBt>,
    pub b_help: &'static str,
    pub kinds: &'a Kinds,
}

/// The table's pairs: each (source, destination) with its first transport, in file order,
/// and the pairs whose cell lists more than one transport with the ones after the first.
pub(crate) type TablePairs = (
    Vec<((SystemId, SystemId), usize)>,
    Vec<((SystemId, SystemId), Vec<usize>)>,
);

/// Resolves the table's rows, columns and cells: reports unknown or repeated systems, a
/// non-square table, ragged rows, self-pairs, cells naming nothing and systems a transport has
/// no endpoint or address for; returns the (source, destination) → transport pairs in file
/// order. A cell may list several transports in order of preference, separated by commas
/// (`"wifi,bt"`, `"W,B"`); a cell without a comma is one name or letter, as it always was.
pub(crate) fn table_pairs(
    table: &RawTable,
    systems: &Systems,
    letter_map: &BTreeMap<u8, (usize, Loc)>,
    transports: &mut Vec<TransportSpec>,
    tag_of: &mut Vec<Option<u8>>,
    defaults: DefaultLetters<'_>,
    diag: &mut Diag,
) -> TablePairs {
    let DefaultLetters {
        legacy_bt,
        b_help,
        kinds,
    } = defaults;
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
    // Per text listing several transports: the ones after the first (empty otherwise).
    let mut rest_of: Vec<Vec<usize>> = vec![Vec::new(); table.texts.len()];
    let mut fallbacks = Vec::new();
    // Per text naming nothing: errors reported, cells not reported, the first of those.
    let mut unresolved: Vec<(usize, usize, Option<RawCell>)> =
        vec![(0, 0, None); table.texts.len()];
    let mut implicit: HashMap<&'static str, usize> = HashMap::new();
    let mut b_missing = BMissing {
        reported: false,
        help: b_help,
    };
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
                None if unresolved[cell.text as usize].0 >= MAX_SAME_CELL_ERRORS => {
                    // Reported often enough: a renamed transport must not make millions of
                    // errors. Counted, and summed up once below.
                    let u = &mut unresolved[cell.text as usize];
                    u.1 += 1;
                    u.2.get_or_insert(*cell);
                    continue;
                }
                None => {
                    let before = diag.errors.len();
                    let mut cx = CellContext {
                        letter_map,
                        transports,
                        tag_of,
                        implicit: &mut implicit,
                        legacy_bt,
                        b_missing: &mut b_missing,
                        kinds,
                        diag,
                    };
                    let resolved_now = resolve_list(table.text(cell), &table.loc(cell), &mut cx);
                    let Some(list) = resolved_now else {
                        if diag.errors.len() > before {
                            unresolved[cell.text as usize].0 += 1;
                        }
                        continue;
                    };
                    resolved[cell.text as usize] = Some(list[0]);
                    rest_of[cell.text as usize] = list[1..].to_vec();
                    list[0]
                }
            };
            let rest = &rest_of[cell.text as usize];
            for &t in std::iter::once(&i).chain(rest) {
                addresses.check(
                    t,
                    (src, src_pos),
                    (dst, dst_pos),
                    || table.loc(cell),
                    transports,
                    systems,
                    diag,
                );
            }
            pairs.push(((src, dst), i));
            if !rest.is_empty() {
                fallbacks.push(((src, dst), rest.clone()));
            }
        }
    }
    for (text, (_, more, first)) in table.texts.iter().zip(&unresolved) {
        if let Some(cell) = first {
            diag.err_help(
                &table.loc(cell),
                format!(
                    "`{text}` names no transport or letter: {} from here on (the first \
                     {MAX_SAME_CELL_ERRORS} are listed above)",
                    plural(*more, "more cell")
                ),
                "the same fix applies to every one of them",
            );
        }
    }
    (pairs, fallbacks)
}

/// Cells of one text naming nothing that are each reported; the rest are counted in one
/// more error.
const MAX_SAME_CELL_ERRORS: usize = 10;

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
                let Some(book) = &t.addresses else { continue };
                let (what, help) = (book.what, book.help_for(sys, sname, &t.name));
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
    t.addresses.as_ref().map(|book| book.systems.contains(&sys))
}

/// "Letter B needs Bluetooth addresses", said once per table, with the loader's help.
struct BMissing {
    reported: bool,
    help: &'static str,
}

/// What resolving a cell reads and adds to: the letters, the transports (the implicit `R` and
/// `B` are added at their first cell) and the errors.
struct CellContext<'a, 'b> {
    letter_map: &'a BTreeMap<u8, (usize, Loc)>,
    transports: &'a mut Vec<TransportSpec>,
    tag_of: &'a mut Vec<Option<u8>>,
    implicit: &'a mut HashMap<&'static str, usize>,
    legacy_bt: Option<&'b LegacyBt>,
    b_missing: &'a mut BMissing,
    /// The registered kinds, for the settings of the implicit `R` and `B`.
    kinds: &'a Kinds,
    diag: &'a mut Diag,
}

/// Resolves one non-X cell into its transports in order of preference: one name or letter,
/// or several separated by commas (`"wifi,bt"`, `"W, B"`). Every entry is checked and each
/// mistake reported (an empty entry, `X` among transports, a transport listed twice, a name
/// that names nothing); None when any entry is unusable.
fn resolve_list(text: &str, loc: &Loc, cx: &mut CellContext<'_, '_>) -> Option<Vec<usize>> {
    if !text.contains(',') {
        return resolve_cell(text, loc, cx).map(|i| vec![i]);
    }
    let mut list: Vec<usize> = Vec::new();
    let mut ok = true;
    for part in text.split(',').map(str::trim) {
        if part.is_empty() {
            cx.diag.err_help(
                loc,
                format!("`{text}` has an empty entry"),
                "list transports or letters separated by single commas, e.g. \"wifi,bt\"",
            );
            ok = false;
            continue;
        }
        if part == "X" {
            cx.diag.err_help(
                loc,
                format!("`{text}` lists `X` among transports"),
                "X means no traffic and stands alone: write \"X\", or list only transports",
            );
            ok = false;
            continue;
        }
        let Some(i) = resolve_cell(part, loc, cx) else {
            ok = false;
            continue;
        };
        if list.contains(&i) {
            cx.diag.err_help(
                loc,
                format!("`{text}` lists transport `{}` twice", cx.transports[i].name),
                "list each transport once, in order of preference",
            );
            ok = false;
            continue;
        }
        list.push(i);
    }
    (ok && !list.is_empty()).then_some(list)
}

/// Resolves one name or letter of a cell: a letter, a transport name, or a default letter
/// (`R`, `B`). None when it names nothing usable (already reported).
fn resolve_cell(text: &str, loc: &Loc, cx: &mut CellContext<'_, '_>) -> Option<usize> {
    let CellContext {
        letter_map,
        transports,
        tag_of,
        implicit,
        legacy_bt,
        b_missing,
        kinds,
        diag,
    } = cx;
    let legacy_bt = *legacy_bt;
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
    let kind = if key == "R" {
        TransportKind::Ros1
    } else {
        TransportKind::Bluetooth
    };
    if key == "B" && legacy_bt.is_none() {
        if !b_missing.reported {
            b_missing.reported = true;
            diag.err_help(
                loc,
                "letter `B` means a Bluetooth transport, which needs Bluetooth addresses, but none are given",
                b_missing.help,
            );
        }
        return None;
    }
    // The kinds' settings are their crates': without the crate compiled in, the transport is
    // known by name only (opening it says how to build it in), as a fleet file's would be.
    let legacy = LegacyFiles {
        bluetooth: legacy_bt.map(|bt| (&bt.addresses, &*bt.file)),
    };
    let mut addresses = None;
    let settings = kinds.spec(kind).and_then(|spec| {
        let settings = spec.implicit(&legacy)?;
        addresses = spec.addresses(&settings);
        Some(TransportSettings::Registered(settings))
    });
    let settings = settings.unwrap_or_else(|| TransportSettings::Raw(BTreeMap::new()));
    transports.push(TransportSpec {
        name: key.to_string(),
        name_loc: loc.clone(),
        kind: Some(kind),
        delivery: DeliveryMode::Acknowledged,
        attempts: 3,
        max_in_flight: crate::model::DEFAULT_MAX_IN_FLIGHT,
        max_in_flight_bytes: crate::model::DEFAULT_MAX_IN_FLIGHT_BYTES,
        ordered: false,
        batch_linger_us: crate::model::DEFAULT_BATCH_LINGER_US,
        letter: None,
        security: SecurityMode::Keys,
        settings: Some(settings),
        over: None,
        in_process: false,
        addresses,
    });
    tag_of.push(Some(key.as_bytes()[0]));
    let i = transports.len() - 1;
    implicit.insert(key, i);
    Some(i)
}

/// "1 cell", "2 cells".
pub(crate) fn plural(n: usize, word: &str) -> String {
    if n == 1 {
        format!("1 {word}")
    } else {
        format!("{n} {word}s")
    }
}

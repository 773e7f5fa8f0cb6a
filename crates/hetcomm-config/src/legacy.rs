//! Readers for the thesis's three plain-text files (§3.5 Tables 1–3, §5.1.1 Tables 6–8,
//! §5.2.1 Tables 16–18). They only split lines into located tokens and check the shape of each
//! line; whether an id names a known system is decided in `assemble`, which also serves the
//! TOML side.

use std::rc::Rc;

use crate::assemble::{BtLine, IdLine, Label, RawTable};
use crate::error::{Diag, Loc};

/// One whitespace-separated token with its position.
struct Tok<'a> {
    text: &'a str,
    /// Byte offset just past the token within its line, to find "the rest of the line".
    end: usize,
    loc: Loc,
}

/// One content line: its tokens and its text (for names that contain spaces).
struct Line<'a> {
    text: &'a str,
    toks: Vec<Tok<'a>>,
}

/// Splits a legacy file into content lines: CRLF and a leading byte-order mark are accepted
/// because these files are often edited on Windows; blank lines and `#` comments are skipped.
fn lines<'a>(file: &Rc<str>, text: &'a str) -> Vec<Line<'a>> {
    content_lines(text)
        .map(|(lno, line)| Line {
            text: line,
            toks: tokens(file, line, lno),
        })
        .collect()
}

/// The content lines of a legacy file with their 1-based numbers (see [`lines`]).
fn content_lines(text: &str) -> impl Iterator<Item = (usize, &str)> {
    let text = text.strip_prefix('\u{feff}').unwrap_or(text);
    text.split('\n').enumerate().filter_map(|(i, raw)| {
        let line = raw.strip_suffix('\r').unwrap_or(raw);
        let trimmed = line.trim();
        (!trimmed.is_empty() && !trimmed.starts_with('#')).then_some((i + 1, line))
    })
}

/// The whitespace-separated tokens of one content line (never empty).
fn tokens<'a>(file: &Rc<str>, line: &'a str, lno: usize) -> Vec<Tok<'a>> {
    let mut toks = Vec::new();
    let mut start: Option<(usize, usize)> = None; // (byte, column)
    for (col0, (byte, ch)) in line.char_indices().enumerate() {
        match (ch.is_whitespace(), start) {
            (false, None) => start = Some((byte, col0 + 1)),
            (true, Some((b, c))) => {
                toks.push(tok(file, line, b, byte, lno, c));
                start = None;
            }
            _ => {}
        }
    }
    if let Some((b, c)) = start {
        toks.push(tok(file, line, b, line.len(), lno, c));
    }
    toks
}

fn tok<'a>(file: &Rc<str>, line: &'a str, b: usize, e: usize, lno: usize, col: usize) -> Tok<'a> {
    Tok {
        text: &line[b..e],
        end: e,
        loc: Loc {
            file: file.clone(),
            line: lno,
            column: col,
        },
    }
}

/// What a u16 id token turned out to be.
pub(crate) enum IdTok {
    Ok(u16),
    OutOfRange,
    NotNumeric,
}

/// Parses an id token strictly: digits only, so `+1`, `-1` and `1.0` are rejected.
pub(crate) fn id_token(s: &str) -> IdTok {
    if s.is_empty() || !s.bytes().all(|b| b.is_ascii_digit()) {
        return IdTok::NotNumeric;
    }
    match s.parse::<u16>() {
        Ok(v) => IdTok::Ok(v),
        Err(_) => IdTok::OutOfRange,
    }
}

/// Reports a bad id token and returns the id if it was fine.
pub(crate) fn check_id(
    diag: &mut Diag,
    text: &str,
    loc: &Loc,
    what: &str,
    line_form: &str,
) -> Option<u16> {
    match id_token(text) {
        IdTok::Ok(v) => Some(v),
        IdTok::OutOfRange => {
            diag.err_help(
                loc,
                format!("{what} id {text} is out of range"),
                "ids are whole numbers from 0 to 65535",
            );
            None
        }
        IdTok::NotNumeric => {
            diag.err_help(
                loc,
                format!("expected a numeric {what} id, found `{text}`"),
                format!("each line is {line_form}"),
            );
            None
        }
    }
}

/// Reads an id file (Tables 1, 6, 16): an optional count line, then `<id> <name>` lines where
/// the name is the rest of the line (it may contain spaces, as in "Virtual Environment").
pub(crate) fn parse_ids(file: &Rc<str>, text: &str, diag: &mut Diag) -> Vec<IdLine> {
    let lines = lines(file, text);
    let mut rest = &lines[..];
    let mut count: Option<(u64, Loc)> = None;
    if let Some(first) = lines.first() {
        if first.toks.len() == 1 && first.toks[0].text.bytes().all(|b| b.is_ascii_digit()) {
            match first.toks[0].text.parse::<u64>() {
                Ok(n) => count = Some((n, first.toks[0].loc.clone())),
                Err(_) => diag.err_help(
                    &first.toks[0].loc,
                    format!("count line `{}` is not a usable number", first.toks[0].text),
                    "the optional first line is the number of systems listed below it",
                ),
            }
            rest = &lines[1..];
        }
    }
    let mut out = Vec::new();
    for line in rest {
        let id_tok = &line.toks[0];
        let Some(id) = check_id(
            diag,
            id_tok.text,
            &id_tok.loc,
            "system",
            "`<id> <name>`, e.g. `0 Alpha`",
        ) else {
            continue;
        };
        let Some(name_tok) = line.toks.get(1) else {
            diag.err_help(
                &id_tok.loc,
                format!("system id {id} has no name"),
                format!("write the name after the id, e.g. `{id} Alpha`"),
            );
            continue;
        };
        out.push(IdLine {
            id,
            id_loc: id_tok.loc.clone(),
            name: line.text[id_tok.end..].trim().to_string(),
            name_loc: name_tok.loc.clone(),
        });
    }
    if let Some((n, loc)) = count {
        let listed = rest.len() as u64;
        if n != listed {
            diag.err_help(
                &loc,
                format!("the count line says {n} systems but the file lists {listed}"),
                format!("change the count to {listed}, or add the missing systems (the count line is optional)"),
            );
        }
    }
    out
}

/// Reads a communication table file (Tables 2, 7, 17): a header line of column ids, then
/// `<row id> <cell> <cell> …` lines. Lines are split one at a time, straight into the table's
/// compact cells, so a big table costs little more than its cells.
pub(crate) fn parse_table(file: &Rc<str>, text: &str, diag: &mut Diag) -> Option<RawTable> {
    let mut content = content_lines(text);
    let Some((lno, header)) = content.next() else {
        diag.err_help(
            &Loc::start(file),
            "the communication table file is empty",
            "write a header line of system ids, then one row per source system, e.g. `0 X R`",
        );
        return None;
    };
    let label = |t: &Tok| Label {
        text: t.text.to_string(),
        loc: t.loc.clone(),
        by_id: true,
    };
    let header = tokens(file, header, lno);
    let columns = header.iter().map(label).collect();
    let mut table = RawTable::new(file.clone(), header[0].loc.clone(), columns);
    for (lno, line) in content {
        let toks = tokens(file, line, lno);
        table.start_row(label(&toks[0]));
        for t in &toks[1..] {
            table.push_cell(t.text, t.loc.line, t.loc.column);
        }
    }
    Some(table)
}

/// Reads a Bluetooth address file (Tables 3, 8, 18): `<id> <XX:XX:XX:XX:XX:XX>` lines.
pub(crate) fn parse_bluetooth(file: &Rc<str>, text: &str, diag: &mut Diag) -> Vec<BtLine> {
    let mut out = Vec::new();
    for line in lines(file, text) {
        let id_tok = &line.toks[0];
        let form = "`<id> <address>`, e.g. `1 68:A3:C4:4A:B3:BA`";
        let Some(id) = check_id(diag, id_tok.text, &id_tok.loc, "system", form) else {
            continue;
        };
        match &line.toks[1..] {
            [addr] => out.push(BtLine {
                key: Label {
                    text: id.to_string(),
                    loc: id_tok.loc.clone(),
                    by_id: true,
                },
                addr: addr.text.to_string(),
                addr_loc: addr.loc.clone(),
            }),
            [] => diag.err_help(
                &id_tok.loc,
                format!("system id {id} has no Bluetooth address"),
                format!("write the address after the id, e.g. `{id} 68:A3:C4:4A:B3:BA`"),
            ),
            [_, extra, ..] => diag.err_help(
                &extra.loc,
                format!("unexpected `{}` after the Bluetooth address", extra.text),
                format!("each line is {form}"),
            ),
        }
    }
    out
}

//! A fast reader for the common shape of `[table]`, so that a fleet of thousands of systems
//! (millions of cells) does not go through `toml_edit`'s document, which keeps a value with
//! its text, decoration and span for every cell (hundreds of bytes each).
//!
//! It reads only the plain form: a `[table]` header line, then `key = [ … ]` lines whose keys
//! are bare or quoted without escapes, `columns` holding strings or plain integers, every row
//! holding strings without escapes; comments, blank lines and arrays over several lines are
//! fine. Anything else (an escape, a dotted key, a value of another type, a repeated key, a
//! second `table` anywhere, a syntax error) makes it give up, and the whole file is read the
//! ordinary way, so every error keeps its usual wording. When it succeeds, the section is
//! replaced by as many empty lines for `toml_edit`, which therefore sees every other line at
//! its own line and column.

use std::rc::Rc;

use rustc_hash::FxHashSet;

use crate::assemble::{Label, RawTable};
use crate::error::Loc;

/// A `[table]` section read by [`scan`].
pub(super) struct Scanned {
    /// The table, with the same labels, cells and locations the `toml_edit` path gives.
    pub table: RawTable,
    /// The file's text with the section replaced by its newlines.
    pub rest: String,
}

/// Reads the `[table]` section of `text` if it has the plain form; None otherwise.
pub(super) fn scan(text: &str, file: &Rc<str>) -> Option<Scanned> {
    let start = header_start(text)?;
    let mut c = Cursor {
        b: text.as_bytes(),
        text,
        pos: start,
        line: 1 + text[..start].bytes().filter(|&b| b == b'\n').count(),
        col: 1,
    };
    let header_loc = c.loc(file);
    c.pos += "[table]".len();
    c.col += "[table]".len();
    c.end_of_line()?;
    let mut columns: Option<Vec<Label>> = None;
    let mut table = RawTable::new(file.clone(), header_loc, Vec::new());
    let mut keys: FxHashSet<&str> = FxHashSet::default();
    loop {
        c.skip_blank_lines()?;
        match c.peek() {
            None | Some(b'[') => break,
            _ => {}
        }
        let key_loc = c.loc(file);
        let key = c.key()?;
        if !keys.insert(key) {
            return None;
        }
        c.spaces();
        c.expect(b'=')?;
        c.spaces();
        if key == "columns" {
            columns = Some(c.columns(file)?);
        } else {
            table.start_row(Label {
                text: key.to_string(),
                loc: key_loc,
                by_id: false,
            });
            c.row(&mut table)?;
        }
        c.end_of_line()?;
    }
    table.columns = columns?;
    // The section ends where the next header's line starts (its indentation included).
    let end = if c.pos == text.len() {
        c.pos
    } else {
        text[..c.pos].rfind('\n').map_or(c.pos, |i| i + 1)
    };
    let newlines = text[start..end].bytes().filter(|&b| b == b'\n').count();
    let mut rest = String::with_capacity(text.len() - (end - start) + newlines);
    rest.push_str(&text[..start]);
    rest.push_str(&"\n".repeat(newlines));
    rest.push_str(&text[end..]);
    Some(Scanned { table, rest })
}

/// Byte offset of the one `[table]` header line, if the text has one this reader can find
/// safely: nothing before it may be a multi-line string, whose content could look like a
/// header.
fn header_start(text: &str) -> Option<usize> {
    let mut offset = 0;
    for line in text.split_inclusive('\n') {
        let trimmed = line.trim_start_matches([' ', '\t']);
        if let Some(after) = trimmed.strip_prefix("[table]") {
            let after = after.trim_start_matches([' ', '\t']);
            if after.is_empty() || after.starts_with(['\n', '\r', '#']) {
                let start = offset + (line.len() - trimmed.len());
                if text[..start].contains("\"\"\"") || text[..start].contains("'''") {
                    return None;
                }
                return Some(start);
            }
        }
        offset += line.len();
    }
    None
}

/// A position in the text, with its line and column (in characters) kept up to date.
struct Cursor<'a> {
    b: &'a [u8],
    text: &'a str,
    pos: usize,
    line: usize,
    col: usize,
}

impl<'a> Cursor<'a> {
    fn peek(&self) -> Option<u8> {
        self.b.get(self.pos).copied()
    }

    fn loc(&self, file: &Rc<str>) -> Loc {
        Loc {
            file: file.clone(),
            line: self.line,
            column: self.col,
        }
    }

    /// Moves past one byte of a line (not a newline).
    fn bump(&mut self) {
        // Columns count characters: continuation bytes of UTF-8 do not start one.
        if self.b[self.pos] & 0xC0 != 0x80 {
            self.col += 1;
        }
        self.pos += 1;
    }

    fn expect(&mut self, byte: u8) -> Option<()> {
        (self.peek()? == byte).then(|| self.bump())
    }

    /// Spaces and tabs.
    fn spaces(&mut self) {
        while matches!(self.peek(), Some(b' ' | b'\t')) {
            self.bump();
        }
    }

    /// A newline (`\n` or `\r\n`), if one is next.
    fn newline(&mut self) -> Option<bool> {
        match self.peek() {
            Some(b'\n') => {}
            Some(b'\r') if self.b.get(self.pos + 1) == Some(&b'\n') => self.pos += 1,
            Some(b'\r') => return None,
            _ => return Some(false),
        }
        self.pos += 1;
        self.line += 1;
        self.col = 1;
        Some(true)
    }

    /// A comment up to (not including) its newline, if one is next. TOML forbids control
    /// characters other than tab in comments.
    fn comment(&mut self) -> Option<()> {
        if self.peek() == Some(b'#') {
            while let Some(b) = self.peek() {
                if b == b'\n' || b == b'\r' {
                    break;
                }
                if (b < 0x20 && b != b'\t') || b == 0x7f {
                    return None;
                }
                self.bump();
            }
        }
        Some(())
    }

    /// The end of a statement: spaces, an optional comment, then a newline or the end.
    fn end_of_line(&mut self) -> Option<()> {
        self.spaces();
        self.comment()?;
        if self.newline()? || self.peek().is_none() {
            Some(())
        } else {
            None
        }
    }

    /// Blank and comment-only lines, leaving the cursor at the next statement's first byte.
    fn skip_blank_lines(&mut self) -> Option<()> {
        loop {
            self.spaces();
            self.comment()?;
            if !self.newline()? {
                return Some(());
            }
        }
    }

    /// Whitespace, newlines and comments inside an array.
    fn array_space(&mut self) -> Option<()> {
        loop {
            self.spaces();
            self.comment()?;
            if !self.newline()? {
                return Some(());
            }
        }
    }

    /// A bare key, or a quoted one without escapes; a dotted key is not read.
    fn key(&mut self) -> Option<&'a str> {
        let key = match self.peek()? {
            b'"' | b'\'' => self.string()?,
            _ => {
                let start = self.pos;
                while self
                    .peek()
                    .is_some_and(|b| b.is_ascii_alphanumeric() || b == b'_' || b == b'-')
                {
                    self.bump();
                }
                if self.pos == start {
                    return None;
                }
                &self.text[start..self.pos]
            }
        };
        self.spaces();
        (self.peek() != Some(b'.')).then_some(key)
    }

    /// A basic string without escapes or a literal string, on one line; its content.
    fn string(&mut self) -> Option<&'a str> {
        let quote = self.peek()?;
        self.bump();
        let start = self.pos;
        loop {
            let b = self.peek()?;
            if b == quote {
                let s = &self.text[start..self.pos];
                self.bump();
                // `""` followed by a quote would open a multi-line string.
                return (self.peek() != Some(quote) || !s.is_empty()).then_some(s);
            }
            if b == b'\\' || (b < 0x20 && b != b'\t') || b == 0x7f {
                return None;
            }
            self.bump();
        }
    }

    /// Runs `item` for each element of an array (the cursor at its first byte).
    fn array(&mut self, mut item: impl FnMut(&mut Self) -> Option<()>) -> Option<()> {
        self.expect(b'[')?;
        loop {
            self.array_space()?;
            if self.peek()? == b']' {
                self.bump();
                return Some(());
            }
            item(self)?;
            self.array_space()?;
            match self.peek()? {
                b',' => self.bump(),
                b']' => {
                    self.bump();
                    return Some(());
                }
                _ => return None,
            }
        }
    }

    /// `columns = [ "Alpha", 2, … ]`: names, or plain integers taken as ids.
    fn columns(&mut self, file: &Rc<str>) -> Option<Vec<Label>> {
        let mut out = Vec::new();
        self.array(|c| {
            let loc = c.loc(file);
            match c.peek()? {
                b'"' | b'\'' => {
                    let s = c.string()?;
                    out.push(Label {
                        text: s.to_string(),
                        loc,
                        by_id: false,
                    });
                }
                b'0'..=b'9' => {
                    let start = c.pos;
                    while c.peek().is_some_and(|b| b.is_ascii_digit()) {
                        c.bump();
                    }
                    let digits = &c.text[start..c.pos];
                    // TOML forbids leading zeros; `1_000`, `0x1` and the like go the long way.
                    if (digits.len() > 1 && digits.starts_with('0'))
                        || c.peek()
                            .is_some_and(|b| b.is_ascii_alphanumeric() || b == b'_')
                        || digits.parse::<i64>().is_err()
                    {
                        return None;
                    }
                    out.push(Label {
                        text: digits.to_string(),
                        loc,
                        by_id: true,
                    });
                }
                _ => return None,
            }
            Some(())
        })?;
        Some(out)
    }

    /// A row's `[ "X", "wired", … ]`, straight into the table.
    fn row(&mut self, table: &mut RawTable) -> Option<()> {
        self.array(|c| {
            let (line, column) = (c.line, c.col);
            if !matches!(c.peek()?, b'"' | b'\'') {
                return None;
            }
            let s = c.string()?;
            table.push_cell(s, line, column);
            Some(())
        })
    }
}

#[cfg(test)]
mod tests {
    use super::super::parse_with;

    const HEAD: &str = "name = \"t\"\n[systems]\nAlpha = 0\nBravo = 1\n\"Caf\u{e9}\" = 2\n\n\
                        [transports.wired]\nkind = \"inproc\"\n[transports.lan]\nkind = \"udp\"\n\
                        endpoints = { Alpha = \"127.0.0.1:1\", Bravo = \"127.0.0.1:2\" }\n\
                        [letters]\nW = \"wired\"\n\n";

    /// Both ways of reading must give the same fleet, or the same errors at the same places.
    fn same(table: &str, tail: &str, fast_expected: bool) {
        let text = format!("{HEAD}{table}{tail}");
        let (fast, used) = parse_with(&text, "s.toml", None, None, &Default::default(), true, true);
        let (slow, _) = parse_with(&text, "s.toml", None, None, &Default::default(), true, false);
        assert_eq!(fast, slow, "{text}");
        assert_eq!(used, fast_expected, "fast path taken?\n{text}");
    }

    #[test]
    fn the_fast_reader_agrees_with_toml_edit() {
        let ok_tables = [
            // The plain form, valid.
            "[table]\ncolumns = [\"Alpha\", \"Bravo\", \"Caf\u{e9}\"]\n\
             Alpha = [\"X\", \"wired\", \"W\"]\nBravo = [\"lan\", \"X\", \"X\"]\n\
             \"Caf\u{e9}\" = [\"W\", \"X\", \"X\"]\n",
            // Comments, CRLF, indentation, literal strings, arrays over lines, trailing commas,
            // integer columns, rows before columns.
            "  [table] # the table\r\n\r\n# rows\r\nAlpha = [ 'X', \"wired\",\r\n   \"W\", # c\r\n ]\r\n\
             columns = [0, 1, \"Caf\u{e9}\",]\r\n  Bravo=[\"lan\",\"X\",\"X\"]\r\n\
             'Caf\u{e9}' = [\"X\", \"X\", \"X\"] # end\r\n",
            // Errors found later: an unknown system, a ragged row, a self-pair, unknown cells,
            // a missing endpoint, a repeated column.
            "[table]\ncolumns = [\"Alpha\", \"Bravo\", \"Bravo\", \"Zulu\"]\n\
             Alpha = [\"wired\", \"nope\", \"nope\", \"X\"]\nBravo = [\"X\"]\n\
             Charly = [\"X\", \"X\", \"X\", \"X\"]\n\"Caf\u{e9}\" = [\"lan\", \"lan\", \"X\", \"Q\"]\n",
            // Empty rows and an empty table body after the columns.
            "[table]\ncolumns = []\n",
            "[table]\ncolumns = [\"Alpha\"]\nAlpha = []\n",
        ];
        for t in ok_tables {
            same(t, "", true);
            // A section after the table, indented, is kept in place.
            same(t, "\n  [modules]\n  M = 0 # x\n", true);
        }
        let long_way = [
            // Escapes, dotted keys, other value types, repeated keys, no columns, a second
            // `table`, multi-line strings, syntax errors, headers in other spellings.
            "[table]\ncolumns = [\"Al\\u0070ha\", \"Bravo\"]\nAlpha = [\"X\", \"W\"]\n",
            "[table]\ncolumns = [\"Alpha\"]\nAlpha.x = [\"X\"]\n",
            "[table]\ncolumns = [\"Alpha\"]\nAlpha = [1]\n",
            "[table]\ncolumns = [\"Alpha\"]\nAlpha = \"X\"\n",
            "[table]\ncolumns = [1.5]\nAlpha = [\"X\"]\n",
            "[table]\ncolumns = [01]\n",
            "[table]\ncolumns = [1_0]\n",
            "[table]\ncolumns = [\"Alpha\"]\nAlpha = [\"X\"]\n\"Alpha\" = [\"X\"]\n",
            "[table]\nAlpha = [\"X\"]\n",
            "[table]\ncolumns = [\"Alpha\"]\nAlpha = [\"X\"]\n[table.more]\nx = 1\n",
            "[table]\ncolumns = [\"Alpha\"]\nAlpha = [\"X\"]\n[table]\n",
            "[table]\ncolumns = [\"Alpha\"\nAlpha = [\"X\"]\n",
            "[table]\ncolumns = [\"Alpha\"] junk\n",
            "[ table ]\ncolumns = [\"Alpha\"]\nAlpha = [\"X\"]\n",
            "x = \"\"\"\n[table]\n\"\"\"\n[table]\ncolumns = []\n",
            "[table]\ncolumns = [\"Alpha\"]\nAlpha = [\"X\"]\n[legacy]\n",
            "[table]\ncolumns = [\"A\u{7}\"]\n",
        ];
        for t in long_way {
            same(t, "", false);
        }
        // No table at all.
        same("", "", false);
    }
}

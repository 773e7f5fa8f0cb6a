//! Located errors, and the small position bookkeeping shared by the TOML and legacy parsers.

use std::fmt;
use std::rc::Rc;

/// One problem found in a fleet file or a legacy file: where it is, what is wrong (quoting the
/// offending value) and, when there is one, how to fix it.
#[derive(Clone, Debug, PartialEq, Eq)]
pub struct ConfigError {
    /// The file the problem is in, as the user named it (the origin given to
    /// [`parse_str`](crate::parse_str), or a path).
    pub file: String,
    /// 1-based line of the offending token; 0 when the problem concerns the whole file and
    /// has no position in it (the file cannot be read).
    pub line: usize,
    /// 1-based column (in characters) of the offending token; 0 together with `line`.
    pub column: usize,
    /// What is wrong, quoting the offending value.
    pub message: String,
    /// What would fix it, if we can tell.
    pub help: Option<String>,
}

impl fmt::Display for ConfigError {
    /// `file:line:column: message`, or `file: message` for a problem with no position, then
    /// `\n  help: …` when there is a fix to suggest.
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        if self.line == 0 {
            write!(f, "{}: {}", self.file, self.message)?;
        } else {
            write!(
                f,
                "{}:{}:{}: {}",
                self.file, self.line, self.column, self.message
            )?;
        }
        if let Some(help) = &self.help {
            write!(f, "\n  help: {help}")?;
        }
        Ok(())
    }
}

impl std::error::Error for ConfigError {}

/// Every problem found in one load, in the order found (loading does not stop at the first
/// one, so a user can fix a file in one pass). Never empty when returned by this crate.
#[derive(Clone, Debug, PartialEq, Eq)]
pub struct ConfigErrors(pub Vec<ConfigError>);

impl fmt::Display for ConfigErrors {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        for (i, e) in self.0.iter().enumerate() {
            if i > 0 {
                f.write_str("\n")?;
            }
            write!(f, "{e}")?;
        }
        Ok(())
    }
}

impl std::error::Error for ConfigErrors {}

/// A position in some file. The file name is shared because thousands of tokens point into
/// the same few files.
#[derive(Clone, Debug)]
pub(crate) struct Loc {
    pub file: Rc<str>,
    pub line: usize,
    pub column: usize,
}

impl Loc {
    /// The start of a file: used when a problem concerns a whole file (it cannot be read, it
    /// defines nothing).
    pub fn start(file: &Rc<str>) -> Loc {
        Loc {
            file: file.clone(),
            line: 1,
            column: 1,
        }
    }

    /// The whole of a file, with no position in it: for a file that cannot be read, where
    /// any line and column would be made up.
    pub fn whole(file: &Rc<str>) -> Loc {
        Loc {
            file: file.clone(),
            line: 0,
            column: 0,
        }
    }
}

/// Collects errors so that every loader keeps going after the first one.
#[derive(Default)]
pub(crate) struct Diag {
    pub errors: Vec<ConfigError>,
}

impl Diag {
    /// Records one error at `loc`.
    pub fn err(&mut self, loc: &Loc, message: impl Into<String>, help: Option<String>) {
        self.errors.push(ConfigError {
            file: loc.file.to_string(),
            line: loc.line,
            column: loc.column,
            message: message.into(),
            help,
        });
    }

    /// The errors ordered by position: files in the order they first had an error, then line
    /// and column, so a user can fix a file top to bottom. Checks run in dependency order
    /// (systems before the table that names them), which is not the order of the text.
    pub fn into_sorted(self) -> ConfigErrors {
        let mut files: Vec<String> = Vec::new();
        for e in &self.errors {
            if !files.contains(&e.file) {
                files.push(e.file.clone());
            }
        }
        let mut errors = self.errors;
        errors.sort_by_key(|e| (files.iter().position(|f| *f == e.file), e.line, e.column));
        ConfigErrors(errors)
    }

    /// Records one error whose fix we can describe.
    pub fn err_help(&mut self, loc: &Loc, message: impl Into<String>, help: impl Into<String>) {
        self.err(loc, message, Some(help.into()));
    }
}

/// Turns byte offsets into 1-based line and character columns.
pub(crate) struct LineIndex {
    starts: Vec<usize>,
}

impl LineIndex {
    /// Indexes the line starts of `text`.
    pub fn new(text: &str) -> LineIndex {
        let mut starts = vec![0];
        starts.extend(text.match_indices('\n').map(|(i, _)| i + 1));
        LineIndex { starts }
    }

    /// The line and column of byte `offset` in `text`.
    pub fn locate(&self, text: &str, offset: usize) -> (usize, usize) {
        let offset = offset.min(text.len());
        let line = self.starts.partition_point(|&s| s <= offset).max(1);
        let start = self.starts[line - 1];
        // Columns count characters, not bytes, so that editors agree with us on non-ASCII
        // names; if the offset were ever inside a character, fall back to bytes.
        let column = text
            .get(start..offset)
            .map_or(offset - start, |s| s.chars().count())
            + 1;
        (line, column)
    }
}

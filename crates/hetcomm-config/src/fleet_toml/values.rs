//! Typed reads of single values: locations, "expected X, found Y", ranges, fixed choices
//! and unknown keys. Every other part of the walker reports through these.

use super::*;

impl P<'_> {
    pub(super) fn at(&self, span: Option<Range<usize>>, fallback: &Loc) -> Loc {
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
    pub(super) fn kloc(&self, t: &dyn TableLike, key: &str, fallback: &Loc) -> Loc {
        let span = t.get_key_value(key).and_then(|(k, _)| k.span());
        self.at(span, fallback)
    }

    /// Location of a value (for a table: its header or opening brace).
    pub(super) fn vloc(&self, item: &Item, fallback: &Loc) -> Loc {
        self.at(item.span(), fallback)
    }

    /// The value as written, for messages.
    pub(super) fn raw(&self, item: &Item) -> String {
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
    pub(super) fn found(&self, item: &Item) -> String {
        match item {
            Item::Value(Value::InlineTable(_))
            | Item::Table(_)
            | Item::ArrayOfTables(_)
            | Item::None => type_name(item).to_string(),
            _ => format!("{} `{}`", type_name(item), self.raw(item)),
        }
    }

    pub(super) fn wrong_type(
        &mut self,
        loc: &Loc,
        path: &str,
        expected: &str,
        item: &Item,
        help: &str,
    ) {
        let found = self.found(item);
        self.diag.err_help(
            loc,
            format!("`{path}` must be {expected}, found {found}"),
            help,
        );
    }

    pub(super) fn table<'t>(
        &mut self,
        item: &'t Item,
        path: &str,
        loc: &Loc,
    ) -> Option<&'t dyn TableLike> {
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

    pub(super) fn string<'t>(
        &mut self,
        item: &'t Item,
        path: &str,
        loc: &Loc,
        help: &str,
    ) -> Option<&'t str> {
        let s = item.as_str();
        if s.is_none() {
            self.wrong_type(loc, path, "a string", item, help);
        }
        s
    }

    pub(super) fn boolean(
        &mut self,
        item: &Item,
        path: &str,
        loc: &Loc,
        help: &str,
    ) -> Option<bool> {
        let v = item.as_bool();
        if v.is_none() {
            self.wrong_type(loc, path, "true or false", item, help);
        }
        v
    }

    pub(super) fn int(&mut self, item: &Item, path: &str, loc: &Loc, help: &str) -> Option<i64> {
        let v = item.as_integer();
        if v.is_none() {
            self.wrong_type(loc, path, "an integer", item, help);
        }
        v
    }

    /// An integer in `min..=max`, reporting either kind of problem.
    pub(super) fn int_in(
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
    pub(super) fn id16(&mut self, item: &Item, path: &str, loc: &Loc, what: &str) -> Option<u16> {
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
    pub(super) fn unknown_keys(
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
    pub(super) fn choice(
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
}

//! Reading and checking a scenario file (the format is in the module above).

use std::ops::Range;

use hetcomm_core::MessageType;
use serde::ser::{Serialize, SerializeMap, SerializeSeq, Serializer};
use toml_edit::{ImDocument, Item, Table, Value};

use super::{Fault, FaultEffect, Injection, Scenario, ScenarioTap, TapKind, TapSpec, Window};
use crate::error::{ConfigError, ConfigErrors, LineIndex};
use crate::Fleet;

mod items;
use items::{parse_injections, parse_links, parse_taps, Plain};

const TOP_KEYS: &[&str] = &["seed", "partition", "silence", "link", "inject", "tap"];

struct P<'a> {
    text: &'a str,
    origin: &'a str,
    lines: LineIndex,
    fleet: &'a Fleet,
    errors: Vec<ConfigError>,
}

impl<'a> P<'a> {
    fn new(text: &'a str, origin: &'a str, fleet: &'a Fleet) -> P<'a> {
        P {
            text,
            origin,
            lines: LineIndex::new(text),
            fleet,
            errors: Vec::new(),
        }
    }

    /// `sc` if nothing was wrong, else every error in file order.
    fn finish(mut self, sc: Scenario) -> Result<Scenario, ConfigErrors> {
        if self.errors.is_empty() {
            Ok(sc)
        } else {
            self.errors.sort_by_key(|e| (e.line, e.column));
            Err(ConfigErrors(self.errors))
        }
    }

    fn at(&self, span: Option<Range<usize>>) -> (usize, usize) {
        span.map_or((1, 1), |r| self.lines.locate(self.text, r.start))
    }

    fn err(&mut self, span: Option<Range<usize>>, message: String, help: Option<String>) {
        let (line, column) = self.at(span);
        self.errors.push(ConfigError {
            file: self.origin.to_string(),
            line,
            column,
            message,
            help,
        });
    }

    fn line(&self, t: &Table) -> usize {
        self.at(t.span()).0
    }

    fn keys(&mut self, t: &Table, what: &str, allowed: &[&str]) {
        for (k, v) in t.iter() {
            if !allowed.contains(&k) {
                let help = crate::suggest::closest(k, allowed)
                    .map(|s| format!("did you mean `{s}`?"))
                    .or_else(|| Some(format!("the keys of {what} are {}", allowed.join(", "))));
                self.err(v.span(), format!("unknown key `{k}` in {what}"), help);
            }
        }
    }

    fn number(&mut self, t: &Table, key: &str, what: &str) -> Option<f64> {
        let item = t.get(key)?;
        match item.as_value() {
            Some(Value::Float(f)) => Some(*f.value()),
            Some(Value::Integer(i)) => Some(*i.value() as f64),
            _ => {
                self.err(
                    item.span(),
                    format!("`{key}` of {what} must be a number"),
                    None,
                );
                None
            }
        }
    }

    fn string(&mut self, t: &Table, key: &str, what: &str) -> Option<String> {
        let item = t.get(key)?;
        match item.as_str() {
            Some(s) => Some(s.to_string()),
            None => {
                self.err(
                    item.span(),
                    format!("`{key}` of {what} must be a string"),
                    None,
                );
                None
            }
        }
    }

    fn required<T>(&mut self, t: &Table, key: &str, what: &str, v: Option<T>) -> Option<T> {
        if v.is_none() && t.get(key).is_none() {
            self.err(t.span(), format!("{what} is missing `{key}`"), None);
        }
        v
    }

    /// A time in seconds of scenario time: finite and not before the start.
    fn time(&mut self, t: &Table, key: &str, what: &str) -> Option<f64> {
        let v = self.number(t, key, what)?;
        if !v.is_finite() || v < 0.0 {
            let span = t.get(key).and_then(Item::span);
            self.err(
                span,
                format!("`{key}` of {what} is {v} s: scenario time starts at 0, so a time must be 0 or later"),
                Some("times are seconds from the start of the run".into()),
            );
            return None;
        }
        Some(v)
    }

    /// `start` and `end`; `optional`: both may be absent (the whole run).
    fn window(&mut self, t: &Table, what: &str, optional: bool) -> Option<Option<Window>> {
        if optional && t.get("start").is_none() && t.get("end").is_none() {
            return Some(None);
        }
        let start = self.time(t, "start", what);
        let start = self.required(t, "start", what, start)?;
        let end = self.time(t, "end", what);
        let end = self.required(t, "end", what, end)?;
        if end <= start {
            let span = t.get("end").and_then(Item::span);
            self.err(
                span,
                format!("{what} ends at {end} s, not after its start at {start} s"),
                Some("`end` must be later than `start`".into()),
            );
            return None;
        }
        Some(Some(Window {
            start_s: start,
            end_s: end,
        }))
    }

    fn system(&mut self, name: &str, span: Option<Range<usize>>, what: &str) -> Option<String> {
        if self.fleet.system_by_name(name).is_some() {
            return Some(name.to_string());
        }
        let names: Vec<&str> = self.fleet.systems.iter().map(|s| s.name.as_str()).collect();
        let help = crate::suggest::closest(name, &names)
            .map(|s| format!("did you mean `{s}`?"))
            .unwrap_or_else(|| format!("the fleet's systems are {}", names.join(", ")));
        self.err(
            span,
            format!("unknown system `{name}` in {what}"),
            Some(help),
        );
        None
    }

    fn module(&mut self, name: &str, span: Option<Range<usize>>, what: &str) -> Option<String> {
        if self.fleet.modules.iter().any(|m| m.name == name) {
            return Some(name.to_string());
        }
        let names: Vec<&str> = self.fleet.modules.iter().map(|m| m.name.as_str()).collect();
        let help = crate::suggest::closest(name, &names)
            .map(|s| format!("did you mean `{s}`?"))
            .unwrap_or_else(|| format!("the fleet's modules are {}", names.join(", ")));
        self.err(
            span,
            format!("unknown module `{name}` in {what}"),
            Some(help),
        );
        None
    }

    /// Reports `module` when system `system` (a known one) does not host it: no message for
    /// it can arrive there.
    fn hosted(&mut self, system: &str, module: &str, span: Option<Range<usize>>, what: &str) {
        let (Some(sys), Some(m)) = (
            self.fleet.system_by_name(system),
            self.fleet.module_by_name(module),
        ) else {
            return;
        };
        let Some(hosted) = &sys.modules else { return };
        if !hosted.contains(&m.id) {
            let names: Vec<&str> = hosted
                .iter()
                .filter_map(|id| self.fleet.modules.iter().find(|x| x.id == *id))
                .map(|x| x.name.as_str())
                .collect();
            self.err(
                span,
                format!("{what} is on a path that does not exist: system `{system}` does not host module `{module}`"),
                Some(format!("`{system}` hosts {}", names.join(", "))),
            );
        }
    }

    fn system_key(&mut self, t: &Table, key: &str, what: &str) -> Option<String> {
        let s = self.string(t, key, what)?;
        let span = t.get(key).and_then(Item::span);
        self.system(&s, span, what)
    }

    /// `"System.Module"`.
    fn address(&mut self, t: &Table, key: &str, what: &str) -> Option<(String, String)> {
        let s = self.string(t, key, what);
        let s = self.required(t, key, what, s)?;
        let span = t.get(key).and_then(Item::span);
        let Some((sys, module)) = s.split_once('.') else {
            self.err(
                span,
                format!("`{key}` of {what} is `{s}`: expected `System.Module`"),
                Some("for example \"Alpha.Plan\"".into()),
            );
            return None;
        };
        let sys = self.system(sys, span.clone(), what);
        let module = self.module(module, span, what);
        Some((sys?, module?))
    }

    fn message_type(&mut self, t: &Table, key: &str, what: &str) -> Option<MessageType> {
        let item = t.get(key)?;
        match item.as_integer() {
            Some(i) if (0..=i64::from(u32::MAX)).contains(&i) => Some(MessageType(i as u32)),
            _ => {
                self.err(
                    item.span(),
                    format!(
                        "`{key}` of {what} must be a message type id (0 to {})",
                        u32::MAX
                    ),
                    Some(format!("write the type's number, e.g. `{key} = 0`")),
                );
                None
            }
        }
    }

    fn payload(&mut self, item: &Item, what: &str) -> Option<Vec<u8>> {
        let v = match item {
            Item::Value(v) => Plain::from_value(v),
            Item::Table(t) => Plain::from_table(t),
            _ => None,
        };
        let Some(v) = v else {
            self.err(
                item.span(),
                format!("the payload of {what} has a value MessagePack cannot carry (a date?)"),
                None,
            );
            return None;
        };
        match hetcomm_core::payload::encode(&v) {
            Ok(bytes) => Some(bytes),
            Err(e) => {
                self.err(item.span(), format!("the payload of {what}: {e}"), None);
                None
            }
        }
    }

    fn tables<'d>(&mut self, root: &'d Table, key: &str) -> Vec<&'d Table> {
        match root.get(key) {
            None => Vec::new(),
            Some(Item::ArrayOfTables(a)) => a.iter().collect(),
            Some(other) => {
                self.err(
                    other.span(),
                    format!("`{key}` must be written as [[{key}]] tables"),
                    Some(format!(
                        "write each one as a table under a `[[{key}]]` line"
                    )),
                );
                Vec::new()
            }
        }
    }

    /// `between = ["A", "B"]` or `[["A", "B"], ["C"]]`: the two sides.
    fn sides(&mut self, t: &Table, what: &str) -> Option<(Vec<String>, Vec<String>)> {
        let item = t.get("between");
        let item = self.required(t, "between", what, item)?;
        let span = item.span();
        let bad = |p: &mut Self| {
            p.err(
                span.clone(),
                format!("`between` of {what} must be two systems or two lists of systems"),
                Some(
                    "between = [\"Charlie\", \"Tango\"] or between = [[\"A\", \"B\"], [\"C\"]]"
                        .into(),
                ),
            );
        };
        let Some(arr) = item.as_array().filter(|a| a.len() == 2) else {
            bad(self);
            return None;
        };
        let mut sides: Vec<Vec<String>> = Vec::new();
        for side in arr.iter() {
            let names: Vec<&Value> = match side {
                Value::String(_) => vec![side],
                Value::Array(a) => a.iter().collect(),
                _ => {
                    bad(self);
                    return None;
                }
            };
            let mut out = Vec::new();
            for n in names {
                let Some(s) = n.as_str() else {
                    bad(self);
                    return None;
                };
                out.extend(self.system(s, n.span(), what));
            }
            sides.push(out);
        }
        let b = sides.pop()?;
        let a = sides.pop()?;
        if let Some(x) = a.iter().find(|x| b.contains(x)) {
            self.err(span, format!("`{x}` is on both sides of {what}"), None);
            return None;
        }
        Some((a, b))
    }
}

/// Reads and checks the `[[tap]]` tables of a fleet file (`root`, parsed from `text`) against
/// the fleet the rest of that file describes: the same syntax, checks and messages as a
/// scenario file's taps.
pub(crate) fn parse_fleet_taps(
    root: &Table,
    text: &str,
    origin: &str,
    fleet: &Fleet,
) -> Result<Vec<ScenarioTap>, ConfigErrors> {
    let mut p = P::new(text, origin, fleet);
    let mut sc = Scenario::default();
    parse_taps(&mut p, root, &mut sc);
    p.finish(sc).map(|sc| sc.taps)
}

/// Parses and checks a scenario file's text against `fleet`; `origin` names it in errors.
pub fn parse_scenario(text: &str, origin: &str, fleet: &Fleet) -> Result<Scenario, ConfigErrors> {
    let mut p = P::new(text, origin, fleet);
    let doc = match ImDocument::parse(text) {
        Ok(d) => d,
        Err(e) => {
            let msg = e.message().lines().next().unwrap_or("").to_string();
            p.err(e.span(), format!("not valid TOML: {msg}"), None);
            return Err(ConfigErrors(p.errors));
        }
    };
    let root = doc.as_table();
    p.keys(root, "a scenario file", TOP_KEYS);
    let mut sc = Scenario {
        origin: origin.to_string(),
        ..Scenario::default()
    };
    if let Some(item) = root.get("seed") {
        match item.as_integer() {
            Some(s) if s >= 0 => sc.seed = Some(s as u64),
            _ => p.err(
                item.span(),
                "`seed` must be a whole number ≥ 0".into(),
                None,
            ),
        }
    }
    let systems: Vec<String> = fleet.systems.iter().map(|s| s.name.clone()).collect();
    for t in p.tables(root, "partition") {
        let what = format!("[[partition]] at line {}", p.line(t));
        p.keys(t, &what, &["between", "start", "end"]);
        let sides = p.sides(t, &what);
        let window = p.window(t, &what, false).flatten();
        if let (Some((a, b)), Some(window)) = (sides, window) {
            let mut pairs = Vec::new();
            for x in &a {
                for y in &b {
                    pairs.push((x.clone(), y.clone()));
                    pairs.push((y.clone(), x.clone()));
                }
            }
            sc.faults.push(Fault {
                kind: "partition",
                pairs,
                window,
                effect: FaultEffect::Cut,
                line: p.line(t),
            });
        }
    }
    for t in p.tables(root, "silence") {
        let what = format!("[[silence]] at line {}", p.line(t));
        p.keys(t, &what, &["system", "start", "end"]);
        let s = p.system_key(t, "system", &what);
        let s = p.required(t, "system", &what, s);
        let window = p.window(t, &what, false).flatten();
        if let (Some(s), Some(window)) = (s, window) {
            let mut pairs = Vec::new();
            for o in systems.iter().filter(|o| **o != s) {
                pairs.push((s.clone(), o.clone()));
                pairs.push((o.clone(), s.clone()));
            }
            sc.faults.push(Fault {
                kind: "silence",
                pairs,
                window,
                effect: FaultEffect::Cut,
                line: p.line(t),
            });
        }
    }
    parse_links(&mut p, root, &mut sc);
    parse_injections(&mut p, root, &mut sc);
    parse_taps(&mut p, root, &mut sc);
    p.finish(sc)
}

//! The `[[link]]`, `[[inject]]` and `[[tap]]` tables, and payloads as plain values.

use super::*;

/// A TOML value as MessagePack sees it (tables as maps with their keys in order).
pub(super) enum Plain {
    Bool(bool),
    Int(i64),
    Float(f64),
    Str(String),
    Array(Vec<Plain>),
    Map(Vec<(String, Plain)>),
}

impl Plain {
    pub(super) fn from_value(v: &Value) -> Option<Plain> {
        Some(match v {
            Value::Boolean(b) => Plain::Bool(*b.value()),
            Value::Integer(i) => Plain::Int(*i.value()),
            Value::Float(f) => Plain::Float(*f.value()),
            Value::String(s) => Plain::Str(s.value().clone()),
            Value::Array(a) => {
                Plain::Array(a.iter().map(Plain::from_value).collect::<Option<_>>()?)
            }
            Value::InlineTable(t) => Plain::Map(
                t.iter()
                    .map(|(k, v)| Some((k.to_string(), Plain::from_value(v)?)))
                    .collect::<Option<_>>()?,
            ),
            Value::Datetime(_) => return None,
        })
    }

    pub(super) fn from_table(t: &Table) -> Option<Plain> {
        Some(Plain::Map(
            t.iter()
                .map(|(k, item)| {
                    let v = match item {
                        Item::Value(v) => Plain::from_value(v)?,
                        Item::Table(t) => Plain::from_table(t)?,
                        _ => return None,
                    };
                    Some((k.to_string(), v))
                })
                .collect::<Option<_>>()?,
        ))
    }
}

impl Serialize for Plain {
    fn serialize<S: Serializer>(&self, s: S) -> Result<S::Ok, S::Error> {
        match self {
            Plain::Bool(b) => s.serialize_bool(*b),
            Plain::Int(i) => s.serialize_i64(*i),
            Plain::Float(f) => s.serialize_f64(*f),
            Plain::Str(x) => s.serialize_str(x),
            Plain::Array(a) => {
                let mut seq = s.serialize_seq(Some(a.len()))?;
                for v in a {
                    seq.serialize_element(v)?;
                }
                seq.end()
            }
            Plain::Map(m) => {
                let mut map = s.serialize_map(Some(m.len()))?;
                for (k, v) in m {
                    map.serialize_entry(k, v)?;
                }
                map.end()
            }
        }
    }
}

pub(super) fn parse_links(p: &mut P<'_>, root: &Table, sc: &mut Scenario) {
    // (pair, window, line) of every degradation so far: two on one pair at once contradict.
    let mut seen: Vec<((String, String), Window, usize)> = Vec::new();
    for t in p.tables(root, "link") {
        let line = p.line(t);
        let what = format!("[[link]] at line {line}");
        p.keys(
            t,
            &what,
            &[
                "between",
                "from",
                "to",
                "loss",
                "latency_ms",
                "jitter_ms",
                "start",
                "end",
            ],
        );
        let pairs = if t.get("between").is_some() {
            if t.get("from").is_some() || t.get("to").is_some() {
                p.err(
                    t.get("from").or(t.get("to")).and_then(Item::span),
                    format!("{what} has both `between` and `from`/`to`"),
                    Some("`between` is both directions; `from` and `to` one".into()),
                );
            }
            p.sides(t, &what).map(|(a, b)| {
                let mut v = Vec::new();
                for x in &a {
                    for y in &b {
                        v.push((x.clone(), y.clone()));
                        v.push((y.clone(), x.clone()));
                    }
                }
                v
            })
        } else {
            let from = p.system_key(t, "from", &what);
            let from = p.required(t, "from", &what, from);
            let to = p.system_key(t, "to", &what);
            let to = p.required(t, "to", &what, to);
            match (from, to) {
                (Some(a), Some(b)) => Some(vec![(a, b)]),
                _ => None,
            }
        };
        let unit = |p: &mut P<'_>, key: &str, max: f64| -> Option<f64> {
            let v = p.number(t, key, &what)?;
            if !(0.0..=max).contains(&v) || !v.is_finite() {
                p.err(
                    t.get(key).and_then(Item::span),
                    format!("`{key}` of {what} is {v}: it must be from 0 to {max}"),
                    None,
                );
                return None;
            }
            Some(v)
        };
        let loss = unit(p, "loss", 1.0).unwrap_or(0.0);
        let latency_ms = unit(p, "latency_ms", 3_600_000.0).unwrap_or(0.0);
        let jitter_ms = unit(p, "jitter_ms", 3_600_000.0).unwrap_or(0.0);
        if ["loss", "latency_ms", "jitter_ms"]
            .iter()
            .all(|k| t.get(k).is_none())
        {
            p.err(
                t.span(),
                format!("{what} changes nothing"),
                Some("give `loss`, `latency_ms` or `jitter_ms`".into()),
            );
        }
        let window = p.window(t, &what, false).flatten();
        let (Some(pairs), Some(window)) = (pairs, window) else {
            continue;
        };
        for pair in &pairs {
            if let Some((_, _, other)) = seen
                .iter()
                .find(|(q, w, _)| q == pair && w.overlaps(&window))
            {
                p.err(
                    t.span(),
                    format!(
                        "{what} changes {}→{} while [[link]] at line {other} already does: the two contradict",
                        pair.0, pair.1
                    ),
                    Some("make the windows not overlap, or merge the two".into()),
                );
                break;
            }
        }
        for pair in &pairs {
            seen.push((pair.clone(), window, line));
        }
        sc.faults.push(Fault {
            kind: "link",
            pairs,
            window,
            effect: FaultEffect::Degrade {
                loss,
                latency_ms,
                jitter_ms,
            },
            line,
        });
    }
}

pub(super) fn parse_injections(p: &mut P<'_>, root: &Table, sc: &mut Scenario) {
    for t in p.tables(root, "inject") {
        let line = p.line(t);
        let what = format!("[[inject]] at line {line}");
        p.keys(t, &what, &["at", "from", "to", "type", "payload"]);
        let at = p.time(t, "at", &what);
        let at = p.required(t, "at", &what, at);
        let from = p.address(t, "from", &what);
        let to = p.address(t, "to", &what);
        let ty = p.message_type(t, "type", &what);
        let ty = p.required(t, "type", &what, ty);
        let payload = match t.get("payload") {
            Some(item) => p.payload(item, &what),
            None => {
                p.err(t.span(), format!("{what} is missing `payload`"), None);
                None
            }
        };
        if let (Some(f), Some(d)) = (&from, &to) {
            let (fs, ds) = (
                p.fleet.system_by_name(&f.0).map(|s| s.id),
                p.fleet.system_by_name(&d.0).map(|s| s.id),
            );
            if let (Some(a), Some(b)) = (fs, ds) {
                if a != b && p.fleet.route(a, b).is_none() {
                    p.err(
                        t.get("to").and_then(Item::span),
                        format!(
                            "{what}: the communication table has `X` from {} to {}, so this message cannot be sent",
                            f.0, d.0
                        ),
                        None,
                    );
                    continue;
                }
            }
        }
        if let (Some(at_s), Some(from), Some(to), Some(message_type), Some(payload)) =
            (at, from, to, ty, payload)
        {
            sc.injections.push(Injection {
                at_s,
                from,
                to,
                message_type,
                payload,
                line,
            });
        }
    }
    sc.injections.sort_by(|a, b| a.at_s.total_cmp(&b.at_s));
}

pub(super) fn parse_taps(p: &mut P<'_>, root: &Table, sc: &mut Scenario) {
    for t in p.tables(root, "tap") {
        let line = p.line(t);
        let what = format!("[[tap]] at line {line}");
        p.keys(
            t,
            &what,
            &[
                "system", "topic", "from", "to", "module", "type", "action", "delay_ms", "copies",
                "start", "end", "script",
            ],
        );
        let path = if t.get("topic").is_some() {
            for k in ["from", "to", "module", "type"] {
                if let Some(i) = t.get(k) {
                    p.err(
                        i.span(),
                        format!("`{k}` does not apply to a topic tap ({what})"),
                        Some("a topic tap takes `system` and `topic`".into()),
                    );
                }
            }
            let system = p.system_key(t, "system", &what);
            let system = p.required(t, "system", &what, system);
            let topic = p.string(t, "topic", &what);
            match (system, topic) {
                (Some(system), Some(topic)) if !topic.is_empty() => {
                    Some(TapSpec::Topic { system, topic })
                }
                (_, Some(_)) => {
                    p.err(
                        t.get("topic").and_then(Item::span),
                        "empty topic name".into(),
                        None,
                    );
                    None
                }
                _ => None,
            }
        } else {
            let to = p.system_key(t, "to", &what);
            let to = p.required(t, "to", &what, to);
            let from = p.system_key(t, "from", &what);
            let module = match p.string(t, "module", &what) {
                Some(m) => {
                    let span = t.get("module").and_then(Item::span);
                    p.module(&m, span, &what)
                }
                None => None,
            };
            let message_type = p.message_type(t, "type", &what);
            if let (Some(d), Some(m)) = (&to, &module) {
                p.hosted(d, m, t.get("module").and_then(Item::span), &what);
            }
            match (&from, &to) {
                (Some(f), Some(d)) if f != d => {
                    let a = p.fleet.system_by_name(f).map(|s| s.id);
                    let b = p.fleet.system_by_name(d).map(|s| s.id);
                    if let (Some(a), Some(b)) = (a, b) {
                        if p.fleet.route(a, b).is_none() {
                            p.err(
                                t.get("from").and_then(Item::span),
                                format!("{what} is on a path that does not exist: the communication table has `X` from {f} to {d}"),
                                Some("tap a pair the table connects".into()),
                            );
                        }
                    }
                }
                _ => {}
            }
            to.map(|to| TapSpec::Messages {
                from,
                to,
                module,
                message_type,
            })
        };
        let action = p.string(t, "action", &what);
        let action = p.required(t, "action", &what, action);
        let kind = match action.as_deref() {
            Some("observe") => Some(TapKind::Observe),
            Some("drop") => Some(TapKind::Drop),
            Some("replace") => Some(TapKind::Replace),
            Some("delay") => match p.number(t, "delay_ms", &what) {
                Some(ms) if ms.is_finite() && ms > 0.0 => Some(TapKind::Delay(ms)),
                Some(ms) => {
                    p.err(
                        t.get("delay_ms").and_then(Item::span),
                        format!("`delay_ms` of {what} is {ms}: it must be more than 0"),
                        None,
                    );
                    None
                }
                None => {
                    p.required::<()>(t, "delay_ms", &what, None);
                    None
                }
            },
            Some("duplicate") => match t.get("copies") {
                None => Some(TapKind::Duplicate(1)),
                Some(i) => match i.as_integer() {
                    Some(n) if (1..=1000).contains(&n) => Some(TapKind::Duplicate(n as u32)),
                    _ => {
                        p.err(
                            i.span(),
                            format!("`copies` of {what} must be from 1 to 1000"),
                            None,
                        );
                        None
                    }
                },
            },
            Some(other) => {
                let options = ["observe", "drop", "delay", "duplicate", "replace"];
                let help = crate::suggest::closest(other, &options)
                    .map(|s| format!("did you mean `{s}`?"))
                    .unwrap_or_else(|| format!("one of {}", options.join(", ")));
                p.err(
                    t.get("action").and_then(Item::span),
                    format!("unknown tap action `{other}` in {what}"),
                    Some(help),
                );
                None
            }
            None => None,
        };
        let window = p.window(t, &what, true);
        let mut script = Vec::new();
        if let Some(item) = t.get("script") {
            if kind != Some(TapKind::Replace) {
                p.err(
                    item.span(),
                    format!("`script` of {what} needs action = \"replace\""),
                    None,
                );
            }
            script = parse_script(p, item, &what, window.flatten());
        }
        let script_type = match &path {
            Some(TapSpec::Messages {
                message_type,
                module,
                ..
            }) if !script.is_empty() => {
                if message_type.is_none() || module.is_none() {
                    p.err(
                        t.get("script").and_then(Item::span),
                        format!("{what} scripts messages, so it needs `module` and `type`"),
                        None,
                    );
                }
                *message_type
            }
            _ => None,
        };
        let (Some(path), Some(kind), Some(window)) = (path, kind, window) else {
            continue;
        };
        if kind == TapKind::Replace {
            if let Some(other) = sc.taps.iter().find(|o| {
                o.kind == TapKind::Replace
                    && paths_overlap(&o.path, &path)
                    && match (o.window, window) {
                        (Some(a), Some(b)) => a.overlaps(&b),
                        _ => true,
                    }
            }) {
                p.err(
                    t.span(),
                    format!(
                        "{what} replaces the source of a path that [[tap]] at line {} already replaces at the same time: the two contradict",
                        other.line
                    ),
                    Some("make the windows not overlap".into()),
                );
                continue;
            }
        }
        sc.taps.push(ScenarioTap {
            path,
            kind,
            window,
            script,
            script_type,
            line,
        });
    }
}

fn parse_script(
    p: &mut P<'_>,
    item: &Item,
    what: &str,
    window: Option<Window>,
) -> Vec<(f64, Vec<u8>)> {
    let entries: Vec<Table> = match item {
        Item::ArrayOfTables(a) => a.iter().cloned().collect(),
        Item::Value(Value::Array(a)) => {
            let mut v = Vec::new();
            for e in a.iter() {
                match e.as_inline_table() {
                    Some(t) => {
                        let mut table = t.clone().into_table();
                        // Keep the entry's position for errors.
                        table.set_implicit(true);
                        v.push(table);
                    }
                    None => {
                        p.err(
                            e.span(),
                            format!("each `script` entry of {what} is {{ at = …, payload = … }}"),
                            None,
                        );
                    }
                }
            }
            v
        }
        _ => {
            p.err(
                item.span(),
                format!("`script` of {what} is a list of {{ at = …, payload = … }}"),
                None,
            );
            return Vec::new();
        }
    };
    let mut out = Vec::new();
    for e in &entries {
        let at = p.time(e, "at", what);
        // Entries converted from inline tables lose their spans: point at the script.
        let Some(at) = at else {
            if e.get("at").is_none() {
                p.err(
                    item.span(),
                    format!("a `script` entry of {what} is missing `at`"),
                    None,
                );
            }
            continue;
        };
        if let Some(w) = window {
            if at < w.start_s || at >= w.end_s {
                p.err(
                    item.span(),
                    format!(
                        "a `script` entry of {what} is at {at} s, outside the replacement's window {}–{} s",
                        w.start_s, w.end_s
                    ),
                    None,
                );
                continue;
            }
        }
        match e.get("payload") {
            Some(pl) => {
                if let Some(bytes) = p.payload(pl, what) {
                    out.push((at, bytes));
                }
            }
            None => p.err(
                item.span(),
                format!("a `script` entry of {what} is missing `payload`"),
                None,
            ),
        }
    }
    out.sort_by(|a, b| a.0.total_cmp(&b.0));
    out
}

/// Whether two tap paths can take the same message (a missing narrowing matches anything).
fn paths_overlap(a: &TapSpec, b: &TapSpec) -> bool {
    fn meet<T: PartialEq>(a: &Option<T>, b: &Option<T>) -> bool {
        match (a, b) {
            (Some(a), Some(b)) => a == b,
            _ => true,
        }
    }
    match (a, b) {
        (TapSpec::Topic { .. }, TapSpec::Topic { .. }) => a == b,
        (
            TapSpec::Messages {
                from: f1,
                to: t1,
                module: m1,
                message_type: y1,
            },
            TapSpec::Messages {
                from: f2,
                to: t2,
                module: m2,
                message_type: y2,
            },
        ) => t1 == t2 && meet(f1, f2) && meet(m1, m2) && meet(y1, y2),
        _ => false,
    }
}

//! Rows of results and their renderings: a text table, JSON and Markdown with the issue's
//! targets evaluated against baselines from the same run.

use std::fmt::Write;

use crate::config_scale::ValidateResult;
use crate::scale::ScaleResult;
use crate::stats::{Latency, Outcomes, Throughput};

/// One measurement.
#[derive(Clone, Debug)]
pub struct Row {
    /// `rtt`, `oneway`, `inproc`, `pinning`, `scale`, `sim`, `config`, `record` or `harness`.
    pub section: &'static str,
    /// What was measured (`raw-udp`, `hetcomm-udp-unack`, …).
    pub path: String,
    /// Payload bytes (0 when not applicable).
    pub size: usize,
    /// Named figures.
    pub metrics: Vec<(&'static str, f64)>,
    /// Free text (mode, pinning).
    pub note: String,
    /// Why the measurement could not be made.
    pub error: Option<String>,
}

impl Row {
    fn new(section: &'static str, path: &str, size: usize) -> Row {
        Row {
            section,
            path: path.to_string(),
            size,
            metrics: Vec::new(),
            note: String::new(),
            error: None,
        }
    }

    /// A measurement that failed.
    pub fn failed(section: &'static str, path: &str, size: usize, error: &str) -> Row {
        let mut r = Row::new(section, path, size);
        r.error = Some(error.to_string());
        r
    }

    /// Round-trip percentiles (µs).
    pub fn latency(section: &'static str, path: &str, size: usize, l: &Latency) -> Row {
        let mut r = Row::new(section, path, size);
        r.metrics = vec![
            ("p50_us", l.p50),
            ("p90_us", l.p90),
            ("p99_us", l.p99),
            ("p999_us", l.p999),
            ("max_us", l.max),
            ("samples", l.count as f64),
            ("lost", l.lost as f64),
        ];
        r
    }

    /// One-way throughput at the receiver, with the sender's outcome counts (acknowledged
    /// hetcomm paths) and the receiver's kernel drops (hetcomm paths) when known.
    pub fn throughput(path: &str, size: usize, t: &Throughput) -> Row {
        let mut r = Row::new("oneway", path, size);
        r.metrics = vec![
            ("msgs_per_s", t.msgs_per_s()),
            ("bytes_per_s", t.bytes_per_s()),
            ("sent", t.sent as f64),
            ("received", t.received as f64),
            ("lost_percent", t.lost_percent()),
        ];
        if let Some(o) = &t.outcomes {
            r.metrics.extend([
                ("delivered", o.delivered as f64),
                ("unconfirmed", o.unconfirmed as f64),
                ("failed", o.failed as f64),
                ("pending", o.pending as f64),
            ]);
        }
        if let Some(k) = t.kernel_drops {
            r.metrics.push(("rx_kernel_drops", k as f64));
        }
        r
    }

    /// The outcome counts of an acknowledged row, as a table cell (`-` when not counted).
    fn outcomes_cell(&self) -> String {
        let n = |k| self.get(k).map(|v| v as u64);
        match (n("delivered"), n("unconfirmed"), n("failed")) {
            (Some(delivered), Some(unconfirmed), Some(failed)) => Outcomes {
                delivered,
                unconfirmed,
                failed,
                pending: n("pending").unwrap_or(0),
            }
            .cell(),
            _ => "-".into(),
        }
    }

    /// In-process hand-off: rate (saturated runs) and latency from the payload's timestamp.
    pub fn handoff(
        path: &str,
        mode: &str,
        size: usize,
        t: Option<&Throughput>,
        l: &Latency,
    ) -> Row {
        let mut r = Row::new("inproc", path, size);
        r.note = mode.to_string();
        if let Some(t) = t {
            r.metrics.push(("msgs_per_s", t.msgs_per_s()));
        }
        r.metrics.push(("handoff_p50_us", l.p50));
        r.metrics.push(("handoff_p99_us", l.p99));
        r.metrics.push(("samples", l.count as f64));
        r
    }

    /// Fleet size figures.
    pub fn scale(s: &ScaleResult) -> Row {
        let mut r = Row::new("scale", &format!("{} systems", s.systems), 0);
        r.metrics = vec![
            ("systems", s.systems as f64),
            ("open_s", s.open_s),
            ("rss_bytes_per_system", s.rss_per_system),
            ("broadcast_ns_per_dest", s.broadcast_ns_per_dest),
            ("broadcast_ack_ns_per_dest", s.broadcast_ack_ns_per_dest),
        ];
        r
    }

    /// Config validation of a big fleet file, in a child process.
    pub fn config(v: &ValidateResult) -> Row {
        let mut r = Row::new("config", &format!("{} systems", v.systems), 0);
        r.metrics = vec![
            ("systems", v.systems as f64),
            ("cells", v.cells as f64),
            ("file_bytes", v.file_bytes as f64),
            ("validate_s", v.seconds),
            ("peak_rss_bytes", v.peak_rss_bytes),
        ];
        r
    }

    /// Simulator speed.
    pub fn sim(name: &str, systems: usize, simulated_s: f64, wall_s: f64, delivered: u64) -> Row {
        let mut r = Row::new("sim", name, 0);
        r.metrics = vec![
            ("systems", systems as f64),
            ("simulated_s", simulated_s),
            ("wall_s", wall_s),
            (
                "sim_s_per_wall_s",
                if wall_s > 0.0 {
                    simulated_s / wall_s
                } else {
                    0.0
                },
            ),
            ("delivered", delivered as f64),
        ];
        r
    }

    /// A named figure.
    pub fn get(&self, name: &str) -> Option<f64> {
        self.metrics
            .iter()
            .find(|(k, _)| *k == name)
            .map(|(_, v)| *v)
    }
}

/// What the report needs besides the rows.
pub struct Context {
    /// Whether this was a `--quick` run.
    pub quick: bool,
    /// Wall time of `hetcomm experiment reliability` (seconds), or why it is missing.
    pub reliability: Option<String>,
    /// How long the benchmark ran.
    pub wall_s: f64,
}

pub fn find<'a>(rows: &'a [Row], section: &str, path: &str, size: usize) -> Option<&'a Row> {
    rows.iter()
        .find(|r| r.section == section && r.path == path && r.size == size && r.error.is_none())
}

fn size_name(s: usize) -> String {
    match s {
        0 => "-".into(),
        s if s >= 1 << 20 && s % (1 << 20) == 0 => format!("{} MiB", s >> 20),
        s if s >= 1024 && s % 1024 == 0 => format!("{} KiB", s >> 10),
        s => format!("{s} B"),
    }
}

/// `v` with `digits` decimals, or `-` when there is none.
pub(crate) fn num(v: Option<f64>, digits: usize) -> String {
    match v {
        Some(v) if v.is_finite() => format!("{v:.digits$}"),
        _ => "-".into(),
    }
}

fn si(v: Option<f64>) -> String {
    match v {
        Some(v) if v >= 1e9 => format!("{:.2} G", v / 1e9),
        Some(v) if v >= 1e6 => format!("{:.2} M", v / 1e6),
        Some(v) if v >= 1e3 => format!("{:.1} k", v / 1e3),
        Some(v) => format!("{v:.0}"),
        None => "-".into(),
    }
}

fn ratio(a: Option<f64>, b: Option<f64>) -> String {
    match (a, b) {
        (Some(a), Some(b)) if b > 0.0 => format!("{:.2}×", a / b),
        _ => "-".into(),
    }
}

/// The tables, as (title, header, rows of cells).
/// A rendered table: title, header, rows of cells.
type Table = (String, Vec<&'static str>, Vec<Vec<String>>);

fn tables(rows: &[Row]) -> Vec<Table> {
    let mut out = Vec::new();
    let err = |r: &Row| r.error.as_ref().map(|e| format!("failed: {e}"));
    let rtt: Vec<Vec<String>> = rows
        .iter()
        .filter(|r| r.section == "rtt")
        .map(|r| {
            let base = find(rows, "rtt", "raw-udp", r.size).and_then(|b| b.get("p50_us"));
            let mut v = vec![r.path.clone(), size_name(r.size)];
            if let Some(e) = err(r) {
                v.push(e);
                return v;
            }
            for k in ["p50_us", "p90_us", "p99_us", "p999_us", "max_us"] {
                v.push(num(r.get(k), 1));
            }
            v.push(num(r.get("lost"), 0));
            v.push(ratio(r.get("p50_us"), base));
            v
        })
        .collect();
    out.push((
        "Round trip (ping-pong between two processes; inproc: two threads), µs".into(),
        vec![
            "path",
            "size",
            "p50",
            "p90",
            "p99",
            "p99.9",
            "max",
            "lost",
            "p50 × raw UDP",
        ],
        rtt,
    ));
    let ow: Vec<Vec<String>> = rows
        .iter()
        .filter(|r| r.section == "oneway")
        .map(|r| {
            let base = find(rows, "oneway", "raw-udp", r.size).and_then(|b| b.get("msgs_per_s"));
            let mut v = vec![r.path.clone(), size_name(r.size)];
            if let Some(e) = err(r) {
                v.push(e);
                return v;
            }
            v.push(si(r.get("msgs_per_s")));
            v.push(si(r.get("bytes_per_s")));
            v.push(num(r.get("lost_percent"), 1));
            v.push(r.outcomes_cell());
            v.push(num(r.get("rx_kernel_drops"), 0));
            v.push(ratio(r.get("msgs_per_s"), base));
            v
        })
        .collect();
    out.push((
        "One-way throughput, counted at the receiver (acknowledged: how the sends ended, \
         delivered/unconfirmed/failed; rx kernel drops: datagrams the receiver's kernel dropped)"
            .into(),
        vec![
            "path",
            "size",
            "msg/s",
            "B/s",
            "lost %",
            "delivered/unconfirmed/failed",
            "rx kernel drops",
            "msg/s × raw UDP",
        ],
        ow,
    ));
    let ip: Vec<Vec<String>> = rows
        .iter()
        .filter(|r| r.section == "inproc")
        .map(|r| {
            let mut v = vec![r.path.clone(), r.note.clone()];
            if let Some(e) = err(r) {
                v.push(e);
                return v;
            }
            v.push(si(r.get("msgs_per_s")));
            v.push(num(r.get("handoff_p50_us"), 2));
            v.push(num(r.get("handoff_p99_us"), 2));
            v
        })
        .collect();
    out.push((
        "In-process hand-off, 64 B (saturated: sender as fast as it can; paced: one at a time)"
            .into(),
        vec![
            "path",
            "mode",
            "msg/s",
            "hand-off p50 µs",
            "hand-off p99 µs",
        ],
        ip,
    ));
    let pin: Vec<Vec<String>> = rows
        .iter()
        .filter(|r| r.section == "pinning")
        .map(|r| {
            let mut v = vec![r.path.clone()];
            if let Some(e) = err(r) {
                v.push(e);
                return v;
            }
            v.push(num(r.get("p50_us"), 1));
            v.push(num(r.get("p99_us"), 1));
            v
        })
        .collect();
    out.push((
        "Pinned (both processes on CPU 0) vs unpinned, 64 B round trip, µs".into(),
        vec!["path", "p50", "p99"],
        pin,
    ));
    let sc: Vec<Vec<String>> = rows
        .iter()
        .filter(|r| r.section == "scale")
        .map(|r| {
            let mut v = vec![r.path.clone()];
            if let Some(e) = err(r) {
                v.push(e);
                return v;
            }
            v.push(num(r.get("open_s"), 3));
            v.push(num(r.get("rss_bytes_per_system").map(|b| b / 1024.0), 1));
            v.push(num(r.get("broadcast_ns_per_dest"), 0));
            v.push(num(r.get("broadcast_ack_ns_per_dest"), 0));
            v
        })
        .collect();
    out.push((
        "Scale: N systems in one process (star over inproc, 64 B broadcast from the hub)".into(),
        vec![
            "fleet",
            "open s",
            "RSS KiB / system",
            "broadcast ns / dest (unack)",
            "broadcast ns / dest (ack)",
        ],
        sc,
    ));
    let sim: Vec<Vec<String>> = rows
        .iter()
        .filter(|r| r.section == "sim")
        .map(|r| {
            let mut v = vec![r.path.clone()];
            if let Some(e) = err(r) {
                v.push(e);
                return v;
            }
            v.push(num(r.get("simulated_s"), 1));
            v.push(num(r.get("wall_s"), 3));
            v.push(num(r.get("sim_s_per_wall_s"), 1));
            v
        })
        .collect();
    out.push((
        "Virtual-time simulator speed".into(),
        vec!["run", "simulated s", "wall s", "simulated s / wall s"],
        sim,
    ));
    let cfg: Vec<Vec<String>> = rows
        .iter()
        .filter(|r| r.section == "config")
        .map(|r| {
            let mut v = vec![r.path.clone()];
            if let Some(e) = err(r) {
                v.push(e);
                return v;
            }
            v.push(si(r.get("cells")));
            v.push(num(r.get("file_bytes").map(|b| b / 1e6), 0));
            v.push(num(r.get("validate_s"), 2));
            v.push(num(r.get("peak_rss_bytes").map(|b| b / 1e6), 0));
            v
        })
        .collect();
    out.push((
        "Config validation (`hetcomm validate`'s load + summary, in a child process; full table)"
            .into(),
        vec!["fleet", "table cells", "file MB", "seconds", "peak RSS MB"],
        cfg,
    ));
    out.extend(crate::record_bench::tables(rows));
    out.extend(crate::harness_cost::tables(rows));
    out.retain(|(_, _, r)| !r.is_empty());
    out
}

/// The readable table for stdout.
pub fn table(rows: &[Row]) -> String {
    let mut s = String::new();
    for (title, header, body) in tables(rows) {
        let _ = writeln!(s, "\n{title}");
        let cols = header.len();
        let mut w: Vec<usize> = header.iter().map(|h| h.chars().count()).collect();
        for r in &body {
            for (i, c) in r.iter().enumerate().take(cols) {
                w[i] = w[i].max(c.chars().count());
            }
        }
        let line = |cells: Vec<String>| {
            let mut l = String::new();
            for (i, c) in cells.iter().enumerate() {
                let width = w.get(i).copied().unwrap_or(0);
                if i == 0 {
                    let _ = write!(l, "{c:<width$}");
                } else {
                    let _ = write!(l, "  {c:>width$}");
                }
            }
            l
        };
        let _ = writeln!(
            s,
            "{}",
            line(header.iter().map(|h| h.to_string()).collect())
        );
        for r in body {
            let _ = writeln!(s, "{}", line(r));
        }
    }
    s
}

/// Every row as JSON, with the run's context.
pub fn json(rows: &[Row], ctx: &Context) -> String {
    let values: Vec<serde_json::Value> = rows
        .iter()
        .map(|r| {
            let mut m = serde_json::Map::new();
            m.insert("section".into(), r.section.into());
            m.insert("path".into(), r.path.clone().into());
            m.insert("size".into(), r.size.into());
            if !r.note.is_empty() {
                m.insert("note".into(), r.note.clone().into());
            }
            if let Some(e) = &r.error {
                m.insert("error".into(), e.clone().into());
            }
            for (k, v) in &r.metrics {
                m.insert((*k).into(), serde_json::json!(v));
            }
            serde_json::Value::Object(m)
        })
        .collect();
    let targets: Vec<serde_json::Value> = targets(rows, ctx)
        .into_iter()
        .map(|t| serde_json::json!({"target": t.name, "status": t.status, "figure": t.figure}))
        .collect();
    let v = serde_json::json!({
        "quick": ctx.quick,
        "wall_s": ctx.wall_s,
        "reliability_wall": ctx.reliability,
        "rows": values,
        "targets": targets,
    });
    serde_json::to_string_pretty(&v).unwrap_or_else(|e| format!("{{\"error\": \"{e}\"}}"))
}

/// One target of the issue, evaluated.
pub struct Target {
    /// What the issue asks.
    pub name: &'static str,
    /// `met`, `missed` or `not measured`.
    pub status: &'static str,
    /// The figures behind the verdict, and by how much it misses.
    pub figure: String,
    /// Why, when it misses or could not be measured.
    pub why: &'static str,
}

fn verdict(ok: bool) -> &'static str {
    if ok {
        "met"
    } else {
        "missed"
    }
}

/// Evaluates the targets.
pub fn targets(rows: &[Row], ctx: &Context) -> Vec<Target> {
    let mut t = Vec::new();
    let g = |section: &str, path: &str, size: usize, k: &str| {
        find(rows, section, path, size).and_then(|r| r.get(k))
    };
    let none = |name, why| Target {
        name,
        status: "not measured",
        figure: "-".into(),
        why,
    };
    // 1. udp RTT 64 B unacknowledged p50 ≤ 1.3× raw UDP.
    let hp50 = g("rtt", "hetcomm-udp-unack", 64, "p50_us");
    let rp50 = g("rtt", "raw-udp", 64, "p50_us");
    t.push(match (hp50, rp50) {
        (Some(h), Some(r)) if r > 0.0 => {
            let x = h / r;
            Target {
                name: "udp round trip 64 B unacknowledged: p50 ≤ 1.3× raw UDP",
                status: verdict(x <= 1.3),
                figure: format!(
                    "{h:.1} µs vs raw UDP {r:.1} µs = {x:.2}× (target 1.3×{})",
                    if x > 1.3 {
                        format!("; misses by {:.0}%", (x / 1.3 - 1.0) * 100.0)
                    } else {
                        String::new()
                    }
                ),
                why: WHY_UDP_P50,
            }
        }
        _ => none(
            "udp round trip 64 B unacknowledged: p50 ≤ 1.3× raw UDP",
            "a run failed",
        ),
    });
    // 2. p99 ≤ 3× p50.
    let hp99 = g("rtt", "hetcomm-udp-unack", 64, "p99_us");
    t.push(match (hp50, hp99) {
        (Some(p50), Some(p99)) if p50 > 0.0 => {
            let x = p99 / p50;
            Target {
                name: "udp round trip 64 B unacknowledged: p99 ≤ 3× p50",
                status: verdict(x <= 3.0),
                figure: format!(
                    "p99 {p99:.1} µs / p50 {p50:.1} µs = {x:.2}×{} (raw UDP: {})",
                    if x > 3.0 {
                        format!("; misses by {:.0}%", (x / 3.0 - 1.0) * 100.0)
                    } else {
                        String::new()
                    },
                    ratio(g("rtt", "raw-udp", 64, "p99_us"), rp50)
                ),
                why: WHY_TAIL,
            }
        }
        _ => none(
            "udp round trip 64 B unacknowledged: p99 ≤ 3× p50",
            "a run failed",
        ),
    });
    // 3. unpinned p50 ≤ 1.5× pinned: with the default (sleeping) receivers, and with
    // receivers spinning before they sleep (`Module::set_wait_spin`).
    let pin_ratio = |row: &str| {
        let p = g("pinning", &format!("{row} pinned-cpu0"), 64, "p50_us")?;
        let f = g("pinning", &format!("{row} unpinned"), 64, "p50_us")?;
        (p > 0.0).then_some((f, p, f / p))
    };
    const PIN_NAME: &str = "udp 64 B unacknowledged: unpinned p50 ≤ 1.5× pinned";
    t.push(match (pin_ratio("hetcomm-udp-unack"), pin_ratio("hetcomm-udp-unack-spin")) {
        (Some((f, p, x)), spin) => {
            let spin_met = spin.is_some_and(|(_, _, xs)| xs <= 1.5);
            Target {
                name: PIN_NAME,
                status: if x <= 1.5 {
                    "met"
                } else if spin_met {
                    "met with spinning receivers"
                } else {
                    "missed"
                },
                figure: format!(
                    "default (receivers sleep): unpinned {f:.1} µs / pinned {p:.1} µs = {x:.2}×{}; {} (raw UDP: {})",
                    if x > 1.5 {
                        format!(", misses by {:.0}%", (x / 1.5 - 1.0) * 100.0)
                    } else {
                        String::new()
                    },
                    match spin {
                        Some((fs, ps, xs)) => format!(
                            "receivers spinning {} µs before they sleep: unpinned {fs:.1} µs / pinned {ps:.1} µs = {xs:.2}×",
                            crate::hc::WAIT_SPIN.as_micros()
                        ),
                        None => "spinning run failed".to_string(),
                    },
                    ratio(
                        g("pinning", "raw-udp unpinned", 64, "p50_us"),
                        g("pinning", "raw-udp pinned-cpu0", 64, "p50_us")
                    )
                ),
                why: WHY_PIN,
            }
        }
        _ => none(PIN_NAME, "a run failed"),
    });
    // 4. acknowledged adds ≤ 3 µs.
    let ack = g("rtt", "hetcomm-udp-ack", 64, "p50_us");
    t.push(match (ack, hp50) {
        (Some(a), Some(u)) => {
            let d = a - u;
            Target {
                name: "acknowledged adds ≤ 3 µs (udp 64 B round trip p50)",
                status: verdict(d <= 3.0),
                figure: format!(
                    "acknowledged {a:.1} µs − unacknowledged {u:.1} µs = {d:+.1} µs{} (tcp: {} µs)",
                    if d > 3.0 {
                        format!("; misses by {:.1} µs", d - 3.0)
                    } else {
                        String::new()
                    },
                    match (
                        g("rtt", "hetcomm-tcp-ack", 64, "p50_us"),
                        g("rtt", "hetcomm-tcp-unack", 64, "p50_us")
                    ) {
                        (Some(a), Some(u)) => format!("{:+.1}", a - u),
                        _ => "-".into(),
                    }
                ),
                why: WHY_ACK,
            }
        }
        _ => none("acknowledged adds ≤ 3 µs", "a run failed"),
    });
    // 5. throughput 64 B ≥ 3 M msg/s.
    let best = ["hetcomm-udp-unack", "hetcomm-tcp-unack"]
        .iter()
        .filter_map(|p| g("oneway", p, 64, "msgs_per_s").map(|v| (*p, v)))
        .max_by(|a, b| a.1.total_cmp(&b.1));
    let raw_udp = g("oneway", "raw-udp", 64, "msgs_per_s");
    t.push(match best {
        Some((p, v)) => Target {
            name: "throughput 64 B, one sender → one receiver (two processes): ≥ 3 M msg/s",
            status: verdict(v >= 3e6),
            figure: format!(
                "best {p}: {:.2} M msg/s{} (raw TCP one write per message: {}, raw UDP: {}){}",
                v / 1e6,
                match raw_udp {
                    Some(r) if r > 0.0 => format!(" = {:.2}× raw UDP", v / r),
                    _ => String::new(),
                },
                si(g("oneway", "raw-tcp", 64, "msgs_per_s")),
                si(raw_udp),
                if v < 3e6 {
                    format!("; misses by {}", shortfall(3e6 / v.max(1.0)))
                } else {
                    String::new()
                }
            ),
            why: WHY_TPUT,
        },
        None => none("throughput 64 B ≥ 3 M msg/s", "a run failed"),
    });
    // 6. 64 KiB over tcp ≥ 90% of raw TCP.
    let h = g("oneway", "hetcomm-tcp-unack", 64 * 1024, "bytes_per_s");
    let r = g("oneway", "raw-tcp", 64 * 1024, "bytes_per_s");
    t.push(match (h, r) {
        (Some(h), Some(r)) if r > 0.0 => {
            let x = h / r;
            Target {
                name: "64 KiB over tcp: ≥ 90% of raw TCP bytes/s",
                status: verdict(x >= 0.9),
                figure: format!(
                    "{:.2} GB/s vs raw TCP {:.2} GB/s = {:.0}%{} (acknowledged: {})",
                    h / 1e9,
                    r / 1e9,
                    x * 100.0,
                    if x < 0.9 {
                        format!("; misses by {:.0} points", (0.9 - x) * 100.0)
                    } else {
                        String::new()
                    },
                    match g("oneway", "hetcomm-tcp-ack", 64 * 1024, "bytes_per_s") {
                        Some(a) => format!("{:.0}%", a / r * 100.0),
                        None => "-".into(),
                    }
                ),
                why: WHY_TCP,
            }
        }
        _ => none(
            "64 KiB over tcp: ≥ 90% of raw TCP bytes/s",
            "not measured in --quick (small payloads only) or a run failed",
        ),
    });
    // 7. in-process ≥ 10 M msg/s and p50 hand-off < 1 µs.
    let rate = rows
        .iter()
        .find(|r| {
            r.section == "inproc" && r.path == "hetcomm-inproc-unack" && r.note == "saturated"
        })
        .and_then(|r| r.get("msgs_per_s"));
    let paced_row = |note: &str| {
        rows.iter()
            .find(|r| r.section == "inproc" && r.path == "hetcomm-inproc-unack" && r.note == note)
            .and_then(|r| r.get("handoff_p50_us"))
    };
    let sleeping = paced_row("paced");
    let spinning = paced_row("paced, spin 100 µs");
    // The better of the two configurations counts; the figure names both.
    let paced = match (sleeping, spinning) {
        (Some(a), Some(b)) => Some(a.min(b)),
        (a, b) => a.or(b),
    };
    t.push(match (rate, paced) {
        (Some(rate), Some(p50)) => Target {
            name: "in-process: ≥ 10 M msg/s and p50 hand-off < 1 µs",
            status: verdict(rate >= 10e6 && p50 < 1.0),
            figure: format!(
                "{:.2} M msg/s{}; hand-off p50 {p50:.2} µs (paced; receiver sleeping {}, spinning {}){}",
                rate / 1e6,
                if rate < 10e6 {
                    format!(" (misses by {})", shortfall(10e6 / rate.max(1.0)))
                } else {
                    String::new()
                },
                sleeping.map_or("-".into(), |v| format!("{v:.2} µs")),
                spinning.map_or("-".into(), |v| format!("{v:.2} µs")),
                if p50 >= 1.0 {
                    format!(" (misses by {})", shortfall(p50))
                } else {
                    String::new()
                }
            ),
            why: WHY_INPROC,
        },
        _ => none(
            "in-process: ≥ 10 M msg/s and p50 hand-off < 1 µs",
            "a run failed",
        ),
    });
    // 8. reliability experiment < 5 s.
    let rel = ctx
        .reliability
        .as_deref()
        .map(|s| (s, s.trim().parse::<f64>()));
    t.push(match rel {
        Some((_, Ok(secs))) => Target {
            name: "20-trial reliability experiment in virtual time: < 5 s",
            status: verdict(secs < 5.0),
            figure: format!(
                "{secs:.3} s wall (`hetcomm experiment reliability --trials 20`, both modes){}",
                if secs >= 5.0 {
                    format!("; misses by {}", shortfall(secs / 5.0))
                } else {
                    String::new()
                }
            ),
            why: WHY_REL,
        },
        Some((text, Err(_))) => Target {
            name: "20-trial reliability experiment in virtual time: < 5 s",
            status: "not measured",
            figure: text.to_string(),
            why: "",
        },
        None => none(
            "20-trial reliability experiment in virtual time: < 5 s",
            "not run (pass --reliability-wall; benchmarks/run.sh does)",
        ),
    });
    // 9. 1000-system fleet sim faster than real time.
    let sim = rows
        .iter()
        .find(|r| r.section == "sim" && r.path.ends_with("star fleet") && r.error.is_none());
    t.push(match sim {
        Some(r) => {
            let n = r.get("systems").unwrap_or(0.0);
            let x = r.get("sim_s_per_wall_s").unwrap_or(0.0);
            Target {
                name: "1000-system fleet in the simulator: faster than real time",
                status: if n < 1000.0 {
                    "not measured"
                } else {
                    verdict(x > 1.0)
                },
                figure: format!(
                    "{n:.0} systems: {x:.2} simulated s per wall s{}",
                    if n < 1000.0 {
                        " (quick run: smaller fleet)"
                    } else if x <= 1.0 {
                        " (slower than real time)"
                    } else {
                        ""
                    }
                ),
                why: WHY_SIM,
            }
        }
        None => none(
            "1000-system fleet in the simulator: faster than real time",
            "a run failed",
        ),
    });
    // 10. A 3 000-system fleet file validates in < 3 s and < 500 MB.
    const CONFIG_NAME: &str =
        "config validation at 3 000 systems (9 M cells): < 3 s, peak RSS < 500 MB";
    t.push(match find(rows, "config", "3000 systems", 0) {
        Some(r) => {
            let secs = r.get("validate_s").unwrap_or(f64::INFINITY);
            let mb = r.get("peak_rss_bytes").unwrap_or(f64::INFINITY) / 1e6;
            Target {
                name: CONFIG_NAME,
                status: verdict(secs < 3.0 && mb < 500.0),
                figure: format!("{secs:.2} s, peak RSS {mb:.0} MB"),
                why: WHY_CONFIG,
            }
        }
        None => none(
            CONFIG_NAME,
            if ctx.quick {
                "quick run: smaller fleet"
            } else {
                "a run failed"
            },
        ),
    });
    // 11. C++ (the C API through hetcomm.hpp) costs no more than Rust on the wire path.
    const CPP_NAME: &str =
        "C++ round trip 64 B (two C++ processes, udp acknowledged): p50 within 10% of Rust's";
    // Judged on the pinned pair (both rows on one vCPU, so in the same scheduling mode); the
    // unpinned pair of the round-trip table is shown beside it.
    let pinned = |path: &str| g("pinning", &format!("{path} pinned-cpu0"), 64, "p50_us");
    let cpp = pinned(CPP_PATH);
    let rust = pinned("hetcomm-udp-ack");
    let unpinned = match (
        g("rtt", CPP_PATH, 64, "p50_us"),
        g("rtt", "hetcomm-udp-ack", 64, "p50_us"),
    ) {
        (Some(c), Some(r)) if r > 0.0 => format!(
            "; unpinned (round-trip table) C++ {c:.1} µs vs Rust {r:.1} µs = {:.2}×",
            c / r
        ),
        _ => String::new(),
    };
    t.push(match (cpp, rust) {
        (Some(c), Some(r)) if r > 0.0 => {
            let x = c / r;
            Target {
                name: CPP_NAME,
                status: verdict(x <= 1.1),
                figure: format!(
                    "pinned to one vCPU: C++ {c:.1} µs vs Rust hetcomm-udp-ack {r:.1} µs = {x:.2}×{unpinned}"
                ),
                why: WHY_CPP,
            }
        }
        _ => none(
            CPP_NAME,
            "not run (pass --cpp-bin with examples/cpp's pingpong; benchmarks/run.sh builds it)",
        ),
    });
    t.extend(crate::secured::targets(rows));
    t.extend(crate::harness_cost::targets(rows));
    t
}

/// The row of the C++ round trip (`--cpp-bin`).
pub const CPP_PATH: &str = "cpp-udp-ack";

const WHY_CPP: &str = "the C++ processes run the same Rust runtime through the C API (libhetcomm_c): per message the wrapper adds a ticket allocation and a copy of the payload into the caller's buffer; the rest is the same code as the Rust row. Round trips on this VM swing with where the scheduler puts the two processes (two modes, about 43 and 52 µs unpinned), so the verdict compares the two paths pinned to the same vCPU, where both run in the same mode.";

const WHY_UDP_P50: &str = "a module waiting in `recv` reads the UDP socket itself (the runtime's reactor), so, as with raw UDP, the only wake-up per direction is the kernel's. What remains is work per message: encoding the frame with its CRC, the router (a lock, the duplicate filter), the inbox, and a poll(2) before each read where raw UDP blocks in recvfrom directly.";
const WHY_TAIL: &str = "round trips on this VM are bimodal (about 3 µs when both processes share a vCPU, about 20 µs when a wake-up crosses vCPUs), and a run whose median falls in the fast mode has its p99 in the slow one; raw UDP's own tail moves the same way from run to run. (A request and its answer hold no frame for batching, so the batching timer's wake-ups are not on their path: those once put every few round trips in the slow mode.)";
const WHY_PIN: &str = "pinned, all threads share one core and every hand-off is a plain context switch; unpinned, a wake-up that crosses vCPUs (an IPI) costs several µs on this VM, paid by raw UDP and by hetcomm's default receiver, which sleeps in poll() on its socket. With `Module::set_wait_spin` the waiting module keeps reading its links (poll without a timeout, yielding the CPU between looks) for up to that long before it sleeps: unpinned, the reply is read on arrival with no wake-up at all, pinned, the yield lets the peer run. Spinning costs a busy core while waiting, so it is an opt-in per module, not the default.";
const WHY_ACK: &str = "an acknowledged send adds an ack frame in each direction (encode, send syscall, receive, router bookkeeping and a retransmission timer); the ack goes at once without making the answer after it wait for batching, so little of this is on the round trip's path, and the figure is a difference of two noisy medians.";
const WHY_TPUT: &str = "small frames are batched into one datagram or write while they come faster than `batch_linger_us`, so syscalls are amortised; an unacknowledged send skips the router's pending entry and outcome slot (its outcome is known when the link takes the frame), and a received batch datagram is handled under one router lock and one clock reading. The sender is now faster than the receiver, so unacknowledged UDP loses datagrams at the receiving socket (the `lost %` column): use acknowledged delivery for flow control (at most `max_in_flight` sends, default 1024, await their acknowledgement per destination; the benchmark's sender yields and retries when it is refused with `Backpressure`). The target is an absolute rate while this VM's speed changes from run to run (raw UDP's own rate here moved between 0.8 and 1.3 M msg/s across runs): the ratio to raw UDP in the same run is the steadier figure.";
const WHY_TCP: &str = "the frames on TCP carry a header-only CRC (TCP checksums the bytes); the sender writes record header, frame header and the caller's payload with one `writev` (no copy into a frame buffer); the waiting module reads its connections itself through one epoll descriptor (no reader thread, so no wake-up and no third thread competing for the two CPUs), straight into a pooled buffer that becomes the payload and goes back to the pool when the message is dropped (no allocation per message: with glibc, a 64 KiB buffer allocated on one thread and freed on another was returned to the kernel and faulted in again every time). What remains against raw TCP: the receiver's `poll` and `epoll_wait` before its reads, and the router's per-send bookkeeping. On this VM the ratio moves by about ±5% from run to run.";
const WHY_INPROC: &str = "an in-process send skips framing, checksums and both routers: a lane shared with the sender's router numbers and counts it with one atomic increment (no lock), its timestamp comes from the time-stamp counter (10 ns a read instead of 26 for `clock_gettime`), and it is appended to the destination inbox's intake under a short lock; the receiver swaps the whole intake out per batch and takes batches (`Module::recv_raw_many`). Alone, a sender spends about 85 ns a send (about 12 M msg/s; callgrind counts some 520 instructions). With the receiver on the other core, the two threads exchange the intake's lock line and the swapped vector's memory once per batch; the faster the receiver keeps up, the smaller the batches and the more often that happens, so the rate moves between about 8 and 11 M msg/s from run to run on this VM (the table keeps the median of three). Going further needs the sender to hand over whole batches (a send of many messages at once), which the API does not offer. When the scheduler puts both threads on one vCPU the rate falls to about 2.5 M msg/s. A receiver that sleeps is woken through a futex, several µs on this VM; with `Module::set_wait_spin` it spins and takes the message in well under 1 µs.";
const WHY_REL: &str = "the experiment's wall time is dominated by the simulated runs of every trial and the report files it writes.";
const WHY_CONFIG: &str = "the file's text is held once; the table is read without a TOML document (12 bytes per cell, cell texts interned), resolved one distinct text at a time, and sorted into the pair map once; the pair map itself (`Fleet::table`, a BTreeMap) and the file's text are most of the peak.";
const WHY_SIM: &str = "the simulator runs every frame and timer of every system on one thread; the cost grows with the number of messages per simulated second (here about 2×N per 100 ms).";

/// How far a figure is from its target, `ratio` times off: a percentage when close (where
/// "1.0×" would hide it), a factor otherwise.
fn shortfall(ratio: f64) -> String {
    if ratio < 1.5 {
        format!("{:.0}%", (ratio - 1.0) * 100.0)
    } else {
        format!("{ratio:.1}×")
    }
}

/// Markdown: the tables and the targets.
pub fn markdown(rows: &[Row], ctx: &Context) -> String {
    let mut s = String::new();
    for (title, header, body) in tables(rows) {
        let _ = writeln!(s, "### {title}\n");
        let _ = writeln!(s, "| {} |", header.join(" | "));
        let _ = writeln!(s, "|{}", "---|".repeat(header.len()));
        for r in body {
            let mut cells = r.clone();
            cells.resize(header.len(), String::new());
            let _ = writeln!(s, "| {} |", cells.join(" | ").replace('\n', " "));
        }
        let _ = writeln!(s);
    }
    let _ = writeln!(s, "## Targets\n");
    let _ = writeln!(s, "| target | status | figure (same run) |");
    let _ = writeln!(s, "|---|---|---|");
    let ts = targets(rows, ctx);
    for t in &ts {
        let _ = writeln!(s, "| {} | **{}** | {} |", t.name, t.status, t.figure);
    }
    let _ = writeln!(s);
    for t in ts.iter().filter(|t| t.status != "met" && !t.why.is_empty()) {
        let _ = writeln!(s, "- *{}* — {}: {}", t.name, t.status, t.why);
    }
    let _ = writeln!(s, "\nBenchmark wall time: {:.0} s.", ctx.wall_s);
    s
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::stats::Outcomes;

    #[test]
    fn an_acknowledged_row_shows_how_its_sends_ended() {
        let acked = Throughput {
            sent: 10,
            received: 9,
            bytes: 9 * 64,
            seconds: 1.0,
            outcomes: Some(Outcomes {
                delivered: 8,
                unconfirmed: 2,
                failed: 0,
                pending: 0,
            }),
            kernel_drops: Some(3),
        };
        let unacked = Throughput {
            outcomes: None,
            kernel_drops: None,
            ..acked.clone()
        };
        let rows = [
            Row::throughput("hetcomm-udp-ack", 64, &acked),
            Row::throughput("raw-udp", 64, &unacked),
        ];
        assert_eq!(rows[0].get("unconfirmed"), Some(2.0));
        assert_eq!(rows[0].get("rx_kernel_drops"), Some(3.0));
        let md = markdown(
            &rows,
            &Context {
                quick: true,
                reliability: None,
                wall_s: 0.0,
            },
        );
        assert!(
            md.contains("| hetcomm-udp-ack | 64 B | 9 | 576 | 10.0 | 8/2/0 | 3 | 1.00× |"),
            "{md}"
        );
        assert!(
            md.contains("| raw-udp | 64 B | 9 | 576 | 10.0 | - | - | 1.00× |"),
            "{md}"
        );
    }
}

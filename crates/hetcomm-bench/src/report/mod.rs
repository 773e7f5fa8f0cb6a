//! Rows of results and their renderings: a text table, JSON and Markdown with the issue's
//! targets evaluated against baselines from the same run.

use std::fmt::Write;

use crate::config_scale::ValidateResult;
use crate::scale::ScaleResult;
use crate::stats::{Latency, Outcomes, Throughput};

mod peers;
mod targets;
pub use targets::{targets, Target, CPP_PATH};

/// One measurement.
#[derive(Clone, Debug)]
pub struct Row {
    /// `rtt`, `oneway`, `paired` (a secured path against its unsecured twin, round by round),
    /// `inproc`, `pinning`, `scale`, `sim`, `config`, `record` or `harness`.
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
    /// An empty row of `section`.
    pub fn new(section: &'static str, path: &str, size: usize) -> Row {
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

    /// A secured path's rate over its unsecured twin's, round by round (`ratios`, in round
    /// order) and their median; `None` without a single round where both were measured.
    pub fn paired(secured: &str, twin: &str, size: usize, ratios: &[f64]) -> Option<Row> {
        let mut sorted = ratios.to_vec();
        sorted.sort_by(f64::total_cmp);
        let median = *sorted.get(sorted.len() / 2)?;
        let mut r = Row::new("paired", secured, size);
        r.metrics = vec![("ratio_median", median), ("rounds", ratios.len() as f64)];
        let rounds: Vec<String> = ratios
            .iter()
            .map(|x| format!("{:.0}%", x * 100.0))
            .collect();
        r.note = format!("over {twin}, round by round: {}", rounds.join(", "));
        Some(r)
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

    /// A simulated star fleet's run: [`Row::sim`] with the fleet's opening (time, memory per
    /// system) and the messages delivered per wall second.
    pub fn sim_fleet(name: &str, s: &crate::scale::SimResult) -> Row {
        let mut r = Row::sim(name, s.systems, s.simulated_s, s.wall_s, s.delivered);
        r.metrics.push(("open_s", s.open_s));
        r.metrics
            .push(("rss_kib_per_system", s.rss_per_system / 1024.0));
        if s.wall_s > 0.0 {
            r.metrics
                .push(("delivered_per_wall_s", s.delivered as f64 / s.wall_s));
        }
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

/// A rendered table: title, header, rows of cells.
pub type Table = (String, Vec<&'static str>, Vec<Vec<String>>);

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
            v.push(si(r.get("delivered_per_wall_s")));
            v.push(num(r.get("open_s"), 3));
            v.push(num(r.get("rss_kib_per_system"), 1));
            v
        })
        .collect();
    out.push((
        "Virtual-time simulator speed".into(),
        vec![
            "run",
            "simulated s",
            "wall s",
            "simulated s / wall s",
            "messages delivered / wall s",
            "open s",
            "RSS KiB / system",
        ],
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
    out.extend(crate::secured::tables(rows));
    out.extend(crate::record_bench::tables(rows));
    out.extend(crate::harness_cost::tables(rows));
    out.extend(crate::failover::tables(rows));
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

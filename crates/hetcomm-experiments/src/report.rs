//! Formatting a [`ReliabilityReport`]: text tables in the shape of the thesis's Tables 19 and
//! 20, CSV and JSON, and writing them into an output directory.

use std::fmt::Write as _;
use std::path::{Path, PathBuf};

use crate::reliability::{ExperimentError, ModeReport, ReliabilityReport, SystemRow};

/// Output format for stdout.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum Format {
    /// Human-readable tables.
    Text,
    /// `summary.csv` then, after a blank line, `tables.csv`.
    Csv,
    /// The report as one JSON object.
    Json,
}

impl Format {
    /// Parses `text`, `csv` or `json`.
    pub fn parse(s: &str) -> Option<Format> {
        match s {
            "text" => Some(Format::Text),
            "csv" => Some(Format::Csv),
            "json" => Some(Format::Json),
            _ => None,
        }
    }
}

fn pad(out: &mut String, cells: &[String], widths: &[usize]) {
    for (i, (c, w)) in cells.iter().zip(widths).enumerate() {
        if i == 0 {
            let _ = write!(out, "{c:<w$}");
        } else {
            let _ = write!(out, "  {c:>w$}");
        }
    }
    out.push('\n');
}

fn table(header: &[String], rows: &[Vec<String>]) -> String {
    let mut widths: Vec<usize> = header.iter().map(|h| h.chars().count()).collect();
    for r in rows {
        for (w, c) in widths.iter_mut().zip(r) {
            *w = (*w).max(c.chars().count());
        }
    }
    let mut out = String::new();
    pad(&mut out, header, &widths);
    let rule: Vec<String> = widths.iter().map(|&w| "-".repeat(w)).collect();
    pad(&mut out, &rule, &widths);
    for r in rows {
        pad(&mut out, r, &widths);
    }
    out
}

fn letters(rows: &[SystemRow]) -> Vec<String> {
    rows.first()
        .map(|r| {
            r.per_transport
                .iter()
                .map(|c| c.transport.clone())
                .collect()
        })
        .unwrap_or_default()
}

/// Table 19's shape: per system, per transport, attempts, successes and receivals, with a
/// total row.
pub fn table19(rows: &[SystemRow]) -> String {
    let ls = letters(rows);
    let mut header = vec!["System".to_string()];
    for what in ["transmit attempts", "transmit successes", "receivals"] {
        for l in &ls {
            header.push(format!("{l} {what}"));
        }
    }
    let n = ls.len();
    let mut totals = vec![0u64; 3 * n];
    let mut body: Vec<Vec<String>> = rows
        .iter()
        .map(|r| {
            let mut cells = vec![r.system.clone()];
            for (k, get) in [
                |c: &crate::reliability::TransportCounts| c.transmit_attempts,
                |c: &crate::reliability::TransportCounts| c.transmit_successes,
                |c: &crate::reliability::TransportCounts| c.receivals,
            ]
            .iter()
            .enumerate()
            {
                for (j, c) in r.per_transport.iter().enumerate() {
                    totals[k * n + j] += get(c);
                    cells.push(get(c).to_string());
                }
            }
            cells
        })
        .collect();
    let mut total_row = vec!["Total".to_string()];
    total_row.extend(totals.iter().map(|t| t.to_string()));
    body.push(total_row);
    table(&header, &body)
}

/// Table 20's shape: additional attempts per system and transport, with the sends that ended
/// unconfirmed (may have arrived) and failed (certainly did not).
pub fn table20(rows: &[SystemRow]) -> String {
    type Get = fn(&crate::reliability::TransportCounts) -> u64;
    let columns: [(&str, Get); 3] = [
        ("additional attempts", |c| c.additional_attempts),
        ("unconfirmed sends", |c| c.unconfirmed),
        ("failed sends", |c| c.failed),
    ];
    let ls = letters(rows);
    let mut header = vec!["System".to_string()];
    for (what, _) in &columns {
        for l in &ls {
            header.push(format!("{l} {what}"));
        }
    }
    let n = ls.len();
    let mut totals = vec![0u64; columns.len() * n];
    let mut body: Vec<Vec<String>> = rows
        .iter()
        .map(|r| {
            let mut cells = vec![r.system.clone()];
            for (k, (_, get)) in columns.iter().enumerate() {
                for (j, c) in r.per_transport.iter().enumerate() {
                    totals[k * n + j] += get(c);
                    cells.push(get(c).to_string());
                }
            }
            cells
        })
        .collect();
    let mut total_row = vec!["Total".to_string()];
    total_row.extend(totals.iter().map(|t| t.to_string()));
    body.push(total_row);
    table(&header, &body)
}

fn mode_text(out: &mut String, report: &ReliabilityReport, m: &ModeReport) {
    let _ = writeln!(out, "== mode: {} ==", m.mode);
    let _ = writeln!(out, "{}.", m.description);
    let _ = writeln!(out, "Losses: {}.", m.losses);
    for t in &m.transports {
        let profile = t
            .profile
            .as_deref()
            .map(|p| format!(", profile {p}"))
            .unwrap_or_default();
        let params = if t.params.is_empty() {
            String::new()
        } else {
            let kv: Vec<String> = t.params.iter().map(|(k, v)| format!("{k} = {v}")).collect();
            format!(", {}", kv.join(", "))
        };
        let _ = writeln!(
            out,
            "  {} = `{}`: {}{}{}; {}; {} attempts",
            t.letter, t.name, t.kind, profile, params, t.delivery, t.attempts
        );
    }
    if m.mode == crate::Mode::Acknowledged {
        let _ = writeln!(
            out,
            "  retransmission timeout: first {} ms, floor {} ms, ceiling {} ms, backoff ×{}",
            m.timing.initial_rto_ms, m.timing.min_rto_ms, m.timing.max_rto_ms, m.timing.backoff
        );
    }
    out.push('\n');
    let _ = writeln!(out, "Message statistics (shape of Table 19)");
    out.push_str(&table19(&m.systems));
    out.push('\n');
    let _ = writeln!(out, "Secondary attempts (shape of Table 20)");
    out.push_str(&table20(&m.systems));
    out.push('\n');
    let _ = writeln!(
        out,
        "Received: {} of {} messages ({:.2}%)   [thesis: {} of {} ({:.2}%)]",
        m.received,
        m.messages,
        m.delivery_ratio_percent,
        report.thesis.received,
        report.thesis.total,
        report.thesis.delivery_ratio_percent
    );
    let _ = writeln!(
        out,
        "Duplicates delivered: {}   (duplicate frames suppressed by the receiving routers: {}); out of order: {}",
        m.duplicates_delivered, m.duplicates_suppressed, m.out_of_order
    );
    let reasons = if m.failure_reasons.is_empty() {
        String::new()
    } else {
        let r: Vec<String> = m
            .failure_reasons
            .iter()
            .map(|(k, v)| format!("{k}: {v}"))
            .collect();
        format!(" ({})", r.join(", "))
    };
    let _ = writeln!(
        out,
        "Failed sends (certainly not delivered): {}{}",
        m.accounting.failed, reasons
    );
    let _ = writeln!(
        out,
        "Unconfirmed sends (frames left, no acknowledgement; may or may not have arrived): {}",
        m.accounting.unconfirmed
    );
    let a = &m.accounting;
    let _ = writeln!(
        out,
        "Accounting: accepted {} = delivered {} + sent without confirmation {} + unconfirmed {} + failed {} + in flight {}  [{}]",
        a.accepted,
        a.delivered,
        a.sent,
        a.unconfirmed,
        a.failed,
        a.in_flight,
        if a.balanced { "balanced" } else { "NOT BALANCED" }
    );
    let _ = writeln!(
        out,
        "Transmissions: {} ({:.3} per message, at most {}); delay send→receipt: mean {:.3} ms, p50 {:.3} ms, p99 {:.3} ms, max {:.3} ms",
        m.transmissions,
        m.attempts_per_message,
        m.max_attempts,
        m.delay.mean_ms,
        m.delay.p50_ms,
        m.delay.p99_ms,
        m.delay.max_ms
    );
    let drops: Vec<String> = m
        .network_drops
        .iter()
        .map(|(k, v)| format!("{k} {v}"))
        .collect();
    let _ = writeln!(
        out,
        "Network: {} frames sent, dropped: {}; virtual time {:.3} s over {} trials",
        m.network_frames,
        if drops.is_empty() {
            "none".to_string()
        } else {
            drops.join(", ")
        },
        m.virtual_seconds,
        report.trials
    );
    out.push('\n');
}

/// The whole report as text.
pub fn text(report: &ReliabilityReport) -> String {
    let mut out = String::new();
    let _ = writeln!(
        out,
        "Reliability analysis (thesis §5.2): {} trials, seed {}, {} messages per trial",
        report.trials, report.seed, report.messages_per_trial
    );
    let _ = writeln!(
        out,
        "Loss on {}: {}",
        report.lossy_transport, report.loss_description
    );
    let _ = writeln!(
        out,
        "Acknowledged mode budget: {} attempts (chosen so that 30% loss on B, i.i.d. or bursty \
         with mean burst 3, still delivers every message of the 20-trial experiment)",
        report.acknowledged_attempts
    );
    out.push('\n');
    for m in &report.modes {
        mode_text(&mut out, report, m);
    }
    let _ = writeln!(out, "== thesis (published, R = ROS, B = Bluetooth) ==");
    out.push_str(&table19(&report.thesis.systems));
    out.push('\n');
    out.push_str(&table20(&report.thesis.systems));
    let _ = writeln!(
        out,
        "\nReceived: {} of {} ({:.2}%)",
        report.thesis.received, report.thesis.total, report.thesis.delivery_ratio_percent
    );
    out
}

/// One row per (mode, system, transport), the thesis's published rows included as mode
/// `thesis-published`.
pub fn tables_csv(report: &ReliabilityReport) -> String {
    let mut out = String::from(
        "mode,system,transport,transmit_attempts,transmit_successes,receivals,additional_attempts,unconfirmed,failed\n",
    );
    let groups = report
        .modes
        .iter()
        .map(|m| (m.mode.name(), &m.systems))
        .chain(std::iter::once((
            "thesis-published",
            &report.thesis.systems,
        )));
    for (mode, rows) in groups {
        for r in rows {
            for c in &r.per_transport {
                let _ = writeln!(
                    out,
                    "{},{},{},{},{},{},{},{},{}",
                    mode,
                    csv_field(&r.system),
                    csv_field(&c.transport),
                    c.transmit_attempts,
                    c.transmit_successes,
                    c.receivals,
                    c.additional_attempts,
                    c.unconfirmed,
                    c.failed
                );
            }
        }
    }
    out
}

/// One row per mode: totals, accounting, attempts and delay.
pub fn summary_csv(report: &ReliabilityReport) -> String {
    let mut out = String::from(
        "mode,trials,seed,loss,messages,received,delivery_ratio_percent,duplicates_delivered,\
         duplicates_suppressed,accepted,delivered,sent,unconfirmed,failed,in_flight,balanced,\
         transmissions,attempts_per_message,max_attempts,delay_mean_ms,delay_p50_ms,delay_p99_ms,\
         delay_max_ms\n",
    );
    for m in &report.modes {
        let a = &m.accounting;
        let _ = writeln!(
            out,
            "{},{},{},{},{},{},{:.4},{},{},{},{},{},{},{},{},{},{},{:.4},{},{:.4},{:.4},{:.4},{:.4}",
            m.mode,
            report.trials,
            report.seed,
            csv_field(&report.loss_description),
            m.messages,
            m.received,
            m.delivery_ratio_percent,
            m.duplicates_delivered,
            m.duplicates_suppressed,
            a.accepted,
            a.delivered,
            a.sent,
            a.unconfirmed,
            a.failed,
            a.in_flight,
            a.balanced,
            m.transmissions,
            m.attempts_per_message,
            m.max_attempts,
            m.delay.mean_ms,
            m.delay.p50_ms,
            m.delay.p99_ms,
            m.delay.max_ms
        );
    }
    let t = &report.thesis;
    let _ = writeln!(
        out,
        "thesis-published,20,,,{},{},{:.4},,,,,,{},,,,,,,,,",
        t.total,
        t.received,
        t.delivery_ratio_percent,
        t.total - t.received
    );
    out
}

/// Quotes a CSV field if it needs it.
pub fn csv_field(s: &str) -> String {
    if s.contains([',', '"', '\n']) {
        format!("\"{}\"", s.replace('"', "\"\""))
    } else {
        s.to_string()
    }
}

/// The report as pretty JSON.
pub fn json(report: &ReliabilityReport) -> String {
    // Serializing plain structs of numbers, strings and maps with string keys cannot fail.
    serde_json::to_string_pretty(report).unwrap_or_else(|e| format!("{{\"error\": \"{e}\"}}"))
}

/// The report in `format`, as printed on stdout.
pub fn render(report: &ReliabilityReport, format: Format) -> String {
    match format {
        Format::Text => text(report),
        Format::Csv => format!("{}\n{}", summary_csv(report), tables_csv(report)),
        Format::Json => json(report) + "\n",
    }
}

/// Writes `reliability.json`, `summary.csv` and `tables.csv` into `dir` (created if needed)
/// and returns their paths.
pub fn write_files(
    report: &ReliabilityReport,
    dir: &Path,
) -> Result<Vec<PathBuf>, ExperimentError> {
    std::fs::create_dir_all(dir)
        .map_err(ExperimentError::io(format!("creating {}", dir.display())))?;
    let files = [
        ("reliability.json", json(report) + "\n"),
        ("summary.csv", summary_csv(report)),
        ("tables.csv", tables_csv(report)),
    ];
    let mut paths = Vec::new();
    for (name, text) in files {
        let path = dir.join(name);
        std::fs::write(&path, text)
            .map_err(ExperimentError::io(format!("writing {}", path.display())))?;
        paths.push(path);
    }
    Ok(paths)
}

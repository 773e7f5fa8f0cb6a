//! The report as text, CSV and JSON, and the files a run writes.

use std::fmt::Write as _;
use std::path::{Path, PathBuf};

use super::{Distribution, ExperimentError, LatencyReport, PairReport};

fn dist_cells(d: &Distribution) -> String {
    format!(
        "{:>10.1} {:>10.1} {:>10.1} {:>10.1} {:>10.1}",
        d.p50_us, d.p90_us, d.p99_us, d.p999_us, d.max_us
    )
}

fn pair_lines(out: &mut String, p: &PairReport) {
    let name = format!("{} → {}", p.from, p.to);
    let _ = writeln!(
        out,
        "{:<24} {:<20} {:<7} {:<10} {:>6} {:>5} {}",
        name,
        p.transport,
        p.clock.name(),
        "one-way",
        p.one_way.count,
        p.lost_one_way,
        dist_cells(&p.one_way)
    );
    match (&p.round_trip, p.lost_round_trip) {
        (Some(rt), Some(lost)) => {
            let back = format!("back: {}", p.return_transport.as_deref().unwrap_or("-"));
            let _ = writeln!(
                out,
                "{:<24} {:<20} {:<7} {:<10} {:>6} {:>5} {}",
                "",
                back,
                "",
                "round-trip",
                rt.count,
                lost,
                dist_cells(rt)
            );
        }
        _ => {
            let _ = writeln!(
                out,
                "{:<24} {:<20} {:<7} {:<10} no way back: the table has no pair {} → {}",
                "", "", "", "round-trip", p.to, p.from
            );
        }
    }
    if p.refused > 0 || p.duplicates > 0 || p.echoes_refused > 0 {
        let _ = writeln!(
            out,
            "{:<24} sent {} ({} refused{}), echoes refused {}, duplicates {}",
            "",
            p.sent,
            p.refused,
            p.refused_reason
                .as_deref()
                .map(|r| format!(": {r}"))
                .unwrap_or_default(),
            p.echoes_refused,
            p.duplicates
        );
    }
    if let Some(t) = &p.thesis {
        let _ = writeln!(out, "{:<24} thesis: {t}", "");
    }
}

/// The report as text: the settings, the clock methods, and two rows per pair.
pub fn text(report: &LatencyReport) -> String {
    let mut out = String::new();
    let _ = writeln!(
        out,
        "Delay analysis{}: {} probes per ordered pair (after {} warm-up), {} msg/s per pair{}, \
         {} B payload, seed {}",
        report
            .fleet
            .as_deref()
            .map(|f| format!(" of {f}"))
            .unwrap_or_default(),
        report.messages,
        report.warmup,
        report.rate_hz,
        if report.closed_loop {
            " at most, closed loop (each probe after the previous one's echo)"
        } else {
            ""
        },
        report.size_bytes,
        report.seed
    );
    let _ = writeln!(out, "Clocks:");
    for (clock, method) in &report.clock_methods {
        let _ = writeln!(out, "  {clock}: {method}");
    }
    for note in &report.notes {
        let _ = writeln!(out, "Note: {note}");
    }
    if report.against_thesis {
        let _ = writeln!(
            out,
            "Against the thesis (§5.1 fleet, R = emulated `wired`, B = emulated \
             `bluetooth-classic`): its only published delays are Table 12's, to the second; it \
             publishes no round trip and no distribution."
        );
    }
    let _ = writeln!(out);
    let _ = writeln!(
        out,
        "{:<24} {:<20} {:<7} {:<10} {:>6} {:>5} {:>10} {:>10} {:>10} {:>10} {:>10}",
        "pair",
        "transport",
        "clock",
        "delay",
        "n",
        "lost",
        "p50 µs",
        "p90 µs",
        "p99 µs",
        "p99.9 µs",
        "max µs"
    );
    for p in &report.pairs {
        pair_lines(&mut out, p);
    }
    out
}

fn csv_field(s: &str) -> String {
    if s.contains([',', '"', '\n']) {
        format!("\"{}\"", s.replace('"', "\"\""))
    } else {
        s.to_string()
    }
}

/// One line per pair and delay: the distributions.
pub fn csv_summary(report: &LatencyReport) -> String {
    let mut out = String::from(
        "from,to,transport,return_transport,clock,delay,sent,refused,count,lost,min_us,mean_us,\
         p50_us,p90_us,p99_us,p999_us,max_us,achieved_rate_hz\n",
    );
    for p in &report.pairs {
        let mut rows = vec![("one-way", Some(&p.one_way), Some(p.lost_one_way))];
        rows.push(("round-trip", p.round_trip.as_ref(), p.lost_round_trip));
        for (delay, d, lost) in rows {
            let Some(d) = d else { continue };
            let _ = writeln!(
                out,
                "{},{},{},{},{},{},{},{},{},{},{:.3},{:.3},{:.3},{:.3},{:.3},{:.3},{:.3},{:.3}",
                csv_field(&p.from),
                csv_field(&p.to),
                csv_field(&p.transport),
                csv_field(p.return_transport.as_deref().unwrap_or("")),
                p.clock.name(),
                delay,
                p.sent,
                p.refused,
                d.count,
                lost.unwrap_or(0),
                d.min_us,
                d.mean_us,
                d.p50_us,
                d.p90_us,
                d.p99_us,
                d.p999_us,
                d.max_us,
                p.achieved_rate_hz
            );
        }
    }
    out
}

/// Every sample, one line each.
pub fn csv_samples(report: &LatencyReport) -> String {
    let mut out = String::from("from,to,transport,clock,delay,seq,sent_us,delay_us\n");
    for s in &report.samples {
        let _ = writeln!(
            out,
            "{},{},{},{},{},{},{:.3},{:.3}",
            csv_field(&s.from),
            csv_field(&s.to),
            csv_field(&s.transport),
            s.clock.name(),
            s.direction.name(),
            s.seq,
            s.sent_us,
            s.delay_us
        );
    }
    out
}

fn write(path: &Path, text: &str) -> Result<(), ExperimentError> {
    std::fs::write(path, text).map_err(ExperimentError::io(format!("writing {}", path.display())))
}

/// Writes `latency.json`, `summary.csv`, `samples.csv` and a plot per pair
/// (`plots/<from>-<to>.png`: histogram and CDF) into `dir`, and returns their paths.
pub fn write_files(report: &LatencyReport, dir: &Path) -> Result<Vec<PathBuf>, ExperimentError> {
    let plots = dir.join("plots");
    std::fs::create_dir_all(&plots)
        .map_err(ExperimentError::io(format!("creating {}", plots.display())))?;
    let json = serde_json::to_string_pretty(report)
        .map_err(|e| ExperimentError::Invalid(format!("serializing the report: {e}")))?;
    let mut paths = Vec::new();
    for (name, text) in [
        ("latency.json", json + "\n"),
        ("summary.csv", csv_summary(report)),
        ("samples.csv", csv_samples(report)),
    ] {
        let path = dir.join(name);
        write(&path, &text)?;
        paths.push(path);
    }
    for p in &report.pairs {
        let path = plots.join(super::plot::file_name(p));
        super::plot::pair_png(report, p, &path)?;
        paths.push(path);
    }
    Ok(paths)
}

//! What a scenario did to the demonstration: its schedule, the harness's counters, and the
//! commands and final poses compared with the same run (same seed) without it.

use hetcomm::config::scenario::{FaultEffect, Scenario};
use hetcomm::harness::scenario::ScenarioRun;
use hetcomm::HarnessStats;
use hetcomm_sim::report::plot::Band;
use hetcomm_sim::report::CommandKind;

use super::DemoReport;

/// The example scenario shipped with the demonstration: Tango's radio link to Charlie is cut
/// for 3 s while Charlie forwards the "straight" command of t = 5 s.
pub const TANGO_CUT: &str = include_str!("scenario-tango-cut.toml");

/// The schedule, each system's harness counters (systems the harness touched), and what
/// became of each injection.
pub fn report_lines(
    sc: &Scenario,
    run: &ScenarioRun,
    stats: &[(String, HarnessStats)],
) -> Vec<String> {
    let mut lines = vec![format!("Scenario {}:", sc.origin)];
    lines.extend(sc.summary_lines().into_iter().map(|l| format!("  {l}")));
    for (name, s) in stats {
        if *s == HarnessStats::default() {
            continue;
        }
        lines.push(format!(
            "  {name}: frames cut {} / held {} by faults; taps saw {}, dropped {}, delayed {}, duplicated {}, replaced {}, injected {}",
            s.fault_dropped, s.fault_delayed, s.tapped, s.dropped, s.delayed, s.duplicated, s.replaced, s.injected
        ));
    }
    lines.extend(
        run.injection_report()
            .into_iter()
            .map(|l| format!("  inject {l}")),
    );
    lines
}

/// The intervals in which the scenario cuts systems off (its partitions and silences), as
/// bands for the plots: `offset_s` is when the scenario started, in seconds of the
/// demonstration's time axis.
pub fn bands(sc: &Scenario, offset_s: f64) -> Vec<Band> {
    let mut bands: Vec<Band> = sc
        .faults
        .iter()
        .filter(|f| f.effect == FaultEffect::Cut)
        .map(|f| {
            // The pairs both ways between the two sides; a silence's system is in every one.
            let mut pairs: Vec<(&str, &str)> = f
                .pairs
                .iter()
                .map(|(a, b)| (a.min(b).as_str(), a.max(b).as_str()))
                .collect();
            pairs.sort_unstable();
            pairs.dedup();
            let who = match (f.kind, pairs.as_slice()) {
                ("silence", [(a, b), ..]) => {
                    let silent = f.pairs.iter().all(|(x, y)| x == a || y == a);
                    (if silent { *a } else { *b }).to_string()
                }
                (_, [(a, b)]) => format!("{a}–{b}"),
                (_, many) => format!("{} pairs", many.len()),
            };
            Band {
                start_s: offset_s + f.window.start_s,
                end_s: offset_s + f.window.end_s,
                label: format!("{} {who}", f.kind),
            }
        })
        .collect();
    bands.sort_by(|a, b| a.start_s.total_cmp(&b.start_s));
    bands
}

/// Per follower, each command received with and without the scenario (time and code), and
/// how far each rover ended from where it ended without the scenario.
pub fn compare(with: &DemoReport, without: &DemoReport) -> String {
    let mut out = String::from("What the scenario changed (same seed, without → with):\n");
    let received = |r: &DemoReport, rover: &str| -> Vec<(f64, i64)> {
        r.commands
            .iter()
            .filter(|c| c.rover == rover && c.kind == CommandKind::Received)
            .map(|c| (c.t_s, c.code))
            .collect()
    };
    for rover in ["Charlie", "Tango"] {
        let (a, b) = (received(without, rover), received(with, rover));
        out.push_str(&format!(
            "  {rover} received {} → {} commands\n",
            a.len(),
            b.len()
        ));
        // Pair each command with the same one in the other run (order kept; a command the
        // cut lost has no partner).
        let show = |(t, c): &(f64, i64)| format!("code {c} at {t:6.2} s");
        let mut j = 0;
        for x in &a {
            match b.get(j) {
                Some(y) if y.1 == x.1 => {
                    j += 1;
                    // In milliseconds: the tables' resolution (at two decimals of a second a
                    // 1 ms shift printed as "-0.00 s").
                    let late = if (y.0 - x.0).abs() >= 0.0005 {
                        format!("  ({:+.0} ms)", (y.0 - x.0) * 1000.0)
                    } else {
                        String::new()
                    };
                    out.push_str(&format!("    {:<22} → {}{late}\n", show(x), show(y)));
                }
                _ => out.push_str(&format!("    {:<22} → never arrived\n", show(x))),
            }
        }
        for y in &b[j.min(b.len())..] {
            out.push_str(&format!("    {:<22} → {} (extra)\n", "—", show(y)));
        }
    }
    let last = |r: &DemoReport, rover: &str| {
        r.samples
            .iter()
            .rev()
            .find(|s| s.rover == rover)
            .map(|s| (s.pose.x, s.pose.y))
    };
    for rover in ["Alpha", "Charlie", "Tango"] {
        if let (Some(a), Some(b)) = (last(without, rover), last(with, rover)) {
            let d = ((a.0 - b.0).powi(2) + (a.1 - b.1).powi(2)).sqrt();
            out.push_str(&format!(
                "  {rover} ends at ({:.1}, {:.1}) instead of ({:.1}, {:.1}): {d:.1} units away\n",
                b.0, b.1, a.0, a.1
            ));
        }
    }
    out
}

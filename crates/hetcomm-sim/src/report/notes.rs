//! A short note on how a run's figures differ from the thesis's Tables 9–15, and why.
//!
//! The demonstration reproduces the thesis's set-up (starting poses, the leader's plan, the
//! relay Alpha → Charlie → Tango) but not its numbers: times are elapsed seconds, speeds are
//! constant, the followers' delay comes from the control loop (in virtual time) or the
//! transports (in real time) rather than from Bluetooth retries, and the tables run two seconds longer. [`thesis_comparison`] says so with the
//! run's own figures (delays, rows, when each rover started turning), so the note stays true
//! for any seed or transport.

use super::{pair_receipts, records_of, whole_second, CommandKind, CommandRecord};
use crate::kinematics::Pose;
use crate::scenario::{Scenario, ALPHA, CHARLIE, TANGO};
use crate::schedule::Command;
use crate::world::PoseSample;

/// File name the demonstration writes the note to, beside its tables and plots.
pub const NOTES_FILE: &str = "NOTES.md";

/// How a run was made, as far as the note needs to know.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct RunFacts {
    /// The run followed the machine's clock instead of a simulated one.
    pub realtime: bool,
    /// Seconds between two control steps of the rovers (they act and poll once per step).
    pub control_period_s: f64,
}

/// Seconds from each of the leader's commands to `rover`'s receipt of it (paired by command,
/// [`pair_receipts`], so a command lost on the way is left out rather than pairing the next
/// receipt with it): (min, max), or `None` if the rover received none of them.
fn delay_range(records: &[CommandRecord], rover: &str) -> Option<(f64, f64)> {
    let sent = records_of(records, ALPHA, CommandKind::Sent);
    let got = records_of(records, rover, CommandKind::Received);
    let (paired, _) = pair_receipts(&sent, &got);
    let delays: Vec<f64> = sent
        .iter()
        .zip(&paired)
        .filter_map(|(s, g)| Some(g.as_ref()?.t_s - s.t_s))
        .filter(|d| d.is_finite())
        .collect();
    let lo = delays.iter().copied().reduce(f64::min)?;
    let hi = delays.iter().copied().reduce(f64::max)?;
    Some((lo, hi))
}

/// Whole seconds with a sample of `rover`: (first, last, how many are missing in between).
fn seconds_of(samples: &[PoseSample], rover: &str) -> Option<(i64, i64, usize)> {
    let mut secs: Vec<i64> = samples
        .iter()
        .filter(|s| s.rover == rover)
        .filter_map(|s| whole_second(s.t_s))
        .collect();
    secs.sort_unstable();
    secs.dedup();
    let (first, last) = (*secs.first()?, *secs.last()?);
    let span = usize::try_from(last - first + 1).unwrap_or(0);
    Some((first, last, span.saturating_sub(secs.len())))
}

/// The time of the last sample before `rover`'s heading first changes: when it began its
/// first turn, to the resolution of the pose log.
fn first_turn(samples: &[PoseSample], rover: &str) -> Option<f64> {
    let mut mine: Vec<&PoseSample> = samples.iter().filter(|s| s.rover == rover).collect();
    mine.sort_by(|a, b| a.t_s.total_cmp(&b.t_s));
    mine.windows(2)
        .find(|w| (w[1].pose.theta_deg - w[0].pose.theta_deg).abs() > 1e-9)
        .map(|w| w[0].t_s)
}

/// A delay range as "0.100 s" or "0.100–0.104 s".
fn fmt_range((lo, hi): (f64, f64)) -> String {
    let (a, b) = (super::fmt3(lo), super::fmt3(hi));
    if a == b {
        format!("{a} s")
    } else {
        format!("{a}–{b} s")
    }
}

/// A Markdown note of how and why this run's figures differ from the thesis's Tables 9–15:
/// elapsed seconds instead of wall-clock times, constant speeds, where the followers' delay
/// comes from, how many rows the tables have, and θ unwrapped in `theta.png`. Numbers that
/// depend on the run (delays, rows, missing seconds, when each rover started turning) are
/// measured from `records` and `samples`.
pub fn thesis_comparison(
    records: &[CommandRecord],
    samples: &[PoseSample],
    facts: &RunFacts,
) -> String {
    let scenario = Scenario::thesis();
    let mut out = String::from(
        "# How these figures differ from the thesis's (§5.1, Tables 9–15)\n\n\
         The set-up is the thesis's: starting poses (first rows of Tables 13–15), the \
         leader's plan (Fig. 25: turn left at 2 s, straight at 5 s, left at 8 s, straight at \
         10 s) and the relay Alpha → Charlie → Tango. The numbers are not, for these \
         reasons.\n\n",
    );

    // Time.
    out.push_str(
        "- **Time is elapsed seconds, not wall-clock time.** 0.000 is the thesis's \
         08:36:52, so Alpha's first command at 2.000 is its 08:36:54 (Table 9). ",
    );
    if facts.realtime {
        out.push_str(
            "This run followed this machine's clock, so its times vary a little from run \
             to run.\n",
        );
    } else {
        out.push_str(
            "This run used virtual time (a simulated clock): it takes milliseconds and gives \
             the same figures for the same seed.\n",
        );
    }

    // Speeds.
    let (l, r) = Command::Straight.wheels();
    let straight = scenario.drive.step(Pose::new(0.0, 0.0, 0.0), l, r, 1.0);
    let (l, r) = Command::TurnLeft.wheels();
    let pivot = scenario.drive.step(Pose::new(0.0, 0.0, 0.0), l, r, 1.0);
    out.push_str(&format!(
        "- **Speeds are constant.** A rover drives {} units/s straight and pivots at {}°/s \
         (the differential-drive model of hetcomm-sim, integrated on a fixed time grid). \
         The thesis's virtual environments moved a rover on each Wheels message (§5.1.2.4), \
         which the rovers sent once per loop iteration (Figs. 25–26), so speed followed how \
         fast the loops and links ran: Alpha covered 13.175 then 22.073 units in its first \
         two seconds and turned 12.45°, 48.80° and 86.89° in successive seconds (Table 13). \
         Positions and headings after the first row \
         therefore differ from the thesis's.\n",
        super::fmt3(straight.x.hypot(straight.y)),
        super::fmt3(pivot.theta_deg),
    ));

    // Follower delay.
    let delays: Vec<String> = [CHARLIE, TANGO]
        .iter()
        .filter_map(|rover| {
            delay_range(records, rover).map(|d| format!("{rover} {}", fmt_range(d)))
        })
        .collect();
    out.push_str(if facts.realtime {
        "- **The followers' delay is this machine's transport latency, not radio retries.** "
    } else {
        "- **The followers' delay comes from the control loop, not from radio retries.** "
    });
    if delays.is_empty() {
        out.push_str("No follower's received commands were recorded in this run. ");
    } else {
        out.push_str(&format!(
            "From Alpha's send to a follower's receipt: {} (thesis: Charlie in the same \
             second, Tango 0 to 2 s later, Tables 10–12). ",
            delays.join(", ")
        ));
    }
    if facts.realtime {
        out.push_str(&format!(
            "Every rover reads its messages once per {} s control step; the tables record \
             when a message arrived, not when it was read.",
            super::fmt_fixed(facts.control_period_s, 1)
        ));
    } else {
        out.push_str(&format!(
            "Every rover acts once per {p} s control step, and the simulator delivers a \
             message between steps, so Charlie reads a command one step after it arrived and \
             forwards it then: Tango receives it one step ({p} s) plus the B link's latency \
             after Alpha sent it. Charlie's times equal Alpha's because the tables record \
             when a message arrived, not when it was read.",
            p = super::fmt_fixed(facts.control_period_s, 1)
        ));
    }
    let turns: Vec<String> = [ALPHA, CHARLIE, TANGO]
        .iter()
        .filter_map(|rover| {
            first_turn(samples, rover).map(|t| format!("{rover} at {} s", super::fmt_fixed(t, 1)))
        })
        .collect();
    if !turns.is_empty() {
        out.push_str(&format!(
            " The rovers began their first turn: {}.",
            turns.join(", ")
        ));
    }
    out.push('\n');

    // Rows.
    let thesis_last = scenario.schedule.end_s();
    let rows: Vec<(&str, (i64, i64, usize))> = [ALPHA, CHARLIE, TANGO]
        .iter()
        .filter_map(|rover| seconds_of(samples, rover).map(|s| (*rover, s)))
        .collect();
    out.push_str("- **The location tables have more rows.** ");
    // Rovers with the same rows share one entry: "Alpha, Charlie, Tango: 16 rows (0 to 15 s)".
    let mut groups: Vec<(String, Vec<&str>)> = Vec::new();
    for (rover, (first, last, _)) in &rows {
        let span = format!("{} rows ({first} to {last} s)", last - first + 1);
        match groups.iter_mut().find(|(s, _)| *s == span) {
            Some((_, names)) => names.push(rover),
            None => groups.push((span, vec![rover])),
        }
    }
    let spans: Vec<String> = groups
        .iter()
        .map(|(span, names)| format!("{}: {span}", names.join(", ")))
        .collect();
    if spans.is_empty() {
        out.push_str("This run logged no poses. ");
    } else {
        out.push_str(&format!("Rows per rover here: {}. ", spans.join("; ")));
    }
    out.push_str(&format!(
        "The thesis's tables stop at 08:37:05 ({} s, {} rows); this run goes on {} s past \
         the end of the leader's plan at that time. ",
        super::fmt_fixed(thesis_last, 0),
        thesis_last as i64 + 1,
        rows.iter()
            .map(|(_, (_, last, _))| *last)
            .max()
            .map_or("0".to_string(), |l| super::fmt_fixed(
                l as f64 - thesis_last,
                0
            )),
    ));
    let missing: usize = rows.iter().map(|(_, (_, _, m))| m).sum();
    if missing == 0 {
        out.push_str("No second is missing here");
    } else {
        out.push_str(&format!("{missing} second(s) have no data here"));
    }
    out.push_str(
        " (the thesis's Table 14 has no Charlie data at 08:36:55 and 08:37:03, which it \
         puts down to Bluetooth retransmissions holding up Charlie's Wheels messages; the \
         virtual environment here logs every rover at 10 Hz from its own model, whatever \
         the links do).\n",
    );

    // Headings.
    out.push_str(
        "- **θ in theta.png is unwrapped.** The tables and CSV files keep θ in [0, 360) as \
         the thesis does; the plot lets it count on past 360° so that a turn across \
         0°/360° does not draw a jump.\n",
    );
    out
}

#[cfg(test)]
mod tests {
    use super::*;

    fn run() -> (Vec<CommandRecord>, Vec<PoseSample>) {
        let run = Scenario::thesis()
            .run_open_loop(&[(CHARLIE, 0.0), (TANGO, 0.5)])
            .unwrap();
        (run.commands, run.samples)
    }

    #[test]
    fn note_states_the_run_s_own_figures() {
        let (records, samples) = run();
        let facts = RunFacts {
            realtime: false,
            control_period_s: 0.1,
        };
        let note = thesis_comparison(&records, &samples, &facts);
        assert!(note.starts_with("# How these figures differ"), "{note}");
        for expected in [
            "08:36:52",
            "10.000 units/s straight and pivots at 57.296°/s",
            "Charlie 0.000 s, Tango 0.500 s",
            "one step (0.1 s)",
            "Alpha at 2.0 s, Charlie at 2.0 s, Tango at 2.5 s",
            "Alpha, Charlie, Tango: 14 rows (0 to 13 s)",
            "(13 s, 14 rows); this run goes on 0 s",
            "No second is missing",
            "virtual time",
            "unwrapped",
        ] {
            assert!(note.contains(expected), "missing {expected:?} in:\n{note}");
        }
        // One bullet per difference, plain lines otherwise.
        assert_eq!(note.lines().filter(|l| l.starts_with("- **")).count(), 5);
    }

    #[test]
    fn note_counts_missing_seconds_and_real_time() {
        let (records, mut samples) = run();
        samples.retain(|s| !(s.rover == CHARLIE && (2.5..3.5).contains(&s.t_s)));
        let facts = RunFacts {
            realtime: true,
            control_period_s: 0.1,
        };
        let note = thesis_comparison(&records, &samples, &facts);
        assert!(note.contains("1 second(s) have no data here"), "{note}");
        assert!(
            note.contains("Alpha, Charlie, Tango: 14 rows (0 to 13 s)"),
            "{note}"
        );
        assert!(note.contains("machine's clock"), "{note}");
        assert!(note.contains("transport latency"), "{note}");
        assert!(!note.contains("virtual time"), "{note}");
        let empty = thesis_comparison(&[], &[], &facts);
        assert!(empty.contains("No follower's received commands were recorded"));
        assert!(empty.contains("This run logged no poses."));
    }
}

//! The demonstration's reporting: command tables (Tables 9–12), location tables
//! (Tables 13–15), CSV files, and the Appendix A plots (see [`plot`]).
//!
//! Each table's title starts with the number of the thesis's table it corresponds to
//! ("Table 9: Alpha command data", see [`thesis_command_table`], [`THESIS_TIMING_TABLE`] and
//! [`thesis_location_table`]); tables of other rovers carry no number.
//!
//! Times are simulated seconds from the start of the scenario (the thesis's 08:36:52 is
//! 0.000) and are printed with three decimals. Every text output is plain ASCII except
//! the en dash in command labels ("1 – Turn Left", as in the thesis), has no trailing
//! spaces, ends each line with `\n`, and depends only on its input, so snapshots can be
//! compared byte for byte.

pub mod notes;
pub mod plot;
pub mod thesis;

use crate::scenario::{ALPHA, CHARLIE, TANGO};
use crate::schedule::Command;
use crate::world::PoseSample;
use std::io::{self, Write};
use std::path::{Path, PathBuf};

/// Whether a command record is the leader sending a command or a rover receiving one.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Hash, PartialOrd, Ord)]
pub enum CommandKind {
    /// The rover sent (issued) the command, as in Table 9.
    Sent,
    /// The rover received the command, as in Tables 10–11.
    Received,
}

impl CommandKind {
    /// "Sent" or "Received", as in the thesis's column headers.
    pub fn name(self) -> &'static str {
        match self {
            CommandKind::Sent => "Sent",
            CommandKind::Received => "Received",
        }
    }
}

/// One time-stamped command event at one rover.
#[derive(Debug, Clone, PartialEq)]
pub struct CommandRecord {
    /// The rover that sent or received the command.
    pub rover: String,
    /// Simulated time in seconds from the start of the scenario.
    pub t_s: f64,
    /// The command's wire code (0 straight, 1 turn left, 2 stop; others are shown as unknown).
    pub code: i64,
    /// Whether the command was sent or received.
    pub kind: CommandKind,
}

impl CommandRecord {
    /// Builds a record.
    pub fn new(rover: &str, t_s: f64, code: i64, kind: CommandKind) -> Self {
        CommandRecord {
            rover: rover.to_string(),
            t_s,
            code,
            kind,
        }
    }
}

/// The table label for a wire code: "1 – Turn Left", "0 – Go Straight", "2 – Stop", or
/// "7 – Unknown" for a code the thesis does not define.
pub fn command_label(code: i64) -> String {
    match Command::from_code(code) {
        Some(c) => c.label(),
        None => format!("{code} – Unknown"),
    }
}

/// The Table 12 column header for a wire code, e.g. "Left Turn Command".
pub fn command_column_name(code: i64) -> String {
    match Command::from_code(code) {
        Some(Command::TurnLeft) => "Left Turn Command".to_string(),
        Some(Command::Straight) => "Straight Command".to_string(),
        Some(Command::Stop) => "Stop Command".to_string(),
        None => format!("Command {code}"),
    }
}

/// The number of the thesis's table that lists `rover`'s commands of this `kind`: Alpha's sent
/// commands are Table 9, Charlie's received ones Table 10, Tango's Table 11; anything else
/// has no counterpart in the thesis.
///
/// ```
/// use hetcomm_sim::report::{thesis_command_table, CommandKind};
/// assert_eq!(thesis_command_table("Tango", CommandKind::Received), Some(11));
/// assert_eq!(thesis_command_table("Tango", CommandKind::Sent), None);
/// ```
pub fn thesis_command_table(rover: &str, kind: CommandKind) -> Option<u32> {
    match (rover, kind) {
        (ALPHA, CommandKind::Sent) => Some(9),
        (CHARLIE, CommandKind::Received) => Some(10),
        (TANGO, CommandKind::Received) => Some(11),
        _ => None,
    }
}

/// The number of the thesis's command timing table (Table 12), used by
/// [`command_timing_matrix`] when the leader is Alpha, as in the thesis.
pub const THESIS_TIMING_TABLE: u32 = 12;

/// The number of the thesis's location table for `rover`: Alpha 13, Charlie 14, Tango 15.
pub fn thesis_location_table(rover: &str) -> Option<u32> {
    match rover {
        ALPHA => Some(13),
        CHARLIE => Some(14),
        TANGO => Some(15),
        _ => None,
    }
}

/// A table title, prefixed with "Table N: " when the thesis has a table `N` for it.
fn numbered(number: Option<u32>, title: &str) -> String {
    match number {
        Some(n) => format!("Table {n}: {title}"),
        None => title.to_string(),
    }
}

/// Formats a number with three decimals, printing negative zero (and values that round to
/// it) as `0.000` so that snapshots do not flip on the sign of a rounding error. Non-finite
/// values print as `nan`, `inf` or `-inf`.
pub fn fmt3(v: f64) -> String {
    fmt_fixed(v, 3)
}

fn fmt_fixed(v: f64, decimals: usize) -> String {
    if v.is_nan() {
        return "nan".to_string();
    }
    if v.is_infinite() {
        return if v > 0.0 { "inf" } else { "-inf" }.to_string();
    }
    let s = format!("{v:.decimals$}");
    if s.starts_with('-') && s[1..].chars().all(|c| c == '0' || c == '.') {
        s[1..].to_string()
    } else {
        s
    }
}

/// Formats a heading like [`fmt3`], but shows a value that rounds up to 360.000 as 0.000,
/// since headings live in `[0, 360)`.
pub(crate) fn fmt_theta(deg: f64) -> String {
    let s = fmt3(deg);
    if s == "360.000" {
        "0.000".to_string()
    } else {
        s
    }
}

/// Rover names in order of first appearance.
fn rovers_in_order<'a>(names: impl Iterator<Item = &'a str>) -> Vec<&'a str> {
    let mut out: Vec<&str> = Vec::new();
    for n in names {
        if !out.contains(&n) {
            out.push(n);
        }
    }
    out
}

/// Lays out rows as aligned columns; `right[i]` right-aligns column i. Trailing spaces are
/// trimmed so an empty last cell does not leave invisible characters behind.
pub(crate) fn layout(rows: &[Vec<String>], right: &[bool]) -> String {
    let ncol = rows.iter().map(Vec::len).max().unwrap_or(0);
    let mut widths = vec![0usize; ncol];
    for row in rows {
        for (i, cell) in row.iter().enumerate() {
            widths[i] = widths[i].max(cell.chars().count());
        }
    }
    let mut out = String::new();
    for row in rows {
        let mut line = String::new();
        for (i, cell) in row.iter().enumerate() {
            if i > 0 {
                line.push_str("  ");
            }
            let w = widths[i];
            if right.get(i).copied().unwrap_or(false) {
                line.push_str(&format!("{cell:>w$}"));
            } else {
                line.push_str(&format!("{cell:<w$}"));
            }
        }
        out.push_str(line.trim_end());
        out.push('\n');
    }
    out
}

/// The records of one rover and kind, sorted by time (stable for equal times).
pub(crate) fn records_of<'a>(
    records: &'a [CommandRecord],
    rover: &str,
    kind: CommandKind,
) -> Vec<&'a CommandRecord> {
    let mut v: Vec<&CommandRecord> = records
        .iter()
        .filter(|r| r.rover == rover && r.kind == kind)
        .collect();
    v.sort_by(|a, b| a.t_s.total_cmp(&b.t_s));
    v
}

/// One command table in the shape of Tables 9–11 for a rover and kind: a title line
/// (numbered as in the thesis, see [`thesis_command_table`]), a header, and one row per
/// record (time, labelled command), sorted by time.
///
/// ```
/// use hetcomm_sim::report::{command_table, CommandKind, CommandRecord};
/// let recs = [CommandRecord::new("Alpha", 2.0, 1, CommandKind::Sent)];
/// assert_eq!(
///     command_table(&recs, "Alpha", CommandKind::Sent),
///     "Table 9: Alpha command data\nTime (s)  Command (Sent)\n   2.000  1 – Turn Left\n"
/// );
/// ```
pub fn command_table(records: &[CommandRecord], rover: &str, kind: CommandKind) -> String {
    let mut rows = vec![vec![
        "Time (s)".to_string(),
        format!("Command ({})", kind.name()),
    ]];
    for r in records_of(records, rover, kind) {
        rows.push(vec![fmt3(r.t_s), command_label(r.code)]);
    }
    format!(
        "{}\n{}",
        numbered(
            thesis_command_table(rover, kind),
            &format!("{rover} command data")
        ),
        layout(&rows, &[true, false])
    )
}

/// All command tables: for each rover in order of first appearance, its Sent table (if it
/// sent anything) then its Received table (if it received anything), separated by a blank
/// line.
pub fn command_tables(records: &[CommandRecord]) -> String {
    let mut parts = Vec::new();
    for rover in rovers_in_order(records.iter().map(|r| r.rover.as_str())) {
        for kind in [CommandKind::Sent, CommandKind::Received] {
            if records.iter().any(|r| r.rover == rover && r.kind == kind) {
                parts.push(command_table(records, rover, kind));
            }
        }
    }
    parts.join("\n")
}

/// Pairs a follower's receipts with the leader's commands, by command rather than by row: each
/// receipt goes to the latest command with its code that was sent at or before it and comes
/// after the command the previous receipt went to. Returns, per command, the receipt paired
/// with it (None: it never arrived), and the receipts that pair with no command.
///
/// Receipts carry only a code (a relaying rover sends a message of its own), so a command is
/// told from an earlier one of the same code by time alone: the latest fits a follower that
/// gets each command once, soon after it was sent.
pub(crate) fn pair_receipts<'a>(
    sent: &[&'a CommandRecord],
    got: &[&'a CommandRecord],
) -> (Vec<Option<&'a CommandRecord>>, Vec<&'a CommandRecord>) {
    let mut paired = vec![None; sent.len()];
    let mut unpaired = Vec::new();
    let mut next = 0;
    for &g in got {
        let found = (next..sent.len())
            .rev()
            .find(|&j| sent[j].code == g.code && sent[j].t_s <= g.t_s + 1e-9);
        match found {
            Some(j) => {
                paired[j] = Some(g);
                next = j + 1;
            }
            None => unpaired.push(g),
        }
    }
    (paired, unpaired)
}

/// The command timing matrix in the shape of Table 12.
///
/// Rows are rovers in order of first appearance. Columns are the commands of the reference
/// rover (the first with Sent records: the leader; else the first rover), named after their
/// codes; its row holds when it sent each. A follower's receipts are paired with those
/// commands ([`pair_receipts`]): a cell holds when the rover received that command, `-` that
/// it never did. A receipt that pairs with no command (a code the leader had not sent by
/// then) goes in a column of its own after the commands, as `time [code]`, with a key under
/// the table.
pub fn command_timing_matrix(records: &[CommandRecord]) -> String {
    let rovers = rovers_in_order(records.iter().map(|r| r.rover.as_str()));
    let reference_rover = rovers
        .iter()
        .copied()
        .find(|r| {
            records
                .iter()
                .any(|c| c.rover == *r && c.kind == CommandKind::Sent)
        })
        .or_else(|| rovers.first().copied());
    let reference: Vec<&CommandRecord> = reference_rover
        .map(|r| {
            let sent = records_of(records, r, CommandKind::Sent);
            if sent.is_empty() {
                records_of(records, r, CommandKind::Received)
            } else {
                sent
            }
        })
        .unwrap_or_default();
    // Per rover: a cell per command, then its unpaired receipts.
    let cells: Vec<(Vec<Option<&CommandRecord>>, Vec<&CommandRecord>)> = rovers
        .iter()
        .map(|rover| {
            if Some(*rover) == reference_rover {
                return (reference.iter().map(|&c| Some(c)).collect(), Vec::new());
            }
            let got = records_of(records, rover, CommandKind::Received);
            if got.is_empty() {
                // A second sender: its own commands, by row.
                let sent = records_of(records, rover, CommandKind::Sent);
                return (
                    (0..reference.len()).map(|i| sent.get(i).copied()).collect(),
                    sent.get(reference.len()..).unwrap_or_default().to_vec(),
                );
            }
            pair_receipts(&reference, &got)
        })
        .collect();
    let extra = cells.iter().map(|(_, u)| u.len()).max().unwrap_or(0);
    let mut header = vec![String::new()];
    for c in &reference {
        header.push(command_column_name(c.code));
    }
    for i in 0..extra {
        header.push(format!("Command {}", reference.len() + i + 1));
    }
    let mut rows = vec![header];
    for (rover, (paired, unpaired)) in rovers.iter().zip(&cells) {
        let mut row = vec![rover.to_string()];
        for c in paired {
            row.push(c.map_or_else(|| "-".to_string(), |c| fmt3(c.t_s)));
        }
        for i in 0..extra {
            row.push(match unpaired.get(i) {
                Some(c) => format!("{} [{}]", fmt3(c.t_s), c.code),
                None => "-".to_string(),
            });
        }
        rows.push(row);
    }
    let mut right = vec![false];
    right.extend(std::iter::repeat(true).take(reference.len() + extra));
    let number = (reference_rover == Some(ALPHA)).then_some(THESIS_TIMING_TABLE);
    let key = match extra {
        0 => String::new(),
        _ => "[c]: received code c, matching no command sent before it\n".to_string(),
    };
    format!(
        "{}\n{}{key}",
        numbered(number, "Command timing (s)"),
        layout(&rows, &right)
    )
}

/// True when `t` is within a microsecond of a whole second.
pub(crate) fn whole_second(t: f64) -> Option<i64> {
    let r = t.round();
    ((t - r).abs() < 1e-6 && r.abs() < 1e15).then_some(r as i64)
}

/// One location table in the shape of Tables 13–15 for a rover (its title numbered as in
/// the thesis, see [`thesis_location_table`]): one row per simulated
/// second (time, X, Y, Theta with three decimals), from its first to its last whole-second
/// sample. A second with no sample gets a row with the time only, as the thesis's Table 14
/// shows Charlie's missing seconds.
pub fn pose_table(samples: &[PoseSample], rover: &str) -> String {
    let mut rows = vec![vec![
        "Time (s)".to_string(),
        "X".to_string(),
        "Y".to_string(),
        "Theta".to_string(),
    ]];
    let mut by_second: Vec<(i64, &PoseSample)> = Vec::new();
    for s in samples.iter().filter(|s| s.rover == rover) {
        if let Some(sec) = whole_second(s.t_s) {
            // Keep the first sample of each second if a log repeats one.
            if !by_second.iter().any(|(k, _)| *k == sec) {
                by_second.push((sec, s));
            }
        }
    }
    by_second.sort_by_key(|(k, _)| *k);
    if let (Some(&(first, _)), Some(&(last, _))) = (by_second.first(), by_second.last()) {
        for sec in first..=last {
            match by_second.iter().find(|(k, _)| *k == sec) {
                Some((_, s)) => rows.push(vec![
                    fmt3(sec as f64),
                    fmt3(s.pose.x),
                    fmt3(s.pose.y),
                    fmt_theta(s.pose.theta_deg),
                ]),
                None => rows.push(vec![fmt3(sec as f64)]),
            }
        }
    }
    format!(
        "{}\n{}",
        numbered(
            thesis_location_table(rover),
            &format!("{rover} location data")
        ),
        layout(&rows, &[true, true, true, true])
    )
}

/// All location tables, one per rover in order of first appearance, separated by a blank line.
pub fn pose_tables(samples: &[PoseSample]) -> String {
    rovers_in_order(samples.iter().map(|s| s.rover.as_str()))
        .into_iter()
        .map(|r| pose_table(samples, r))
        .collect::<Vec<_>>()
        .join("\n")
}

/// Quotes a CSV field when it contains a comma, quote or line break (RFC 4180).
fn csv_field(s: &str) -> String {
    if s.contains([',', '"', '\n', '\r']) {
        format!("\"{}\"", s.replace('"', "\"\""))
    } else {
        s.to_string()
    }
}

/// Writes command records as CSV, in the given order, with the header
/// `t_s,rover,kind,code,command` (time with six decimals, kind `sent`/`received`).
pub fn write_commands_csv<W: Write>(mut w: W, records: &[CommandRecord]) -> io::Result<()> {
    writeln!(w, "t_s,rover,kind,code,command")?;
    for r in records {
        writeln!(
            w,
            "{},{},{},{},{}",
            fmt_fixed(r.t_s, 6),
            csv_field(&r.rover),
            r.kind.name().to_ascii_lowercase(),
            r.code,
            csv_field(&command_label(r.code))
        )?;
    }
    Ok(())
}

/// Writes pose samples as CSV, in the given order, with the header
/// `t_s,rover,x,y,theta_deg` (six decimals for every number).
pub fn write_poses_csv<W: Write>(mut w: W, samples: &[PoseSample]) -> io::Result<()> {
    writeln!(w, "t_s,rover,x,y,theta_deg")?;
    for s in samples {
        writeln!(
            w,
            "{},{},{},{},{}",
            fmt_fixed(s.t_s, 6),
            csv_field(&s.rover),
            fmt_fixed(s.pose.x, 6),
            fmt_fixed(s.pose.y, 6),
            fmt_fixed(s.pose.theta_deg, 6)
        )?;
    }
    Ok(())
}

/// [`write_commands_csv`] into a string.
pub fn commands_csv(records: &[CommandRecord]) -> String {
    let mut buf = Vec::new();
    // Writing into a Vec cannot fail.
    let _ = write_commands_csv(&mut buf, records);
    String::from_utf8_lossy(&buf).into_owned()
}

/// [`write_poses_csv`] into a string.
pub fn poses_csv(samples: &[PoseSample]) -> String {
    let mut buf = Vec::new();
    let _ = write_poses_csv(&mut buf, samples);
    String::from_utf8_lossy(&buf).into_owned()
}

/// Writes the text report into `dir` (created if missing) and returns the paths written:
/// `commands.txt` (Tables 9–12), `locations.txt` (Tables 13–15), `commands.csv`,
/// `poses.csv`. Plots are separate: see [`plot::write_all`].
pub fn write_tables(
    dir: &Path,
    records: &[CommandRecord],
    samples: &[PoseSample],
) -> io::Result<Vec<PathBuf>> {
    std::fs::create_dir_all(dir)?;
    let mut written = Vec::new();
    let mut put = |name: &str, text: String| -> io::Result<()> {
        let path = dir.join(name);
        std::fs::write(&path, text)?;
        written.push(path);
        Ok(())
    };
    put(
        "commands.txt",
        format!(
            "{}\n{}",
            command_tables(records),
            command_timing_matrix(records)
        ),
    )?;
    put("locations.txt", pose_tables(samples))?;
    put("commands.csv", commands_csv(records))?;
    put("poses.csv", poses_csv(samples))?;
    Ok(written)
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::kinematics::Pose;

    fn records() -> Vec<CommandRecord> {
        use CommandKind::*;
        vec![
            CommandRecord::new("Alpha", 2.0, 1, Sent),
            CommandRecord::new("Charlie", 2.0, 1, Received),
            CommandRecord::new("Alpha", 5.0, 0, Sent),
            CommandRecord::new("Charlie", 5.0, 0, Received),
            CommandRecord::new("Tango", 4.0, 1, Received),
            CommandRecord::new("Tango", 5.25, 2, Received),
            CommandRecord::new("Alpha", 10.0, 2, Sent),
        ]
    }

    #[test]
    fn command_tables_snapshot() {
        let expected = "\
Table 9: Alpha command data
Time (s)  Command (Sent)
   2.000  1 – Turn Left
   5.000  0 – Go Straight
  10.000  2 – Stop

Table 10: Charlie command data
Time (s)  Command (Received)
   2.000  1 – Turn Left
   5.000  0 – Go Straight

Table 11: Tango command data
Time (s)  Command (Received)
   4.000  1 – Turn Left
   5.250  2 – Stop
";
        assert_eq!(command_tables(&records()), expected);
    }

    #[test]
    fn titles_carry_the_thesis_table_numbers() {
        use CommandKind::*;
        let all = format!(
            "{}{}{}",
            command_tables(&records()),
            command_timing_matrix(&records()),
            pose_tables(&samples())
        );
        let titles: Vec<&str> = all.lines().filter(|l| l.starts_with("Table ")).collect();
        assert_eq!(
            titles,
            [
                "Table 9: Alpha command data",
                "Table 10: Charlie command data",
                "Table 11: Tango command data",
                "Table 12: Command timing (s)",
                "Table 13: Alpha location data",
                "Table 14: Charlie location data",
            ]
        );
        assert_eq!(thesis_location_table(TANGO), Some(15));
        // Tables with no counterpart in the thesis keep a plain title.
        let other = [
            CommandRecord::new("Bravo", 1.0, 0, Sent),
            CommandRecord::new("Tango", 1.0, 0, Sent),
        ];
        assert!(command_table(&other, "Bravo", Sent).starts_with("Bravo command data\n"));
        assert!(command_table(&other, "Tango", Sent).starts_with("Tango command data\n"));
        assert!(command_timing_matrix(&other).starts_with("Command timing (s)\n"));
    }

    #[test]
    fn timing_matrix_snapshot() {
        let expected = "\
Table 12: Command timing (s)
         Left Turn Command  Straight Command  Stop Command  Command 4
Alpha                2.000             5.000        10.000          -
Charlie              2.000             5.000             -          -
Tango                4.000                 -             -  5.250 [2]
[c]: received code c, matching no command sent before it
";
        assert_eq!(command_timing_matrix(&records()), expected);
        assert_eq!(command_timing_matrix(&[]), "Command timing (s)\n\n");
    }

    fn samples() -> Vec<PoseSample> {
        let s = |t_s, rover: &str, x, y, th| PoseSample {
            t_s,
            rover: rover.to_string(),
            pose: Pose::new(x, y, th),
        };
        vec![
            s(0.0, "Alpha", -190.494, -200.0, 0.0),
            s(0.0, "Charlie", 200.0, 5.73321, 90.0),
            s(0.5, "Alpha", -185.494, -200.0, 0.0),
            s(1.0, "Alpha", -180.494, -200.0, 0.0),
            s(1.0, "Charlie", 200.0, 15.73321, 90.0),
            s(2.0, "Alpha", -170.494, -0.0000001, 12.4502),
            s(3.0, "Charlie", 200.0, 25.0, 359.9999),
        ]
    }

    #[test]
    fn pose_tables_snapshot() {
        let expected = "\
Table 13: Alpha location data
Time (s)         X         Y   Theta
   0.000  -190.494  -200.000   0.000
   1.000  -180.494  -200.000   0.000
   2.000  -170.494     0.000  12.450

Table 14: Charlie location data
Time (s)        X       Y   Theta
   0.000  200.000   5.733  90.000
   1.000  200.000  15.733  90.000
   2.000
   3.000  200.000  25.000   0.000
";
        assert_eq!(pose_tables(&samples()), expected);
        assert_eq!(
            pose_table(&samples(), "Nobody"),
            "Nobody location data\nTime (s)  X  Y  Theta\n"
        );
    }

    #[test]
    fn csv_snapshots() {
        let expected = "\
t_s,rover,kind,code,command
2.000000,Alpha,sent,1,1 – Turn Left
2.000000,Charlie,received,1,1 – Turn Left
5.000000,Alpha,sent,0,0 – Go Straight
5.000000,Charlie,received,0,0 – Go Straight
4.000000,Tango,received,1,1 – Turn Left
5.250000,Tango,received,2,2 – Stop
10.000000,Alpha,sent,2,2 – Stop
";
        assert_eq!(commands_csv(&records()), expected);
        let expected = "\
t_s,rover,x,y,theta_deg
0.000000,Alpha,-190.494000,-200.000000,0.000000
0.000000,Charlie,200.000000,5.733210,90.000000
0.500000,Alpha,-185.494000,-200.000000,0.000000
1.000000,Alpha,-180.494000,-200.000000,0.000000
1.000000,Charlie,200.000000,15.733210,90.000000
2.000000,Alpha,-170.494000,0.000000,12.450200
3.000000,Charlie,200.000000,25.000000,359.999900
";
        assert_eq!(poses_csv(&samples()), expected);
        let odd = [CommandRecord::new(
            "a,\"b\"",
            f64::NAN,
            9,
            CommandKind::Sent,
        )];
        assert_eq!(
            commands_csv(&odd),
            "t_s,rover,kind,code,command\nnan,\"a,\"\"b\"\"\",sent,9,9 – Unknown\n"
        );
    }

    #[test]
    fn number_formatting() {
        assert_eq!(fmt3(2.0), "2.000");
        assert_eq!(fmt3(-0.0), "0.000");
        assert_eq!(fmt3(-0.0004), "0.000");
        assert_eq!(fmt3(-0.0005001), "-0.001");
        assert_eq!(fmt3(f64::INFINITY), "inf");
        assert_eq!(command_label(1), "1 – Turn Left");
        assert_eq!(command_label(-3), "-3 – Unknown");
        assert_eq!(command_column_name(5), "Command 5");
    }

    #[test]
    fn write_tables_writes_four_files() {
        let dir = std::env::temp_dir().join(format!("hetcomm-sim-tables-{}", std::process::id()));
        let paths = write_tables(&dir, &records(), &samples()).unwrap();
        assert_eq!(paths.len(), 4);
        let csv = std::fs::read_to_string(dir.join("commands.csv")).unwrap();
        assert_eq!(csv, commands_csv(&records()));
        let _ = std::fs::remove_dir_all(&dir);
    }
}

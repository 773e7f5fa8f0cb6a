//! The thesis's Tables 9–15 as published (§5.1), and this run's figures beside them.
//!
//! The thesis's clock read 08:36:52 when the demonstration began; its tables have whole
//! seconds. Here they are given both ways: elapsed seconds (0 = 08:36:52, the unit of this
//! run's tables) and the published clock time. Each table beside this run's ends with a line
//! on how and why they differ, worked out from the two sets of figures.

use super::{
    command_label, fmt3, fmt_theta, layout, pair_receipts, records_of, whole_second, CommandKind,
    CommandRecord,
};
use crate::scenario::{ALPHA, CHARLIE, TANGO};
use crate::world::PoseSample;

/// The thesis's clock at the start of the demonstration, seconds after midnight (08:36:52).
const START_CLOCK_S: i64 = 8 * 3600 + 36 * 60 + 52;

/// Tables 9–11: (rover, elapsed second, code, sent or received), as published.
const COMMANDS: [(&str, i64, i64, CommandKind); 12] = [
    (ALPHA, 2, 1, CommandKind::Sent),
    (ALPHA, 5, 0, CommandKind::Sent),
    (ALPHA, 8, 1, CommandKind::Sent),
    (ALPHA, 10, 0, CommandKind::Sent),
    (CHARLIE, 2, 1, CommandKind::Received),
    (CHARLIE, 5, 0, CommandKind::Received),
    (CHARLIE, 8, 1, CommandKind::Received),
    (CHARLIE, 10, 0, CommandKind::Received),
    (TANGO, 4, 1, CommandKind::Received),
    (TANGO, 5, 0, CommandKind::Received),
    (TANGO, 8, 1, CommandKind::Received),
    (TANGO, 12, 0, CommandKind::Received),
];

/// A row of Tables 13–15: elapsed second, then (x, y, θ), or None where the thesis has an
/// empty row.
type PoseRow = (i64, Option<(f64, f64, f64)>);

/// Table 13, as published.
const ALPHA_POSES: [PoseRow; 14] = [
    (0, Some((-190.494, -200.0, 0.0))),
    (1, Some((-177.319, -200.0, 0.0))),
    (2, Some((-155.246, -200.0, 0.005))),
    (3, Some((-155.246, -200.0, 12.4502))),
    (4, Some((-155.246, -200.0, 61.2503))),
    (5, Some((-155.26, -199.991, 148.145))),
    (6, Some((-157.6, -198.548, 148.145))),
    (7, Some((-168.346, -186.49, 148.145))),
    (8, Some((-179.959, -184.765, 148.225))),
    (9, Some((-179.959, -184.765, 192.221))),
    (10, Some((-179.979, -184.865, 259.261))),
    (11, Some((-181.371, -192.174, 259.261))),
    (12, Some((-183.719, -204.504, 259.261))),
    (13, Some((-186.126, -217.14, 259.261))),
];

/// Table 14, as published (no data at 08:36:55 and 08:37:03).
const CHARLIE_POSES: [PoseRow; 14] = [
    (0, Some((200.0, 5.73321, 90.0))),
    (1, Some((200.0, 15.7074, 90.0))),
    (2, Some((200.0, 32.7212, 90.005))),
    (3, None),
    (4, Some((200.0, 32.7212, 91.37))),
    (5, Some((199.999, 32.7223, 127.23))),
    (6, Some((199.252, 33.7033, 127.23))),
    (7, Some((191.85, 43.4176, 127.23))),
    (8, Some((185.704, 51.4844, 127.24))),
    (9, Some((185.704, 51.4844, 161.29))),
    (10, Some((185.703, 51.4835, 222.206))),
    (11, None),
    (12, Some((184.657, 50.5424, 222.206))),
    (13, Some((176.74, 43.3959, 222.206))),
];

/// Table 15, as published.
const TANGO_POSES: [PoseRow; 14] = [
    (0, Some((191.495, 60.0, 180.0))),
    (1, Some((186.906, 60.0, 180.0))),
    (2, Some((179.16, 60.0, 180.0))),
    (3, Some((174.36, 60.0, 180.0))),
    (4, Some((173.141, 60.0, 180.005))),
    (5, Some((168.589, 59.9996, 196.135))),
    (6, Some((164.879, 58.9251, 196.135))),
    (7, Some((159.99, 57.5111, 196.135))),
    (8, Some((158.474, 57.07, 196.14))),
    (9, Some((158.474, 57.07, 209.38))),
    (10, Some((158.474, 57.07, 226.901))),
    (11, Some((158.474, 57.07, 244.655))),
    (12, Some((158.482, 56.8882, 272.683))),
    (13, Some((158.736, 51.449, 272.683))),
];

/// The thesis's command records (Tables 9–11), in elapsed seconds.
pub fn published_commands() -> Vec<CommandRecord> {
    COMMANDS
        .iter()
        .map(|&(rover, t, code, kind)| CommandRecord::new(rover, t as f64, code, kind))
        .collect()
}

/// The thesis's location rows of `rover` (Tables 13–15), if it has a table.
fn published_poses(rover: &str) -> Option<&'static [PoseRow]> {
    match rover {
        ALPHA => Some(&ALPHA_POSES),
        CHARLIE => Some(&CHARLIE_POSES),
        TANGO => Some(&TANGO_POSES),
        _ => None,
    }
}

/// The thesis's clock time of an elapsed second ("08:36:54").
fn clock(t_s: f64) -> String {
    let s = START_CLOCK_S + t_s.round() as i64;
    format!("{:02}:{:02}:{:02}", s / 3600, s / 60 % 60, s % 60)
}

/// Per command of the leader, when `rover` got it (paired by command), for `records`.
fn receipts<'a>(records: &'a [CommandRecord], rover: &str) -> Vec<Option<&'a CommandRecord>> {
    let sent = records_of(records, ALPHA, CommandKind::Sent);
    if rover == ALPHA {
        return sent.into_iter().map(Some).collect();
    }
    pair_receipts(&sent, &records_of(records, rover, CommandKind::Received)).0
}

/// Delays from the leader's commands to `rover`'s receipts: (min, max, commands never got).
fn delays(records: &[CommandRecord], rover: &str) -> (Option<(f64, f64)>, usize) {
    let sent = records_of(records, ALPHA, CommandKind::Sent);
    let got = receipts(records, rover);
    let d: Vec<f64> = sent
        .iter()
        .zip(&got)
        .filter_map(|(s, g)| Some(g.as_ref()?.t_s - s.t_s))
        .collect();
    let lost = got.iter().filter(|g| g.is_none()).count();
    let range = d
        .iter()
        .copied()
        .reduce(f64::min)
        .zip(d.iter().copied().reduce(f64::max));
    (range, lost)
}

fn range_text((lo, hi): (f64, f64), decimals: usize) -> String {
    if (hi - lo).abs() < 1e-9 {
        format!("{lo:.decimals$} s")
    } else {
        format!("{lo:.decimals$}–{hi:.decimals$} s")
    }
}

/// A command table (9, 10 or 11) beside the thesis's: a row per command of the leader.
fn command_beside(number: u8, rover: &str, ours: &[CommandRecord]) -> String {
    let thesis = published_commands();
    let kind = if rover == ALPHA { "Sent" } else { "Received" };
    let mut rows = vec![vec![
        format!("Command ({kind})"),
        "here (s)".to_string(),
        "thesis (s)".to_string(),
        "thesis clock".to_string(),
    ]];
    let leader = records_of(&thesis, ALPHA, CommandKind::Sent);
    let (here, there) = (receipts(ours, rover), receipts(&thesis, rover));
    for (i, command) in leader.iter().enumerate() {
        let here = here.get(i).copied().flatten();
        let there = there.get(i).copied().flatten();
        rows.push(vec![
            command_label(command.code),
            here.map_or_else(|| "-".to_string(), |c| fmt3(c.t_s)),
            there.map_or_else(|| "-".to_string(), |c| fmt3(c.t_s)),
            there.map_or_else(|| "-".to_string(), |c| clock(c.t_s)),
        ]);
    }
    let why = if rover == ALPHA {
        let same = receipts(ours, ALPHA)
            .iter()
            .zip(&leader)
            .all(|(h, t)| h.is_some_and(|h| (h.t_s - t.t_s).abs() < 0.5));
        match same {
            true => {
                "Differences: none beyond the clock: the leader's plan is the thesis's (Fig. 25), \
                     and its commands fall on the same seconds."
                    .to_string()
            }
            false => "Differences: this run's leader did not follow the thesis's plan (a changed \
                      scenario or schedule)."
                .to_string(),
        }
    } else {
        let (h, h_lost) = delays(ours, rover);
        let (t, _) = delays(&thesis, rover);
        let here = match h {
            Some(r) => format!("{} after Alpha's send here", range_text(r, 3)),
            None => "never here".to_string(),
        };
        let lost = match h_lost {
            0 => String::new(),
            n => format!("; {n} of Alpha's commands never reached it here"),
        };
        let thesis = t.map_or_else(String::new, |r| {
            format!(", {} in the thesis", range_text(r, 0))
        });
        format!(
            "Differences: each command reached {rover} {here}{thesis}{lost}. Here a rover acts \
             once per 0.1 s control step and the relay adds one step per hop plus the link's \
             latency; the thesis's times are whole seconds of its clock, and its late receipts \
             came from radio retries and loop timing."
        )
    };
    format!(
        "Thesis Table {number} beside this run: {rover} command data (thesis clock 08:36:52 = 0 s)\n{}{why}\n",
        layout(&rows, &[false, true, true, true])
    )
}

/// Table 12 beside the thesis's: each cell "here / thesis" (seconds).
fn timing_beside(ours: &[CommandRecord]) -> String {
    let thesis = published_commands();
    let leader = records_of(&thesis, ALPHA, CommandKind::Sent);
    let mut header = vec![String::new()];
    header.extend(leader.iter().map(|c| super::command_column_name(c.code)));
    let mut rows = vec![header];
    for rover in [ALPHA, CHARLIE, TANGO] {
        let (here, there) = (receipts(ours, rover), receipts(&thesis, rover));
        let mut row = vec![rover.to_string()];
        for i in 0..leader.len() {
            let show =
                |c: Option<&CommandRecord>| c.map_or_else(|| "-".to_string(), |c| fmt3(c.t_s));
            row.push(format!(
                "{} / {}",
                show(here.get(i).copied().flatten()),
                show(there.get(i).copied().flatten())
            ));
        }
        rows.push(row);
    }
    let mut right = vec![false];
    right.extend(std::iter::repeat(true).take(leader.len()));
    format!(
        "Thesis Table 12 beside this run: command timing, here / thesis (s)\n{}\
         Differences: as in Tables 10 and 11 above; the thesis's Tango got the first Turn Left \
         2 s after Alpha sent it and the last Straight 2 s after, here every command a \
         fraction of a second after.\n",
        layout(&rows, &right)
    )
}

/// A location table (13, 14 or 15) beside the thesis's: a row per whole second.
fn pose_beside(number: u8, rover: &str, samples: &[PoseSample]) -> String {
    let Some(published) = published_poses(rover) else {
        return String::new();
    };
    let ours: Vec<(i64, &PoseSample)> = samples
        .iter()
        .filter(|s| s.rover == rover)
        .filter_map(|s| Some((whole_second(s.t_s)?, s)))
        .collect();
    let here_at = |sec: i64| ours.iter().find(|(k, _)| *k == sec).map(|(_, s)| *s);
    let last = published
        .last()
        .map(|r| r.0)
        .max(ours.iter().map(|(k, _)| *k).max())
        .unwrap_or(0);
    let mut rows = vec![[
        "Time (s)",
        "X here",
        "Y here",
        "Theta here",
        "X thesis",
        "Y thesis",
        "Theta thesis",
    ]
    .map(String::from)
    .to_vec()];
    let (mut dxy, mut dtheta) = (0.0f64, 0.0f64);
    for sec in 0..=last {
        let mut row = vec![fmt3(sec as f64)];
        let here = here_at(sec);
        match here {
            Some(s) => row.extend([fmt3(s.pose.x), fmt3(s.pose.y), fmt_theta(s.pose.theta_deg)]),
            None => row.extend(["-", "-", "-"].map(String::from)),
        }
        let there = published.iter().find(|r| r.0 == sec).and_then(|r| r.1);
        match there {
            Some((x, y, t)) => row.extend([fmt3(x), fmt3(y), fmt_theta(t)]),
            None => row.extend(["-", "-", "-"].map(String::from)),
        }
        if let (Some(s), Some((x, y, t))) = (here, there) {
            dxy = dxy.max((s.pose.x - x).hypot(s.pose.y - y));
            let d = (s.pose.theta_deg - t).rem_euclid(360.0);
            dtheta = dtheta.max(d.min(360.0 - d));
        }
        rows.push(row);
    }
    let gaps: Vec<String> = published
        .iter()
        .filter(|r| r.1.is_none())
        .map(|r| clock(r.0 as f64))
        .collect();
    let gap_note = match gaps.is_empty() {
        true => String::new(),
        false => format!(
            " The thesis has no row at {} (it puts this down to Bluetooth retransmissions \
             holding up {rover}'s Wheels messages); here the virtual environment logs every \
             second from its own model.",
            gaps.join(" and ")
        ),
    };
    format!(
        "Thesis Table {number} beside this run: {rover} location data\n{}\
         Differences: the first row is the thesis's starting pose; after it the positions are \
         up to {dxy:.1} units apart and the headings up to {dtheta:.1}° apart. Here a rover \
         drives at constant speeds (10 units/s, 57.3°/s); the thesis's moved a step per Wheels \
         message, so its speed followed how fast the loops and links ran. This run goes on to \
         {last} s; the thesis's tables stop at 08:37:05 (13 s).{gap_note}\n",
        layout(&rows, &[true; 7])
    )
}

/// The thesis's Tables 9–15 beside this run's figures, each with how and why they differ.
pub fn beside(commands: &[CommandRecord], samples: &[PoseSample]) -> String {
    [
        command_beside(9, ALPHA, commands),
        command_beside(10, CHARLIE, commands),
        command_beside(11, TANGO, commands),
        timing_beside(commands),
        pose_beside(13, ALPHA, samples),
        pose_beside(14, CHARLIE, samples),
        pose_beside(15, TANGO, samples),
    ]
    .join("\n")
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn the_published_tables_agree_with_themselves() {
        // Table 12 is Tables 9–11 per command; every row has its clock time.
        assert_eq!(clock(0.0), "08:36:52");
        assert_eq!(clock(13.0), "08:37:05");
        let thesis = published_commands();
        let tango: Vec<f64> = receipts(&thesis, TANGO)
            .iter()
            .map(|c| c.unwrap().t_s)
            .collect();
        assert_eq!(tango, [4.0, 5.0, 8.0, 12.0]);
        assert_eq!(delays(&thesis, TANGO), (Some((0.0, 2.0)), 0));
    }

    #[test]
    fn a_command_lost_here_shows_as_lost_beside_the_thesis() {
        let mut ours = published_commands();
        ours.retain(|c| !(c.rover == TANGO && c.t_s == 5.0));
        let text = command_beside(11, TANGO, &ours);
        assert!(
            text.contains("0 – Go Straight            -       5.000      08:36:57"),
            "{text}"
        );
        assert!(
            text.contains("1 of Alpha's commands never reached it here"),
            "{text}"
        );
    }
}

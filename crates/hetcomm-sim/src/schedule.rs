//! The leader's plan as data: which movement command is issued at which simulated second.
//!
//! The thesis's leader (Fig. 25) counts loop iterations and, at fixed counter values,
//! switches between going straight and pivoting left, sending each switch to the first
//! follower. Table 9 shows the resulting commands relative to the start at 08:36:52:
//! turn left at +2 s, straight at +5 s, turn left at +8 s, straight at +10 s; the location
//! tables end at +13 s. [`Schedule::thesis`] is exactly that plan, in simulated seconds.
//!
//! All rovers start moving straight without a command ("all rovers start moving straight
//! as soon as the simulation begins"), so the schedule's [`Schedule::initial`] command is
//! [`Command::Straight`] and is never sent.

/// A movement command as carried by the thesis's *Command* message (a single integer).
#[derive(Debug, Clone, Copy, PartialEq, Eq, Hash, PartialOrd, Ord)]
pub enum Command {
    /// Code 0: both wheels at 1, full forward.
    Straight,
    /// Code 1: left wheel −10, right wheel +10, a left pivot in place.
    TurnLeft,
    /// Code 2: both wheels at 0, halt.
    Stop,
}

impl Command {
    /// Every command, in code order.
    pub const ALL: [Command; 3] = [Command::Straight, Command::TurnLeft, Command::Stop];

    /// The integer code used on the wire (0 straight, 1 turn left, 2 stop).
    pub fn code(self) -> i64 {
        match self {
            Command::Straight => 0,
            Command::TurnLeft => 1,
            Command::Stop => 2,
        }
    }

    /// Parses a wire code; `None` for anything but 0, 1 or 2 (the thesis defines no others).
    pub fn from_code(code: i64) -> Option<Command> {
        match code {
            0 => Some(Command::Straight),
            1 => Some(Command::TurnLeft),
            2 => Some(Command::Stop),
            _ => None,
        }
    }

    /// The `(left, right)` wheel commands a rover applies for this command (Figs. 25–26).
    pub fn wheels(self) -> (f64, f64) {
        match self {
            Command::Straight => (1.0, 1.0),
            Command::TurnLeft => (-10.0, 10.0),
            Command::Stop => (0.0, 0.0),
        }
    }

    /// The short name used in the thesis's tables: "Go Straight", "Turn Left" or "Stop".
    pub fn name(self) -> &'static str {
        match self {
            Command::Straight => "Go Straight",
            Command::TurnLeft => "Turn Left",
            Command::Stop => "Stop",
        }
    }

    /// The table label with its code, as in Tables 9–11: e.g. `"1 – Turn Left"`.
    pub fn label(self) -> String {
        format!("{} – {}", self.code(), self.name())
    }
}

/// Wheel commands for a raw wire code; `None` for an unknown code, which a rover should ignore.
pub fn wheels_for_code(code: i64) -> Option<(f64, f64)> {
    Command::from_code(code).map(Command::wheels)
}

/// One planned command: issue `command` when simulated time reaches `t_s`.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct ScheduleEntry {
    /// Simulated time in seconds from the start of the scenario.
    pub t_s: f64,
    /// The command that becomes due at `t_s`.
    pub command: Command,
}

/// Why a [`Schedule`] could not be built.
#[derive(Debug, Clone, Copy, PartialEq)]
pub enum ScheduleError {
    /// An entry time or the end time was negative or not finite.
    BadTime(f64),
    /// Entry times were not strictly increasing (index of the offending entry).
    NotIncreasing(usize),
    /// The last entry is after the end time.
    EntryAfterEnd(f64),
}

impl std::fmt::Display for ScheduleError {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        match self {
            ScheduleError::BadTime(t) => {
                write!(f, "schedule time must be finite and >= 0, got {t}")
            }
            ScheduleError::NotIncreasing(i) => {
                write!(f, "schedule entry {i} is not later than the one before it")
            }
            ScheduleError::EntryAfterEnd(t) => {
                write!(
                    f,
                    "schedule entry at {t} s is after the end of the scenario"
                )
            }
        }
    }
}

impl std::error::Error for ScheduleError {}

/// A validated, time-ordered list of commands plus the scenario's end time.
#[derive(Debug, Clone, PartialEq)]
pub struct Schedule {
    initial: Command,
    entries: Vec<ScheduleEntry>,
    end_s: f64,
}

impl Schedule {
    /// Builds a schedule; entry times must be finite, ≥ 0, strictly increasing and ≤ `end_s`.
    pub fn new(
        initial: Command,
        entries: Vec<ScheduleEntry>,
        end_s: f64,
    ) -> Result<Self, ScheduleError> {
        if !(end_s.is_finite() && end_s >= 0.0) {
            return Err(ScheduleError::BadTime(end_s));
        }
        for (i, e) in entries.iter().enumerate() {
            if !(e.t_s.is_finite() && e.t_s >= 0.0) {
                return Err(ScheduleError::BadTime(e.t_s));
            }
            if i > 0 && e.t_s <= entries[i - 1].t_s {
                return Err(ScheduleError::NotIncreasing(i));
            }
            if e.t_s > end_s {
                return Err(ScheduleError::EntryAfterEnd(e.t_s));
            }
        }
        Ok(Schedule {
            initial,
            entries,
            end_s,
        })
    }

    /// The thesis's plan (Table 9 relative to 08:36:52): start straight, turn left at 2 s,
    /// straight at 5 s, turn left at 8 s, straight at 10 s, end at 13 s.
    pub fn thesis() -> Self {
        let e = |t_s, command| ScheduleEntry { t_s, command };
        Schedule {
            initial: Command::Straight,
            entries: vec![
                e(2.0, Command::TurnLeft),
                e(5.0, Command::Straight),
                e(8.0, Command::TurnLeft),
                e(10.0, Command::Straight),
            ],
            end_s: 13.0,
        }
    }

    /// The command every rover follows before any command is received (not sent).
    pub fn initial(&self) -> Command {
        self.initial
    }

    /// The planned commands in time order.
    pub fn entries(&self) -> &[ScheduleEntry] {
        &self.entries
    }

    /// The simulated time at which the scenario ends, in seconds.
    pub fn end_s(&self) -> f64 {
        self.end_s
    }

    /// The command in force at `t_s` (the latest entry with time ≤ `t_s`, else the initial
    /// command); NaN is treated like a time before every entry.
    pub fn active_at(&self, t_s: f64) -> Command {
        self.entries
            .iter()
            .take_while(|e| e.t_s <= t_s)
            .last()
            .map_or(self.initial, |e| e.command)
    }

    /// The entries due in the half-open window `(after_s, up_to_s]`, in order.
    ///
    /// Polling with consecutive windows `(t0, t1]`, `(t1, t2]`, … yields every entry
    /// exactly once, whatever the polling rate.
    pub fn due_between(
        &self,
        after_s: f64,
        up_to_s: f64,
    ) -> impl Iterator<Item = ScheduleEntry> + '_ {
        self.entries
            .iter()
            .copied()
            .filter(move |e| e.t_s > after_s && e.t_s <= up_to_s)
    }

    /// A polling cursor over this schedule, for a leader loop that asks "anything new?".
    pub fn player(&self) -> SchedulePlayer<'_> {
        SchedulePlayer {
            schedule: self,
            next: 0,
        }
    }
}

/// A cursor that hands out each of a schedule's commands once, when it falls due.
///
/// This mirrors the leader of Fig. 25, whose `turn` flag makes it send each command once.
#[derive(Debug, Clone)]
pub struct SchedulePlayer<'a> {
    schedule: &'a Schedule,
    next: usize,
}

impl SchedulePlayer<'_> {
    /// Returns the next command newly due at `t_s` (entry time ≤ `t_s`), or `None`.
    ///
    /// If several entries have fallen due since the last call (a coarse polling step),
    /// they come out one per call, oldest first, so call it until it returns `None`.
    /// A NaN `t_s` returns `None`.
    pub fn command_at(&mut self, t_s: f64) -> Option<Command> {
        let entry = self.schedule.entries.get(self.next)?;
        if entry.t_s <= t_s {
            self.next += 1;
            Some(entry.command)
        } else {
            None
        }
    }

    /// Like [`command_at`](Self::command_at) but also returns the entry's planned time.
    pub fn entry_at(&mut self, t_s: f64) -> Option<ScheduleEntry> {
        let entry = *self.schedule.entries.get(self.next)?;
        if entry.t_s <= t_s {
            self.next += 1;
            Some(entry)
        } else {
            None
        }
    }

    /// True once every entry has been handed out.
    pub fn is_finished(&self) -> bool {
        self.next >= self.schedule.entries.len()
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn codes_wheels_labels() {
        for c in Command::ALL {
            assert_eq!(Command::from_code(c.code()), Some(c));
        }
        assert_eq!(Command::from_code(3), None);
        assert_eq!(Command::from_code(-1), None);
        assert_eq!(Command::Straight.wheels(), (1.0, 1.0));
        assert_eq!(Command::TurnLeft.wheels(), (-10.0, 10.0));
        assert_eq!(Command::Stop.wheels(), (0.0, 0.0));
        assert_eq!(wheels_for_code(1), Some((-10.0, 10.0)));
        assert_eq!(wheels_for_code(9), None);
        assert_eq!(Command::TurnLeft.label(), "1 – Turn Left");
        assert_eq!(Command::Straight.label(), "0 – Go Straight");
        assert_eq!(Command::Stop.label(), "2 – Stop");
    }

    #[test]
    fn thesis_schedule_matches_table_9() {
        let s = Schedule::thesis();
        let times: Vec<f64> = s.entries().iter().map(|e| e.t_s).collect();
        assert_eq!(times, [2.0, 5.0, 8.0, 10.0]);
        let codes: Vec<i64> = s.entries().iter().map(|e| e.command.code()).collect();
        assert_eq!(codes, [1, 0, 1, 0]);
        assert_eq!(s.end_s(), 13.0);
        assert_eq!(s.initial(), Command::Straight);
        assert_eq!(
            Schedule::new(s.initial(), s.entries().to_vec(), 13.0),
            Ok(s)
        );
    }

    #[test]
    fn active_and_due() {
        let s = Schedule::thesis();
        assert_eq!(s.active_at(0.0), Command::Straight);
        assert_eq!(s.active_at(1.999), Command::Straight);
        assert_eq!(s.active_at(2.0), Command::TurnLeft);
        assert_eq!(s.active_at(7.0), Command::Straight);
        assert_eq!(s.active_at(9.0), Command::TurnLeft);
        assert_eq!(s.active_at(100.0), Command::Straight);
        assert_eq!(s.active_at(f64::NAN), Command::Straight);
        assert_eq!(s.due_between(0.0, 2.0).count(), 1);
        assert_eq!(s.due_between(2.0, 4.0).count(), 0);
        assert_eq!(s.due_between(-1.0, 13.0).count(), 4);
    }

    #[test]
    fn player_hands_out_each_command_once() {
        let s = Schedule::thesis();
        let mut p = s.player();
        let mut got = Vec::new();
        for k in 0..=1300 {
            let t = k as f64 / 100.0;
            while let Some(c) = p.command_at(t) {
                got.push((k, c));
            }
        }
        assert_eq!(
            got,
            [
                (200, Command::TurnLeft),
                (500, Command::Straight),
                (800, Command::TurnLeft),
                (1000, Command::Straight)
            ]
        );
        assert!(p.is_finished());
        // A coarse poll releases overdue entries one per call.
        let mut p = s.player();
        assert_eq!(p.command_at(f64::NAN), None);
        assert_eq!(p.entry_at(9.0).map(|e| e.t_s), Some(2.0));
        assert_eq!(p.command_at(9.0), Some(Command::Straight));
        assert_eq!(p.command_at(9.0), Some(Command::TurnLeft));
        assert_eq!(p.command_at(9.0), None);
    }

    #[test]
    fn invalid_schedules_are_rejected() {
        let e = |t_s| ScheduleEntry {
            t_s,
            command: Command::Stop,
        };
        assert_eq!(
            Schedule::new(Command::Straight, vec![e(1.0), e(1.0)], 5.0),
            Err(ScheduleError::NotIncreasing(1))
        );
        assert!(matches!(
            Schedule::new(Command::Straight, vec![e(f64::NAN)], 5.0),
            Err(ScheduleError::BadTime(_))
        ));
        assert_eq!(
            Schedule::new(Command::Straight, vec![e(6.0)], 5.0),
            Err(ScheduleError::EntryAfterEnd(6.0))
        );
        assert!(Schedule::new(Command::Straight, vec![], f64::INFINITY).is_err());
    }
}

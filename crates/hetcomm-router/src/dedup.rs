//! Receive-side duplicate suppression by (origin, incarnation, sequence).
//!
//! The filter answers what a receiver may truthfully say about a data frame: new (deliver
//! it), a duplicate of one delivered (acknowledge it again), a duplicate of one its inbox
//! refused (refuse it again, with the same status), or too old to tell (its memory of that
//! number is gone: neither deliver nor acknowledge it). Memory is bounded per
//! (origin, incarnation); what falls out of it becomes "too old", never "delivered".

use std::collections::{BTreeMap, BTreeSet, VecDeque};

use rustc_hash::FxHashMap as HashMap;

use hetcomm_core::wire::AckStatus;
use hetcomm_core::SystemId;

/// What the filter knows of a sequence number.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub(crate) enum Verdict {
    /// Never seen: deliver it (the filter now counts it as seen).
    New,
    /// Seen, and not refused: the inbox took it (or its verdict is pending).
    Duplicate,
    /// Seen, and the inbox refused it with this status.
    Refused(AckStatus),
    /// Older than what the filter remembers: it may or may not have been delivered.
    TooOld,
}

/// Sequence numbers seen from one (origin, incarnation): everything at or below `floor` except
/// the `holes`, plus the set `above` it. Each part is bounded by the window: past `window`
/// entries above, the floor moves up over the gap (which becomes a hole: a retransmission of
/// a missing message is still new); past `window` holes or refusals, the oldest is dropped and
/// everything at or below it becomes too old to tell.
#[derive(Debug, Default)]
struct Seen {
    floor: u64,
    above: BTreeSet<u64>,
    /// Ranges at or below `floor` never seen, by first number → last number.
    holes: BTreeMap<u64, u64>,
    /// Numbers seen whose delivery the inbox refused, with its status.
    refused: BTreeMap<u64, AckStatus>,
    /// Numbers at or below this (and not in `holes` or `refused`) are too old to tell.
    forgotten: u64,
}

impl Seen {
    fn verdict(&self, seq: u64) -> Verdict {
        if let Some(status) = self.refused.get(&seq) {
            return Verdict::Refused(*status);
        }
        if seq <= self.floor {
            if self.in_hole(seq) {
                return Verdict::New;
            }
            if seq <= self.forgotten {
                return Verdict::TooOld;
            }
            return Verdict::Duplicate;
        }
        match self.above.contains(&seq) {
            true => Verdict::Duplicate,
            false => Verdict::New,
        }
    }

    fn in_hole(&self, seq: u64) -> bool {
        self.holes
            .range(..=seq)
            .next_back()
            .is_some_and(|(_, last)| seq <= *last)
    }

    /// Records a new number as seen.
    fn insert(&mut self, seq: u64, window: usize) {
        if seq <= self.floor {
            self.fill_hole(seq);
            return;
        }
        // The common case, in-order arrival with no gaps, touches no tree.
        if seq == self.floor + 1 && self.above.is_empty() {
            self.floor = seq;
            return;
        }
        self.above.insert(seq);
        self.slide();
        while self.above.len() > window {
            let Some(first) = self.above.pop_first() else {
                break;
            };
            // The numbers skipped are not seen: a late retransmission of one is still new.
            if first > self.floor + 1 {
                self.holes.insert(self.floor + 1, first - 1);
                while self.holes.len() > window {
                    if let Some((_, last)) = self.holes.pop_first() {
                        self.forgotten = self.forgotten.max(last);
                    }
                }
            }
            self.floor = first;
            self.slide();
        }
    }

    /// Moves the floor over a contiguous run above it.
    fn slide(&mut self) {
        while self.above.first() == Some(&(self.floor + 1)) {
            self.above.pop_first();
            self.floor += 1;
        }
    }

    /// `seq`, in a hole, is seen now: the hole shrinks or splits around it.
    fn fill_hole(&mut self, seq: u64) {
        let Some((&first, &last)) = self.holes.range(..=seq).next_back() else {
            return;
        };
        if seq > last {
            return;
        }
        self.holes.remove(&first);
        if first < seq {
            self.holes.insert(first, seq - 1);
        }
        if seq < last {
            self.holes.insert(seq + 1, last);
        }
    }

    /// Remembers that the inbox refused `seq` (seen) with `status`.
    fn refuse(&mut self, seq: u64, status: AckStatus, window: usize) {
        self.refused.insert(seq, status);
        while self.refused.len() > window {
            if let Some((oldest, _)) = self.refused.pop_first() {
                self.forgotten = self.forgotten.max(oldest);
            }
        }
    }
}

/// Duplicate filter for every origin talking to this system.
#[derive(Debug)]
pub(crate) struct Dedup {
    window: usize,
    by_origin: HashMap<SystemId, Incarnations>,
}

/// What the filter keeps of one origin's incarnations.
#[derive(Debug, Default)]
struct Incarnations {
    /// Tracked, newest last (at most [`INCARNATIONS`]).
    live: VecDeque<(u32, Seen)>,
    /// Incarnations whose state was dropped to make room, newest last (at most
    /// [`RETIRED`]): a late frame of one is too old to tell, not new (taking it as new would
    /// deliver again what its first copy delivered).
    retired: VecDeque<u32>,
}

/// Incarnations remembered per origin: a restarted sender's late frames from its previous life
/// are still recognised.
const INCARNATIONS: usize = 4;
/// Dropped incarnations remembered per origin by number alone (4 bytes each).
const RETIRED: usize = 64;

impl Dedup {
    pub(crate) fn new(window: usize) -> Self {
        Dedup {
            window: window.max(1),
            by_origin: HashMap::default(),
        }
    }

    /// The state of (origin, incarnation), made for an incarnation never heard; None for
    /// one whose state was dropped.
    fn seen_mut(&mut self, origin: SystemId, incarnation: u32) -> Option<&mut Seen> {
        let o = self.by_origin.entry(origin).or_default();
        let pos = match o.live.iter().position(|(i, _)| *i == incarnation) {
            Some(pos) => pos,
            None if o.retired.contains(&incarnation) => return None,
            None => {
                if o.live.len() == INCARNATIONS {
                    if let Some((old, _)) = o.live.pop_front() {
                        if o.retired.len() == RETIRED {
                            o.retired.pop_front();
                        }
                        o.retired.push_back(old);
                    }
                }
                o.live.push_back((incarnation, Seen::default()));
                o.live.len() - 1
            }
        };
        Some(&mut o.live[pos].1)
    }

    /// What the filter knows of (origin, incarnation, seq).
    #[cfg(test)]
    pub(crate) fn verdict(&self, origin: SystemId, incarnation: u32, seq: u64) -> Verdict {
        self.by_origin
            .get(&origin)
            .and_then(|o| o.live.iter().find(|(i, _)| *i == incarnation))
            .map_or(Verdict::New, |(_, s)| s.verdict(seq))
    }

    /// What the filter knew of (origin, incarnation, seq); a new number is recorded as seen.
    /// One lookup of the origin for both.
    pub(crate) fn check_and_insert(
        &mut self,
        origin: SystemId,
        incarnation: u32,
        seq: u64,
    ) -> Verdict {
        let window = self.window;
        let Some(seen) = self.seen_mut(origin, incarnation) else {
            return Verdict::TooOld;
        };
        let verdict = seen.verdict(seq);
        if verdict == Verdict::New {
            seen.insert(seq, window);
        }
        verdict
    }

    /// Remembers that the inbox refused (origin, incarnation, seq): a retransmission is
    /// refused again with the same status, since the sender may already have reported the
    /// refusal (a later copy let in would make that report false).
    pub(crate) fn refuse(
        &mut self,
        origin: SystemId,
        incarnation: u32,
        seq: u64,
        status: AckStatus,
    ) {
        let window = self.window;
        if let Some(seen) = self.seen_mut(origin, incarnation) {
            seen.refuse(seq, status, window);
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use proptest::prelude::*;

    const O: SystemId = SystemId(1);

    /// Arrivals (a number, and whether its inbox refuses it) against an unbounded model.
    fn arrivals() -> impl Strategy<Value = Vec<(u64, bool)>> {
        proptest::collection::vec((1u64..300, proptest::bool::weighted(0.2)), 0..400)
    }

    /// Plays `arrivals` on a filter of `window`, checking each verdict against the truth; returns
    /// how many were too old to tell.
    fn play(window: usize, arrivals: &[(u64, bool)]) -> Result<usize, TestCaseError> {
        let mut d = Dedup::new(window);
        let mut seen = std::collections::HashMap::new();
        let mut too_old = 0;
        for &(seq, refuse) in arrivals {
            let truth = seen.get(&seq).copied();
            match d.check_and_insert(O, 7, seq) {
                Verdict::New => {
                    prop_assert_eq!(truth, None, "{} taken as new a second time", seq);
                    let status = refuse.then_some(AckStatus::InboxFull);
                    if let Some(status) = status {
                        d.refuse(O, 7, seq, status);
                    }
                    seen.insert(seq, status);
                }
                Verdict::Duplicate => prop_assert_eq!(truth, Some(None), "{} a duplicate", seq),
                Verdict::Refused(s) => prop_assert_eq!(truth, Some(Some(s)), "{} refused", seq),
                Verdict::TooOld => too_old += 1,
            }
        }
        Ok(too_old)
    }

    proptest! {
        /// Whatever the window, every verdict but "too old" is exactly the truth: nothing new
        /// twice, no duplicate of what never came, refusals answered with their status.
        #[test]
        fn never_says_what_is_not_so(window in 1usize..16, arrivals in arrivals()) {
            play(window, &arrivals)?;
        }

        /// With room for every number, the filter answers exactly like an unbounded set.
        #[test]
        fn within_the_window_it_is_exact(arrivals in arrivals()) {
            prop_assert_eq!(play(1000, &arrivals)?, 0);
        }
    }

    #[test]
    fn incarnations_are_separate() {
        let mut d = Dedup::new(16);
        assert_eq!(d.check_and_insert(O, 1, 5), Verdict::New);
        assert_eq!(d.verdict(O, 1, 5), Verdict::Duplicate);
        assert_eq!(d.verdict(O, 2, 5), Verdict::New);
    }

    #[test]
    fn a_refusal_of_an_in_order_message_is_remembered() {
        // Arrived in order, so it lives under the floor: the refusal must still hold there.
        let mut d = Dedup::new(16);
        assert_eq!(d.check_and_insert(O, 1, 1), Verdict::New);
        d.refuse(O, 1, 1, AckStatus::InboxFull);
        assert_eq!(
            d.check_and_insert(O, 1, 1),
            Verdict::Refused(AckStatus::InboxFull)
        );
    }

    #[test]
    fn a_gap_the_window_moved_past_is_still_new() {
        let mut d = Dedup::new(8);
        for s in 2..100 {
            assert_eq!(d.check_and_insert(O, 1, s), Verdict::New);
        }
        assert_eq!(d.check_and_insert(O, 1, 1), Verdict::New, "never seen");
        assert_eq!(d.check_and_insert(O, 1, 1), Verdict::Duplicate);
    }

    #[test]
    fn late_frames_of_a_dropped_incarnation_are_too_old_not_new() {
        // A sender restarted more often than the filter keeps incarnations, while frames of
        // its first life were still on the way: taking one as new would deliver it twice.
        let mut d = Dedup::new(16);
        assert_eq!(d.check_and_insert(O, 1, 23), Verdict::New);
        for incarnation in 2..=INCARNATIONS as u32 + 1 {
            assert_eq!(d.check_and_insert(O, incarnation, 1), Verdict::New);
        }
        assert_eq!(d.check_and_insert(O, 1, 23), Verdict::TooOld);
    }

    #[test]
    fn window_bounds_memory() {
        let mut d = Dedup::new(8);
        for s in (2..100_000).step_by(2) {
            d.check_and_insert(O, 1, s);
            d.refuse(O, 1, s, AckStatus::InboxFull);
        }
        let seen = &d.by_origin[&O].live[0].1;
        assert!(seen.above.len() <= 8 && seen.holes.len() <= 8 && seen.refused.len() <= 8);
        // What fell out of memory is too old to tell, never a duplicate of a delivery.
        assert_eq!(d.verdict(O, 1, 3), Verdict::TooOld);
        assert_eq!(d.verdict(O, 1, 4), Verdict::TooOld);
        assert_eq!(
            d.verdict(O, 1, 99_998),
            Verdict::Refused(AckStatus::InboxFull)
        );
        assert_eq!(
            d.verdict(O, 1, 99_999),
            Verdict::New,
            "the newest hole is kept"
        );
    }
}

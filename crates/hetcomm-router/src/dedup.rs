//! Receive-side duplicate suppression by (origin, incarnation, sequence).

use std::collections::{BTreeSet, VecDeque};

use rustc_hash::FxHashMap as HashMap;

use hetcomm_core::SystemId;

/// Sequence numbers seen from one (origin, incarnation): everything at or below `floor`, plus
/// the set `above` it. The set is bounded: past `window` entries the floor moves up, so a frame
/// more than `window` messages older than the newest is taken as a duplicate.
#[derive(Debug, Default)]
struct Seen {
    floor: u64,
    above: BTreeSet<u64>,
}

impl Seen {
    fn contains(&self, seq: u64) -> bool {
        seq <= self.floor || self.above.contains(&seq)
    }

    fn insert(&mut self, seq: u64, window: usize) {
        if seq <= self.floor {
            return;
        }
        // The common case, in-order arrival with no gaps, touches no tree.
        if seq == self.floor + 1 && self.above.is_empty() {
            self.floor = seq;
            return;
        }
        self.above.insert(seq);
        // Slide the floor over a contiguous run.
        while self.above.first() == Some(&(self.floor + 1)) {
            self.above.pop_first();
            self.floor += 1;
        }
        while self.above.len() > window {
            if let Some(first) = self.above.pop_first() {
                self.floor = first;
            }
        }
        while self.above.first() == Some(&(self.floor + 1)) {
            self.above.pop_first();
            self.floor += 1;
        }
    }

    fn remove(&mut self, seq: u64) {
        self.above.remove(&seq);
    }
}

/// Duplicate filter for every origin talking to this system.
#[derive(Debug)]
pub(crate) struct Dedup {
    window: usize,
    /// Per origin: the incarnations tracked, newest last (at most `INCARNATIONS`).
    by_origin: HashMap<SystemId, VecDeque<(u32, Seen)>>,
}

/// Incarnations remembered per origin: a restarted sender's late frames from its previous life
/// are still recognised.
const INCARNATIONS: usize = 4;

impl Dedup {
    pub(crate) fn new(window: usize) -> Self {
        Dedup {
            window: window.max(1),
            by_origin: HashMap::default(),
        }
    }

    fn seen_mut(&mut self, origin: SystemId, incarnation: u32) -> &mut Seen {
        let list = self.by_origin.entry(origin).or_default();
        let pos = match list.iter().position(|(i, _)| *i == incarnation) {
            Some(pos) => pos,
            None => {
                if list.len() == INCARNATIONS {
                    list.pop_front();
                }
                list.push_back((incarnation, Seen::default()));
                list.len() - 1
            }
        };
        &mut list[pos].1
    }

    /// Whether (origin, incarnation, seq) was seen before.
    #[cfg(test)]
    pub(crate) fn contains(&self, origin: SystemId, incarnation: u32, seq: u64) -> bool {
        self.by_origin
            .get(&origin)
            .and_then(|l| l.iter().find(|(i, _)| *i == incarnation))
            .is_some_and(|(_, s)| s.contains(seq))
    }

    /// Records (origin, incarnation, seq) as seen.
    #[cfg(test)]
    pub(crate) fn insert(&mut self, origin: SystemId, incarnation: u32, seq: u64) {
        let window = self.window;
        self.seen_mut(origin, incarnation).insert(seq, window);
    }

    /// Records (origin, incarnation, seq) as seen; false if it already was. One lookup of the
    /// origin instead of the two of [`Dedup::contains`] then [`Dedup::insert`].
    pub(crate) fn insert_new(&mut self, origin: SystemId, incarnation: u32, seq: u64) -> bool {
        let window = self.window;
        let seen = self.seen_mut(origin, incarnation);
        if seen.contains(seq) {
            return false;
        }
        seen.insert(seq, window);
        true
    }

    /// Forgets a sequence number (its delivery was refused, so a retransmission may try again).
    pub(crate) fn remove(&mut self, origin: SystemId, incarnation: u32, seq: u64) {
        self.seen_mut(origin, incarnation).remove(seq);
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use proptest::prelude::*;

    proptest! {
        /// Within the window, the filter answers exactly like an unbounded set.
        #[test]
        fn matches_a_set(seqs in proptest::collection::vec(1u64..200, 0..300)) {
            let mut d = Dedup::new(1000);
            let mut set = std::collections::HashSet::new();
            let mut e = Dedup::new(1000);
            for s in seqs {
                prop_assert_eq!(d.contains(SystemId(1), 7, s), set.contains(&s));
                d.insert(SystemId(1), 7, s);
                prop_assert_eq!(e.insert_new(SystemId(1), 7, s), set.insert(s));
            }
        }
    }

    #[test]
    fn incarnations_are_separate() {
        let mut d = Dedup::new(16);
        d.insert(SystemId(1), 1, 5);
        assert!(d.contains(SystemId(1), 1, 5));
        assert!(!d.contains(SystemId(1), 2, 5));
    }

    #[test]
    fn window_bounds_memory() {
        let mut d = Dedup::new(8);
        for s in (2..1000).step_by(2) {
            d.insert(SystemId(1), 1, s);
        }
        let list = &d.by_origin[&SystemId(1)];
        assert!(list[0].1.above.len() <= 8);
        assert!(d.contains(SystemId(1), 1, 998));
    }
}

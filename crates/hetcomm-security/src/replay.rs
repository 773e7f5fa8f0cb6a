//! The anti-replay window of RFC 6479 (as WireGuard uses it): which of the last
//! [`WINDOW`] counters of a session have been seen. Checked only after a frame authenticated,
//! so forged frames cannot move it.

/// Counters behind the highest one seen that are still accepted (if not seen before).
pub const WINDOW: u64 = 8192 - 64;

const WORDS: usize = 8192 / 64;

/// Counters seen in one session's receive direction.
#[derive(Clone, Debug)]
pub struct ReplayWindow {
    /// The highest counter accepted so far, plus one (0: none yet).
    next: u64,
    bits: [u64; WORDS],
}

impl Default for ReplayWindow {
    fn default() -> Self {
        ReplayWindow {
            next: 0,
            bits: [0; WORDS],
        }
    }
}

impl ReplayWindow {
    /// Accepts `counter` if it was not seen before and is not too old, and records it.
    /// Returns false for a replay (or a counter older than the window).
    pub fn accept(&mut self, counter: u64) -> bool {
        if counter == u64::MAX {
            return false;
        }
        let word = (counter / 64) as usize;
        if counter >= self.next {
            // Clear the words between the old top and the new one: they are new ground.
            let old_top = if self.next == 0 {
                None
            } else {
                Some(((self.next - 1) / 64) as usize)
            };
            match old_top {
                Some(top) if word - top < WORDS => {
                    for w in top + 1..=word {
                        self.bits[w % WORDS] = 0;
                    }
                }
                _ => self.bits = [0; WORDS],
            }
            self.next = counter + 1;
        } else if self.next - 1 - counter >= WINDOW {
            return false;
        }
        let slot = &mut self.bits[word % WORDS];
        let bit = 1u64 << (counter % 64);
        if *slot & bit != 0 {
            return false;
        }
        *slot |= bit;
        true
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use proptest::prelude::*;

    #[test]
    fn each_counter_is_accepted_once() {
        let mut w = ReplayWindow::default();
        assert!(w.accept(0));
        assert!(!w.accept(0));
        assert!(w.accept(5));
        assert!(w.accept(3));
        assert!(!w.accept(3));
        assert!(!w.accept(5));
        assert!(w.accept(1_000_000));
        assert!(!w.accept(5), "far behind the window");
        assert!(w.accept(1_000_000 - WINDOW + 1));
        assert!(!w.accept(1_000_000 - WINDOW));
        assert!(!w.accept(u64::MAX));
    }

    proptest! {
        /// Against a model that remembers everything: accepted iff new and within the window.
        #[test]
        fn matches_a_model(counters in proptest::collection::vec(0u64..20_000, 1..400)) {
            let mut w = ReplayWindow::default();
            let mut seen = std::collections::HashSet::new();
            let mut top: Option<u64> = None;
            for c in counters {
                let too_old = top.is_some_and(|t| c < t && t - c >= WINDOW);
                let expect = !too_old && !seen.contains(&c);
                prop_assert_eq!(w.accept(c), expect, "counter {}", c);
                if expect {
                    seen.insert(c);
                    top = Some(top.map_or(c, |t| t.max(c)));
                }
            }
        }
    }
}

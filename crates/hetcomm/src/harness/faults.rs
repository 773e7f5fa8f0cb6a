//! Scheduled network faults as a pure model: given the time and a frame's pair of systems,
//! pass it, drop it, or hold it back. No I/O, no clock of its own; the randomness (loss,
//! jitter) comes from a seeded generator per system, so a simulation is repeatable.
//!
//! Applied where every frame of a system leaves (`SystemCore::transmit_on`), so the same model
//! acts on real links in real time and on simulated links in virtual time, before any link
//! sees the frame: a frame dropped here is lost as on a cut radio (the router retransmits and
//! the send ends `Failed` or `Unconfirmed` when the cut lasts), and acknowledgements are
//! subject to the same faults as data.

use parking_lot::Mutex;
use std::time::Duration;

use hetcomm_core::{SystemId, Time};

/// What a fault does to the frames of a pair while it lasts.
#[derive(Clone, Copy, Debug, PartialEq)]
pub(crate) enum Effect {
    /// Nothing passes (a partition, a silent system).
    Cut,
    /// Frames are lost with probability `loss` and held back `latency` plus up to `jitter`.
    Degrade {
        loss: f64,
        latency: Duration,
        jitter: Duration,
    },
}

/// One scheduled fault on frames from `from` to `to` (None: any system), from `start` to `end`.
#[derive(Clone, Copy, Debug, PartialEq)]
pub(crate) struct FaultRule {
    pub from: Option<SystemId>,
    pub to: Option<SystemId>,
    pub start: Time,
    pub end: Time,
    pub effect: Effect,
}

/// What the schedule does with one frame.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub(crate) enum FaultVerdict {
    Pass,
    Drop,
    Delay(Duration),
}

/// A system's fault schedule and its random generator.
pub(crate) struct Faults {
    rules: Vec<FaultRule>,
    rng: Mutex<u64>,
}

impl Faults {
    /// The rules that concern frames leaving `system`, seeded by `seed`.
    pub(crate) fn new(rules: Vec<FaultRule>, seed: u64, system: SystemId) -> Faults {
        Faults {
            rules,
            rng: Mutex::new(seed ^ (u64::from(system.0) + 1).wrapping_mul(0x9E37_79B9_7F4A_7C15)),
        }
    }

    /// A uniform number in [0, 1) (splitmix64).
    fn uniform(&self) -> f64 {
        let mut s = self.rng.lock();
        *s = s.wrapping_add(0x9E37_79B9_7F4A_7C15);
        let mut z = *s;
        z = (z ^ (z >> 30)).wrapping_mul(0xBF58_476D_1CE4_E5B9);
        z = (z ^ (z >> 27)).wrapping_mul(0x94D0_49BB_1331_11EB);
        z ^= z >> 31;
        (z >> 11) as f64 / (1u64 << 53) as f64
    }

    /// The verdict for a frame from `from` to `to` at `now`: a cut wins over everything; of
    /// degradations, the first rule in force applies (the scenario loader refuses two that
    /// overlap on one pair).
    pub(crate) fn verdict(&self, now: Time, from: SystemId, to: SystemId) -> FaultVerdict {
        let mut degrade = None;
        for r in &self.rules {
            if now < r.start || now >= r.end {
                continue;
            }
            if r.from.is_some_and(|f| f != from) || r.to.is_some_and(|t| t != to) {
                continue;
            }
            match r.effect {
                Effect::Cut => return FaultVerdict::Drop,
                Effect::Degrade { .. } if degrade.is_none() => degrade = Some(r.effect),
                Effect::Degrade { .. } => {}
            }
        }
        let Some(Effect::Degrade {
            loss,
            latency,
            jitter,
        }) = degrade
        else {
            return FaultVerdict::Pass;
        };
        if loss > 0.0 && self.uniform() < loss {
            return FaultVerdict::Drop;
        }
        let extra = if jitter.is_zero() {
            Duration::ZERO
        } else {
            jitter.mul_f64(self.uniform())
        };
        let d = latency + extra;
        if d.is_zero() {
            FaultVerdict::Pass
        } else {
            FaultVerdict::Delay(d)
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    fn t(s: f64) -> Time {
        Time::from_micros((s * 1e6) as u64)
    }

    #[test]
    fn a_cut_acts_only_inside_its_window_and_pair() {
        let f = Faults::new(
            vec![FaultRule {
                from: Some(SystemId(1)),
                to: Some(SystemId(2)),
                start: t(1.0),
                end: t(2.0),
                effect: Effect::Cut,
            }],
            7,
            SystemId(1),
        );
        assert_eq!(
            f.verdict(t(0.5), SystemId(1), SystemId(2)),
            FaultVerdict::Pass
        );
        assert_eq!(
            f.verdict(t(1.0), SystemId(1), SystemId(2)),
            FaultVerdict::Drop
        );
        assert_eq!(
            f.verdict(t(1.5), SystemId(1), SystemId(3)),
            FaultVerdict::Pass
        );
        assert_eq!(
            f.verdict(t(2.0), SystemId(1), SystemId(2)),
            FaultVerdict::Pass
        );
    }

    #[test]
    fn loss_is_seeded_and_close_to_its_rate() {
        let rule = FaultRule {
            from: None,
            to: None,
            start: t(0.0),
            end: t(10.0),
            effect: Effect::Degrade {
                loss: 0.25,
                latency: Duration::from_millis(5),
                jitter: Duration::from_millis(2),
            },
        };
        let run = || {
            let f = Faults::new(vec![rule], 42, SystemId(0));
            (0..4000)
                .map(|_| f.verdict(t(1.0), SystemId(0), SystemId(1)))
                .collect::<Vec<_>>()
        };
        let a = run();
        assert_eq!(a, run());
        let lost = a.iter().filter(|v| **v == FaultVerdict::Drop).count();
        assert!((900..1100).contains(&lost), "lost {lost} of 4000 at 25%");
        for v in a {
            if let FaultVerdict::Delay(d) = v {
                assert!(d >= Duration::from_millis(5) && d < Duration::from_millis(7));
            }
        }
    }
}

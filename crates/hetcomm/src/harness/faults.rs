//! Scheduled network faults: given the time and a frame's pair of systems, pass it, drop it,
//! or hold it back. No I/O, no clock of its own. A degradation is judged by the emulation's
//! own [`LinkModel`] (one loss model, one family of seeded ChaCha8 streams, one per
//! direction), so a simulation is repeatable and a scenario's `loss`, `latency_ms` and
//! `jitter_ms` mean what an `emulated` transport's do.
//!
//! Applied where every frame of a system leaves (the interception point,
//! `SystemCore::leave`), before any link sees the frame, so the same schedule acts on real
//! links in real time and on simulated links in virtual time, whichever transport carries
//! the pair: a frame dropped here is lost as on a cut radio (the router retransmits and the
//! send ends `Failed` or `Unconfirmed` when the cut lasts), and acknowledgements are subject
//! to the same faults as data.

use parking_lot::Mutex;
use std::time::Duration;

use hetcomm_core::{SystemId, Time};
use hetcomm_link::emulation::{LinkModel, ModelParams, Verdict};

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

impl Effect {
    /// The link model of a degradation: `latency` plus a uniform share of `jitter` is the
    /// model's `latency_ms` ± `jitter_ms` around the window's middle.
    fn model(&self, seed: u64) -> Option<LinkModel> {
        let Effect::Degrade {
            loss,
            latency,
            jitter,
        } = *self
        else {
            return None;
        };
        let half_jitter_ms = jitter.as_secs_f64() * 1e3 / 2.0;
        let params = ModelParams {
            loss_percent: loss * 100.0,
            latency_ms: latency.as_secs_f64() * 1e3 + half_jitter_ms,
            jitter_ms: half_jitter_ms,
            ..ModelParams::default()
        };
        // The scenario loader checked the ranges (loss in 0..=1, times ≥ 0 and finite).
        LinkModel::new(params, seed).ok()
    }
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

/// A system's fault schedule, each degradation with its link model.
pub(crate) struct Faults {
    rules: Vec<(FaultRule, Option<Mutex<LinkModel>>)>,
}

impl Faults {
    /// The rules that concern frames leaving a system, their models seeded by `seed` (each
    /// rule's on its own seed, each direction on its own stream).
    pub(crate) fn new(rules: Vec<FaultRule>, seed: u64) -> Faults {
        let rules = rules
            .into_iter()
            .enumerate()
            .map(|(i, r)| {
                let model = r.effect.model(seed.wrapping_add(i as u64));
                (r, model.map(Mutex::new))
            })
            .collect();
        Faults { rules }
    }

    /// The verdict for a frame of `len` bytes from `from` to `to` at `now`: a cut wins over
    /// everything; of degradations, the first rule in force applies (the scenario loader
    /// refuses two that overlap on one pair).
    pub(crate) fn verdict(
        &self,
        now: Time,
        from: SystemId,
        to: SystemId,
        len: usize,
    ) -> FaultVerdict {
        let mut degrade = None;
        for (r, model) in &self.rules {
            if now < r.start || now >= r.end {
                continue;
            }
            if r.from.is_some_and(|f| f != from) || r.to.is_some_and(|t| t != to) {
                continue;
            }
            match (r.effect, model) {
                (Effect::Cut, _) => return FaultVerdict::Drop,
                (Effect::Degrade { .. }, Some(model)) if degrade.is_none() => degrade = Some(model),
                (Effect::Degrade { .. }, _) => {}
            }
        }
        let Some(model) = degrade else {
            return FaultVerdict::Pass;
        };
        match model.lock().on_frame(now, from, to, len, None) {
            Verdict::Drop(_) => FaultVerdict::Drop,
            Verdict::Deliver { first, .. } => match first.at.saturating_since(now) {
                d if d.is_zero() => FaultVerdict::Pass,
                d => FaultVerdict::Delay(d),
            },
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
        );
        assert_eq!(
            f.verdict(t(0.5), SystemId(1), SystemId(2), 64),
            FaultVerdict::Pass
        );
        assert_eq!(
            f.verdict(t(1.0), SystemId(1), SystemId(2), 64),
            FaultVerdict::Drop
        );
        assert_eq!(
            f.verdict(t(1.5), SystemId(1), SystemId(3), 64),
            FaultVerdict::Pass
        );
        assert_eq!(
            f.verdict(t(2.0), SystemId(1), SystemId(2), 64),
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
            let f = Faults::new(vec![rule], 42);
            (0..4000)
                .map(|_| f.verdict(t(1.0), SystemId(0), SystemId(1), 64))
                .collect::<Vec<_>>()
        };
        let a = run();
        assert_eq!(a, run());
        let lost = a.iter().filter(|v| **v == FaultVerdict::Drop).count();
        assert!((900..1100).contains(&lost), "lost {lost} of 4000 at 25%");
        for v in a {
            if let FaultVerdict::Delay(d) = v {
                assert!(d >= Duration::from_millis(5) && d <= Duration::from_millis(7));
            }
        }
    }
}

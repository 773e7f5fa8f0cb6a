//! The pure link model: given the time, the frame's length, its direction and the distance,
//! return a [`Verdict`]. No clock, no threads, no I/O; all randomness from seeded ChaCha8
//! streams, one per direction.

use std::collections::{BTreeMap, VecDeque};

use super::settings::EmulatedSettings;
use hetcomm_core::{SystemId, Time};
use rand::{Rng, SeedableRng};
use rand_chacha::ChaCha8Rng;

use super::params::{sanitize_distance, EmulationError, ModelParams};

pub use super::verdict::{Arrival, BitFlip, DropReason, Verdict};

/// State of one direction (src → dst).
#[derive(Clone, Debug)]
struct Direction {
    rng: ChaCha8Rng,
    /// Gilbert–Elliott state.
    bad: bool,
    /// When the transmitter is next idle, µs (fractional, so rounding does not accumulate).
    next_free_us: f64,
    /// Departure times (end of serialization) of frames still queued or in transmission, µs.
    departures: VecDeque<f64>,
    /// Arrival time of the latest copy, µs (for `preserve_order`).
    last_arrival_us: f64,
}

/// The per-direction RNG stream: ChaCha8 keyed by `seed`, on stream `src << 16 | dst`. ChaCha's
/// 64-bit stream id gives every direction an independent sequence, so traffic on one pair
/// never shifts another pair's draws.
pub fn direction_rng(seed: u64, src: SystemId, dst: SystemId) -> ChaCha8Rng {
    let mut rng = ChaCha8Rng::seed_from_u64(seed);
    rng.set_stream(((src.0 as u64) << 16) | dst.0 as u64);
    rng
}

/// A deterministic model of one emulated transport (all its directions).
///
/// Call [`LinkModel::on_frame`] once per frame, in send order, with non-decreasing `now`
/// per direction. The same parameters, seed and calls give the same verdicts on any machine,
/// in real or virtual time.
///
/// ```
/// use hetcomm_core::{SystemId, Time};
/// use hetcomm_link::emulation::{LinkModel, ModelParams, Verdict};
///
/// let params = ModelParams { latency_ms: 20.0, ..ModelParams::default() };
/// let mut model = LinkModel::new(params, 42).unwrap();
/// let v = model.on_frame(Time::from_micros(1_000), SystemId(1), SystemId(2), 100, None);
/// assert!(matches!(v, Verdict::Deliver { first, .. } if first.at == Time::from_micros(21_000)));
/// ```
#[derive(Clone, Debug)]
pub struct LinkModel {
    params: ModelParams,
    seed: u64,
    ge: Option<(f64, f64)>,
    directions: BTreeMap<(SystemId, SystemId), Direction>,
}

impl LinkModel {
    /// A model with validated `params`, drawing from `seed`.
    pub fn new(params: ModelParams, seed: u64) -> Result<LinkModel, EmulationError> {
        params.validate()?;
        Ok(LinkModel {
            ge: params.gilbert_elliott(),
            params,
            seed,
            directions: BTreeMap::new(),
        })
    }

    /// The model of an `emulated` transport from the fleet file (profile, overrides and seed).
    pub fn from_settings(settings: &EmulatedSettings) -> Result<LinkModel, EmulationError> {
        LinkModel::new(ModelParams::from_settings(settings)?, settings.seed)
    }

    /// The parameters in force.
    pub fn params(&self) -> &ModelParams {
        &self.params
    }

    /// The seed the per-direction streams derive from.
    pub fn seed(&self) -> u64 {
        self.seed
    }

    /// Forgets all per-direction state (queues, burst state, RNG positions): the next frames
    /// are judged as if the model were new.
    pub fn reset(&mut self) {
        self.directions.clear();
    }

    /// Judges one frame of `len` bytes sent from `src` to `dst` at `now`, with the systems
    /// `distance_m` metres apart (`None`, negative or NaN: unknown, counted as 0).
    ///
    /// Checks, in order: MTU, outage, range cut-off (these draw no random numbers and leave no
    /// state), then the transmit queue (a frame that gets a slot occupies the transmitter even
    /// if it is lost afterwards, as on a real radio), path loss, Gilbert–Elliott burst loss,
    /// iid loss; a surviving frame gets its arrival time(s), duplication and corruption.
    pub fn on_frame(
        &mut self,
        now: Time,
        src: SystemId,
        dst: SystemId,
        len: usize,
        distance_m: Option<f64>,
    ) -> Verdict {
        let p = &self.params;
        if p.mtu_bytes.is_some_and(|mtu| len > mtu) {
            return Verdict::Drop(DropReason::Mtu);
        }
        if p.outage.is_some_and(|o| o.contains(now.as_micros())) {
            return Verdict::Drop(DropReason::Outage);
        }
        let distance = sanitize_distance(distance_m);
        if p.range_m.is_some_and(|r| distance > r) {
            return Verdict::Drop(DropReason::OutOfRange);
        }
        let seed = self.seed;
        let ge = self.ge;
        let dir = self.directions.entry((src, dst)).or_insert_with(|| {
            let mut rng = direction_rng(seed, src, dst);
            // Start the chain in its stationary distribution so short runs are unbiased.
            let bad = match ge {
                Some((gb, bg)) => rng.gen::<f64>() < gb / (gb + bg),
                None => false,
            };
            Direction {
                rng,
                bad,
                next_free_us: 0.0,
                departures: VecDeque::new(),
                last_arrival_us: 0.0,
            }
        });
        let now_us = now.as_micros() as f64;

        // Transmit queue and serialization: FIFO, one frame on the air at a time.
        let departure_us = match p.bandwidth_kbps {
            Some(kbps) => {
                while dir.departures.front().is_some_and(|&d| d <= now_us) {
                    dir.departures.pop_front();
                }
                if p.queue_frames.is_some_and(|q| dir.departures.len() >= q) {
                    return Verdict::Drop(DropReason::QueueFull);
                }
                // bits / (kbit/s · 1000) s = len·8·1000/kbps µs.
                let serialization_us = len as f64 * 8.0 * 1000.0 / kbps;
                let departure = dir.next_free_us.max(now_us) + serialization_us;
                dir.next_free_us = departure;
                if p.queue_frames.is_some() {
                    dir.departures.push_back(departure);
                }
                departure
            }
            None => now_us,
        };

        if let Some(pl) = p.path_loss {
            let loss = pl.loss_probability(distance);
            if dir.rng.gen::<f64>() < loss {
                return Verdict::Drop(DropReason::PathLoss);
            }
        }
        if let Some((good_to_bad, bad_to_good)) = ge {
            // Transition first, then judge the frame by the new state.
            let u = dir.rng.gen::<f64>();
            dir.bad = if dir.bad {
                u >= bad_to_good
            } else {
                u < good_to_bad
            };
            if dir.bad {
                return Verdict::Drop(DropReason::BurstLoss);
            }
        }
        if p.loss_percent > 0.0 && dir.rng.gen::<f64>() * 100.0 < p.loss_percent {
            return Verdict::Drop(DropReason::Loss);
        }

        let first = arrival(p, dir, now_us, departure_us, len);
        let duplicate = (p.duplicate_percent > 0.0
            && dir.rng.gen::<f64>() * 100.0 < p.duplicate_percent)
            .then(|| arrival(p, dir, now_us, departure_us, len));
        Verdict::Deliver { first, duplicate }
    }
}

/// Draws one copy's arrival: departure + max(0, latency + U(−jitter, +jitter)) + Exp(tail)
/// [+ reorder delay], kept after the previous copy when `preserve_order` is set, and its
/// corruption.
fn arrival(
    p: &ModelParams,
    dir: &mut Direction,
    now_us: f64,
    departure_us: f64,
    len: usize,
) -> Arrival {
    let mut delay_ms = p.latency_ms;
    if p.jitter_ms > 0.0 {
        delay_ms += dir.rng.gen_range(-p.jitter_ms..=p.jitter_ms);
    }
    delay_ms = delay_ms.max(0.0);
    if p.delay_tail_ms > 0.0 {
        // Inverse CDF of the exponential distribution; 1 − u ∈ (0, 1], so ln is finite.
        let u: f64 = dir.rng.gen();
        delay_ms += -p.delay_tail_ms * (1.0 - u).ln();
    }
    let reordered = p.reorder_percent > 0.0 && dir.rng.gen::<f64>() * 100.0 < p.reorder_percent;
    if reordered {
        delay_ms += p.reorder_delay_ms;
    }
    let mut at_us = (departure_us + delay_ms * 1000.0).max(now_us);
    if p.preserve_order {
        at_us = at_us.max(dir.last_arrival_us);
    }
    dir.last_arrival_us = dir.last_arrival_us.max(at_us);
    let corrupt =
        (p.corrupt_percent > 0.0 && len > 0 && dir.rng.gen::<f64>() * 100.0 < p.corrupt_percent)
            .then(|| BitFlip {
                byte: dir.rng.gen_range(0..len),
                mask: 1u8 << dir.rng.gen_range(0..8u32),
            });
    Arrival {
        at: Time::from_micros(at_us.round() as u64),
        corrupt,
        reordered,
    }
}

#[cfg(test)]
#[path = "model_tests.rs"]
mod tests;

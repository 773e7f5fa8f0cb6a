//! Emulated radio links: loss, burst loss, latency, jitter, bandwidth, queues, MTU,
//! duplication, reordering, corruption, outages and range, over any other [`Link`](crate::Link).
//!
//! Two layers, as in smoltcp's `FaultInjector` and turmoil's rules:
//!
//! - [`LinkModel`] is **pure**: no clock, no threads. Given `now`, the frame's length, its
//!   direction `(src, dst)` and the distance between the systems it returns a [`Verdict`]:
//!   dropped (with a [`DropReason`]) or delivered at a time, possibly twice, possibly with a
//!   [`BitFlip`]. The virtual-time simulator calls it directly.
//! - [`EmulatedLink`] applies a model in real time around an inner link: drops silently,
//!   forwards copies that are due now on the caller's thread and the others from one delay
//!   thread per link. It adds nothing to the model's decisions, and offers everything else
//!   the inner link offers (its driven receive side included).
//! - [`EmulationLayer`] is emulation as a [layer](crate::layer): it puts an `EmulatedLink`
//!   over whatever link it is given, in real time, and leaves the link alone under
//!   simulation, where the simulator applies the model in virtual time.
//!
//! # Parameters
//!
//! [`ModelParams`] holds the keys of an `emulated` transport ([`KEYS`]); a built-in profile
//! ([`PROFILES`]: `wired`, `wifi`, `bluetooth-classic`) gives starting values that explicit
//! keys override one by one. `docs/emulation.md` lists every key with its unit and default,
//! and the profiles' figures with their sources.
//!
//! # Formulas
//!
//! Checks run in this order for each frame: MTU, outage, range cut-off, queue, path loss,
//! burst loss, iid loss; then delay, duplication and corruption of the surviving frame.
//!
//! - **iid loss**: lost with probability `loss_percent / 100`.
//! - **Gilbert–Elliott** (per frame of one direction; loss 1 in the bad state, 0 in the good
//!   one): with `π = burst_loss_percent/100` and `L = burst_length_mean`,
//!   `p(bad→good) = r = 1/L` and `p(good→bad) = p = π·r/(1 − π)`, so the long-run loss is
//!   `p/(p + r) = π` and bursts are geometric with mean `1/r = L`. Needs `π ≤ L/(1 + L)`. The
//!   chain transitions first, then judges the frame; it starts in its stationary distribution.
//! - **Rate limit**: one frame on the air at a time per direction, FIFO. Serialization takes
//!   `len·8 / (bandwidth_kbps·1000)` s; a frame starts at `max(now, previous departure)`.
//!   With `queue_frames = Q`, a frame arriving while `Q` frames are still queued or being
//!   transmitted is dropped ("queue full"). A frame that got a slot occupies the air even if
//!   it is lost afterwards.
//! - **Delay**: `arrival = departure + max(0, latency_ms + U(−jitter_ms, +jitter_ms)) +
//!   Exp(mean delay_tail_ms) [+ reorder_delay_ms]`. Jitter is uniform, so every delay lies in
//!   `[max(0, latency − jitter), latency + jitter]` before the tail. With `preserve_order = 1`
//!   a copy never arrives before the previous copy of its direction (jitter without
//!   reordering, as on RFCOMM).
//! - **Reordering**: with probability `reorder_percent/100` a copy is held back by an extra
//!   `reorder_delay_ms` (default 10 ms); frames sent less than that later overtake it.
//! - **Duplication**: with probability `duplicate_percent/100` a second copy is delivered, with
//!   its own delay draw. **Corruption**: each copy, with probability `corrupt_percent/100`,
//!   gets one uniformly chosen bit flipped.
//! - **Outage**: frames sent in `[start + k·period, start + k·period + duration)` (ms on the
//!   model's clock; one window if no period) are dropped.
//! - **Range**: beyond `range_m` → dropped "out of range". **Path loss** (log-distance):
//!   `Pr = tx_power_dbm − reference_loss_db − 10·n·log10(d/d0)` with `d` clamped to at least
//!   `d0 = reference_distance_m`; loss probability `1 / (1 + exp((Pr − sensitivity_dbm) /
//!   margin_slope_db))` (a hard threshold `Pr < sensitivity` when the slope is 0). An unknown
//!   position (or a negative/NaN distance) counts as distance 0.
//!
//! # Determinism
//!
//! Each direction draws from its own ChaCha8 stream: key `seed`, stream id
//! `src << 16 | dst` ([`direction_rng`]). The same parameters, seed and sequence of calls give
//! the same verdicts everywhere; traffic on one pair never changes another pair's draws.
//!
//! ```
//! use std::collections::BTreeMap;
//! use hetcomm_core::{SystemId, Time};
//! use hetcomm_link::emulation::{DropReason, LinkModel, ModelParams};
//!
//! let mut keys = BTreeMap::new();
//! keys.insert("range_m".to_string(), 30.0);
//! let params = ModelParams::from_keys(Some("wifi"), &keys).unwrap();
//! let mut model = LinkModel::new(params, 7).unwrap();
//! let v = model.on_frame(Time::ZERO, SystemId(1), SystemId(2), 200, Some(45.0));
//! assert_eq!(v.drop_reason(), Some(DropReason::OutOfRange));
//! ```

mod factory;
mod layer;
mod link;
mod model;
mod params;
mod positions;
mod settings;
mod verdict;

pub use factory::EmulatedFactory;
pub use layer::EmulationLayer;
pub use link::{DropCounts, EmulatedLink};
pub use model::{direction_rng, Arrival, BitFlip, DropReason, LinkModel, Verdict};
pub use params::{profile, EmulationError, ModelParams, Outage, PathLoss, KEYS, PROFILES};
pub use positions::PositionTable;
pub use settings::EmulatedSettings;

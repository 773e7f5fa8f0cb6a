//! Time as the router sees it: microseconds on a clock chosen by the driver. The real runtime
//! uses microseconds since the UNIX epoch; the simulator uses virtual microseconds since the
//! start of a run. The router never reads a clock itself.

use std::ops::{Add, Sub};
use std::time::Duration;

use serde::{Deserialize, Serialize};

/// A point in time, in microseconds on the driver's clock.
#[derive(
    Clone, Copy, Debug, Default, PartialEq, Eq, Hash, PartialOrd, Ord, Serialize, Deserialize,
)]
pub struct Time(pub u64);

impl Time {
    /// The clock's origin.
    pub const ZERO: Time = Time(0);
    /// Later than any real deadline.
    pub const MAX: Time = Time(u64::MAX);

    /// Microseconds since the clock's origin.
    pub fn as_micros(self) -> u64 {
        self.0
    }

    /// Builds a time from whole microseconds.
    pub fn from_micros(us: u64) -> Time {
        Time(us)
    }

    /// Builds a time from seconds (fractions allowed).
    pub fn from_secs_f64(s: f64) -> Time {
        Time((s * 1e6).round() as u64)
    }

    /// Seconds since the clock's origin.
    pub fn as_secs_f64(self) -> f64 {
        self.0 as f64 / 1e6
    }

    /// The current wall-clock time (microseconds since the UNIX epoch). Only drivers call this.
    pub fn now_wall() -> Time {
        let since = std::time::SystemTime::now()
            .duration_since(std::time::UNIX_EPOCH)
            .unwrap_or_default();
        Time(since.as_micros() as u64)
    }

    /// `self - earlier`, or zero if `earlier` is later.
    pub fn saturating_since(self, earlier: Time) -> Duration {
        Duration::from_micros(self.0.saturating_sub(earlier.0))
    }
}

impl Add<Duration> for Time {
    type Output = Time;
    fn add(self, d: Duration) -> Time {
        Time(
            self.0
                .saturating_add(d.as_micros().min(u64::MAX as u128) as u64),
        )
    }
}

impl Sub<Time> for Time {
    type Output = Duration;
    fn sub(self, earlier: Time) -> Duration {
        self.saturating_since(earlier)
    }
}

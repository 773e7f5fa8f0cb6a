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
        #[cfg(unix)]
        {
            // Straight from clock_gettime: `SystemTime::now` and `duration_since` add about
            // 8 ns of checks to the 20 ns read here, and every in-process send reads the clock.
            let mut ts = libc::timespec {
                tv_sec: 0,
                tv_nsec: 0,
            };
            // SAFETY: clock_gettime writes into the timespec we pass; CLOCK_REALTIME exists
            // everywhere, so it only fails for a bad pointer.
            if unsafe { libc::clock_gettime(libc::CLOCK_REALTIME, &mut ts) } == 0 {
                let secs = u64::try_from(ts.tv_sec).unwrap_or(0);
                let micros = u64::try_from(ts.tv_nsec).unwrap_or(0) / 1_000;
                return Time(secs.saturating_mul(1_000_000).saturating_add(micros));
            }
        }
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

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn wall_clock_reads_microseconds_since_the_unix_epoch() {
        let micros = |t: std::time::SystemTime| {
            t.duration_since(std::time::UNIX_EPOCH).unwrap().as_micros() as u64
        };
        let before = micros(std::time::SystemTime::now());
        let now = Time::now_wall().as_micros();
        let after = micros(std::time::SystemTime::now());
        assert!(
            before <= now && now <= after,
            "{before} <= {now} <= {after}"
        );
    }
}

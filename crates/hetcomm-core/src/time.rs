//! Time as the router sees it: microseconds on a clock chosen by the driver. The real runtime
//! uses microseconds since the UNIX epoch; the simulator uses virtual microseconds since the
//! start of a run. The router never reads a clock itself.

use std::ops::{Add, Sub};
use std::time::Duration;

use serde::{Deserialize, Serialize};

#[cfg(all(target_os = "linux", target_arch = "x86_64"))]
mod tsc;

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
    ///
    /// On x86-64 Linux, where the kernel keeps time with the CPU's time-stamp counter, it is
    /// read from the counter against an anchor renewed from the OS clock every 100 ms (10 ns
    /// instead of 26; within a microsecond of the OS clock); elsewhere from the OS clock.
    pub fn now_wall() -> Time {
        #[cfg(all(target_os = "linux", target_arch = "x86_64"))]
        if let Some(ns) = tsc::now_ns(os_now_ns) {
            return Time(ns / 1_000);
        }
        Time(os_now_ns() / 1_000)
    }

    /// `self - earlier`, or zero if `earlier` is later.
    pub fn saturating_since(self, earlier: Time) -> Duration {
        Duration::from_micros(self.0.saturating_sub(earlier.0))
    }
}

/// Nanoseconds since the UNIX epoch from the OS clock.
fn os_now_ns() -> u64 {
    #[cfg(unix)]
    {
        // Straight from clock_gettime: `SystemTime::now` and `duration_since` add about 8 ns
        // of checks to the read.
        let mut ts = libc::timespec {
            tv_sec: 0,
            tv_nsec: 0,
        };
        // SAFETY: clock_gettime writes into the timespec we pass; CLOCK_REALTIME exists
        // everywhere, so it only fails for a bad pointer.
        if unsafe { libc::clock_gettime(libc::CLOCK_REALTIME, &mut ts) } == 0 {
            let secs = u64::try_from(ts.tv_sec).unwrap_or(0);
            let nanos = u64::try_from(ts.tv_nsec).unwrap_or(0);
            return secs.saturating_mul(1_000_000_000).saturating_add(nanos);
        }
    }
    let since = std::time::SystemTime::now()
        .duration_since(std::time::UNIX_EPOCH)
        .unwrap_or_default();
    u64::try_from(since.as_nanos()).unwrap_or(u64::MAX)
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

    fn os_micros() -> u64 {
        std::time::SystemTime::now()
            .duration_since(std::time::UNIX_EPOCH)
            .unwrap()
            .as_micros() as u64
    }

    #[test]
    fn wall_clock_reads_microseconds_since_the_unix_epoch() {
        let before = os_micros();
        let now = Time::now_wall().as_micros();
        let after = os_micros();
        // One microsecond of slack: a counter-based read may round the other way.
        assert!(
            before <= now + 1 && now <= after + 1,
            "{before} <= {now} <= {after}"
        );
    }

    /// Reads spread over more than one anchor's life (so the rate is measured and anchors
    /// are renewed) stay within a few microseconds of the OS clock. The bound is loose for
    /// a preempted read between the two clocks, not for the estimate.
    #[test]
    fn the_wall_clock_follows_the_os_clock_across_anchors() {
        let start = std::time::Instant::now();
        let mut close = 0;
        let mut reads = 0;
        while start.elapsed() < std::time::Duration::from_millis(350) {
            let before = os_micros();
            let now = Time::now_wall().as_micros();
            let after = os_micros();
            reads += 1;
            if after - before <= 2 {
                assert!(
                    now + 3 >= before && now <= after + 3,
                    "{before} <= {now} <= {after} after {:?}",
                    start.elapsed()
                );
                close += 1;
            }
            std::thread::sleep(std::time::Duration::from_micros(300));
        }
        assert!(
            close > reads / 2,
            "{close} of {reads} reads were uninterrupted"
        );
    }
}

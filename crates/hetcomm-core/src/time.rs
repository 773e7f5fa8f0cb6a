//! Time as the router sees it: microseconds on a clock chosen by the driver.
//!
//! Two clocks matter in a real run, and they are never mixed:
//!
//! - the **monotonic** clock ([`Time::now_mono`]: `CLOCK_MONOTONIC`, microseconds since an
//!   arbitrary origin, usually the boot) times everything that waits or measures a span:
//!   every `now` the router is given (retransmission and in-order hold deadlines, RTT
//!   samples, delivery latencies), batching, the harness's schedules, observers' records.
//!   It is never stepped, so NTP, chrony or an operator setting the clock moves no timer.
//! - the **wall** clock ([`Time::now_wall`], [`Time::wall_at`]: `CLOCK_REALTIME`,
//!   microseconds since the UNIX epoch) only for what crosses hosts or is shown to people:
//!   the header's `timestamp` and a received message's `received_at`, so that
//!   `received_at - timestamp` is a one-way latency (on hosts whose clocks agree).
//!
//! The simulator uses one virtual clock, microseconds since the start of a run, for both.
//! The router never reads a clock itself.

use std::cell::Cell;
use std::ops::{Add, Sub};
use std::time::Duration;

use serde::{Deserialize, Serialize};

#[cfg(all(target_os = "linux", target_arch = "x86_64"))]
mod tsc;

/// A point in time, in microseconds on the driver's clock (monotonic or wall: the field or
/// parameter holding it says which; see the module's documentation).
#[derive(
    Clone, Copy, Debug, Default, PartialEq, Eq, Hash, PartialOrd, Ord, Serialize, Deserialize,
)]
pub struct Time(pub u64);

/// How long a thread uses one reading of the offset between the wall clock and the
/// monotonic clock ([`Time::wall_at`]): a step of the wall clock shows within this.
const WALL_OFFSET_LIFE_US: u64 = 100_000;
/// An offset whose two monotonic reads are further apart than this was interrupted and is
/// read again.
const WALL_OFFSET_TOLERANCE_NS: u64 = 2_000;

thread_local! {
    /// This thread's (monotonic µs when read, wall µs minus monotonic µs); the first
    /// field is 0 before the first read.
    static WALL_OFFSET: Cell<(u64, i64)> = const { Cell::new((0, 0)) };
}

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

    /// The current monotonic time (microseconds since an arbitrary origin; never stepped):
    /// what the real runtime gives the router as `now`. Only drivers call this.
    ///
    /// On x86-64 Linux, where the kernel keeps time with the CPU's time-stamp counter, it is
    /// read from the counter against an anchor renewed from `CLOCK_MONOTONIC` every 100 ms
    /// (10 ns instead of 26; within a microsecond of the OS clock); elsewhere from the OS.
    pub fn now_mono() -> Time {
        #[cfg(all(target_os = "linux", target_arch = "x86_64"))]
        if let Some(ns) = tsc::now_ns(os_mono_ns) {
            return Time(ns / 1_000);
        }
        Time(os_mono_ns() / 1_000)
    }

    /// The current wall-clock time (microseconds since the UNIX epoch), read from the OS.
    /// For times shown to people or compared with another host's; never for a deadline.
    pub fn now_wall() -> Time {
        Time(os_wall_ns() / 1_000)
    }

    /// The wall-clock time (microseconds since the UNIX epoch) at `mono`, a reading of
    /// [`Time::now_mono`] taken just before on this thread: what a send is stamped with.
    ///
    /// The offset between the two clocks is read from the OS at most every 100 ms per
    /// thread, so that stamping costs an addition, not a second clock read; a step of the
    /// wall clock shows in stamps within 100 ms (and in no timer).
    pub fn wall_at(mono: Time) -> Time {
        WALL_OFFSET.with(|cell| {
            let (read_at, offset) = cell.get();
            let offset = if read_at != 0 && mono.0.wrapping_sub(read_at) < WALL_OFFSET_LIFE_US {
                offset
            } else {
                let offset = wall_offset_us();
                cell.set((mono.0.max(1), offset));
                offset
            };
            Time(mono.0.saturating_add_signed(offset))
        })
    }

    /// `self - earlier`, or zero if `earlier` is later.
    pub fn saturating_since(self, earlier: Time) -> Duration {
        Duration::from_micros(self.0.saturating_sub(earlier.0))
    }
}

/// Wall-clock microseconds minus monotonic microseconds, from the OS, read between two
/// monotonic reads close together (a preempted read would put the offset off by the
/// preemption).
fn wall_offset_us() -> i64 {
    let mut best = None;
    for _ in 0..4 {
        let before = os_mono_ns();
        let wall = os_wall_ns();
        let after = os_mono_ns();
        let mono = before + after.saturating_sub(before) / 2;
        let offset = (wall / 1_000) as i64 - (mono / 1_000) as i64;
        best = Some(offset);
        if after.saturating_sub(before) <= WALL_OFFSET_TOLERANCE_NS {
            break;
        }
    }
    best.unwrap_or(0)
}

/// Nanoseconds on the OS's monotonic clock.
fn os_mono_ns() -> u64 {
    #[cfg(unix)]
    {
        os_ns(libc::CLOCK_MONOTONIC)
    }
    #[cfg(not(unix))]
    {
        use std::sync::OnceLock;
        static ORIGIN: OnceLock<std::time::Instant> = OnceLock::new();
        let origin = *ORIGIN.get_or_init(std::time::Instant::now);
        // Never 0: callers keep 0 for "not read yet".
        u64::try_from(origin.elapsed().as_nanos()).unwrap_or(u64::MAX) + 1_000
    }
}

/// Nanoseconds since the UNIX epoch from the OS clock.
fn os_wall_ns() -> u64 {
    #[cfg(unix)]
    {
        os_ns(libc::CLOCK_REALTIME)
    }
    #[cfg(not(unix))]
    {
        let since = std::time::SystemTime::now()
            .duration_since(std::time::UNIX_EPOCH)
            .unwrap_or_default();
        u64::try_from(since.as_nanos()).unwrap_or(u64::MAX)
    }
}

/// Nanoseconds on `clock`, straight from clock_gettime: `SystemTime::now` and
/// `duration_since` add about 8 ns of checks to the read. (Through libc, so that a
/// preloaded library that moves the clock, such as libfaketime in the tests, is obeyed.)
#[cfg(unix)]
fn os_ns(clock: libc::clockid_t) -> u64 {
    let mut ts = libc::timespec {
        tv_sec: 0,
        tv_nsec: 0,
    };
    // SAFETY: clock_gettime writes into the timespec we pass; CLOCK_REALTIME and
    // CLOCK_MONOTONIC exist everywhere, so it only fails for a bad pointer.
    if unsafe { libc::clock_gettime(clock, &mut ts) } != 0 {
        return 0;
    }
    let secs = u64::try_from(ts.tv_sec).unwrap_or(0);
    let nanos = u64::try_from(ts.tv_nsec).unwrap_or(0);
    secs.saturating_mul(1_000_000_000).saturating_add(nanos)
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

    fn mono_micros() -> u64 {
        os_mono_ns() / 1_000
    }

    #[test]
    fn wall_clock_reads_microseconds_since_the_unix_epoch() {
        let before = os_micros();
        let now = Time::now_wall().as_micros();
        let after = os_micros();
        assert!(
            before <= now && now <= after,
            "{before} <= {now} <= {after}"
        );
    }

    #[test]
    fn a_stamp_is_the_wall_clock_at_a_monotonic_reading() {
        let before = os_micros();
        let stamp = Time::wall_at(Time::now_mono()).as_micros();
        let after = os_micros();
        // A few microseconds of slack: the offset is read once and rounded twice.
        assert!(
            before <= stamp + 3 && stamp <= after + 3,
            "{before} <= {stamp} <= {after}"
        );
    }

    /// Reads spread over more than one anchor's life (so the rate is measured and anchors
    /// are renewed) stay within a few microseconds of the OS clock, for the monotonic reading
    /// and for the stamp made from it. The bound is loose for a preempted read between the
    /// two clocks, not for the estimate.
    #[test]
    fn both_clocks_follow_the_os_clocks_across_anchors() {
        let start = std::time::Instant::now();
        let mut close = 0;
        let mut reads = 0;
        let mut last = Time::ZERO;
        while start.elapsed() < std::time::Duration::from_millis(350) {
            let (before, wall_before) = (mono_micros(), os_micros());
            let now = Time::now_mono();
            let stamp = Time::wall_at(now).as_micros();
            let (after, wall_after) = (mono_micros(), os_micros());
            reads += 1;
            assert!(now.0 + 1 >= last.0, "went back from {last:?} to {now:?}");
            last = now;
            let now = now.as_micros();
            if after - before <= 2 && wall_after - wall_before <= 2 {
                assert!(
                    now + 3 >= before && now <= after + 3,
                    "{before} <= {now} <= {after} after {:?}",
                    start.elapsed()
                );
                assert!(
                    stamp + 5 >= wall_before && stamp <= wall_after + 5,
                    "{wall_before} <= {stamp} <= {wall_after} after {:?}",
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

    /// The monotonic clock is not the wall clock: it counts from the boot, not from 1970.
    #[test]
    fn the_monotonic_clock_is_not_the_wall_clock() {
        let mono = Time::now_mono().as_micros();
        let wall = Time::now_wall().as_micros();
        assert!(mono.abs_diff(mono_micros()) < 1_000_000, "{mono}");
        assert!(wall > mono, "{wall} against {mono}");
    }
}

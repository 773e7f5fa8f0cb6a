//! The monotonic clock read from the CPU's time-stamp counter.
//!
//! `clock_gettime` costs about 26 ns on the machines we measure, a quarter of an in-process
//! send's budget; `rdtsc` costs 10. Each thread keeps an anchor, a (counter, OS clock) pair
//! read together, and converts the counter's ticks since then with a rate that is measured,
//! not assumed: the first anchors of the process give it, each re-anchoring refines it. An
//! anchor is renewed from the OS clock every [`ANCHOR_LIFE_NS`], so the estimate drifts from
//! the OS clock by well under a microsecond in between (70 ns a second was measured here).
//!
//! The OS clock anchored to is `CLOCK_MONOTONIC`, which is never stepped: the wall clock is
//! not read here (see `Time::wall_at`), so a step of the system clock reaches no timer.
//!
//! Used only where the kernel itself keeps time with the counter (its clock source is
//! `tsc`, which it picks only when the counter is invariant and synchronised across CPUs);
//! elsewhere every read goes to the OS. The estimate ([`Estimator`]) takes the counter and
//! the OS clock as functions, so its tests run on any machine with counters of their own.

use std::cell::Cell;
use std::sync::atomic::{AtomicU64, Ordering};
use std::sync::OnceLock;

/// How long a thread's anchor is used before it is read again from the OS clock.
const ANCHOR_LIFE_NS: u64 = 100_000_000;
/// The shortest span over which the counter's rate is measured: the OS clock's read
/// jitter (tens of nanoseconds) over this is a relative error below 1e-6.
const RATE_SPAN_NS: u64 = 20_000_000;
/// An anchor whose two OS reads are further apart than this was interrupted and is read
/// again (a preempted read would skew every estimate made from it).
const ANCHOR_TOLERANCE_NS: u64 = 2_000;

/// The range of counter rates believed, in [`Estimator::rate`]'s units: 20 GHz to 100 MHz.
const MIN_RATE: u64 = (1 << 32) / 20;
const MAX_RATE: u64 = 10 << 32;

/// The process's estimate for the real counter.
static ESTIMATOR: Estimator = Estimator::new();

thread_local! {
    /// This thread's (counter, OS nanoseconds) pair for the real counter; (0, 0) before the
    /// first read.
    static ANCHOR: Cell<(u64, u64)> = const { Cell::new((0, 0)) };
}

/// Whether the counter may be used: read once per process.
fn usable() -> bool {
    static USABLE: OnceLock<bool> = OnceLock::new();
    *USABLE.get_or_init(|| {
        std::fs::read_to_string("/sys/devices/system/clocksource/clocksource0/current_clocksource")
            .is_ok_and(|s| s.trim() == "tsc")
    })
}

fn ticks() -> u64 {
    // SAFETY: `rdtsc` exists on every x86-64 CPU and has no preconditions.
    unsafe { core::arch::x86_64::_rdtsc() }
}

/// Nanoseconds on the OS clock `os_now_ns` reads (the caller's `CLOCK_MONOTONIC`): from the
/// counter when it is usable, else `None` (the caller reads the OS clock).
pub(super) fn now_ns(os_now_ns: impl Fn() -> u64) -> Option<u64> {
    if !usable() {
        return None;
    }
    ANCHOR.with(|anchor| ESTIMATOR.read(anchor, ticks, os_now_ns))
}

/// A counter's rate against an OS clock, shared by every thread that reads the counter.
pub(super) struct Estimator {
    /// Nanoseconds per tick, as a 32.32 fixed-point number (0: not measured yet).
    rate: AtomicU64,
}

impl Estimator {
    pub(super) const fn new() -> Self {
        Estimator {
            rate: AtomicU64::new(0),
        }
    }

    /// The OS clock's nanoseconds now, estimated from `ticks` against `anchor` (the calling
    /// thread's), or `None` if no anchor could be read.
    pub(super) fn read(
        &self,
        anchor: &Cell<(u64, u64)>,
        ticks: impl Fn() -> u64,
        os_now_ns: impl Fn() -> u64,
    ) -> Option<u64> {
        let now = ticks();
        let (tsc0, os0) = anchor.get();
        let rate = self.rate.load(Ordering::Relaxed);
        if tsc0 != 0 && rate != 0 {
            let elapsed = ((u128::from(now.wrapping_sub(tsc0)) * u128::from(rate)) >> 32) as u64;
            if elapsed < ANCHOR_LIFE_NS {
                return Some(os0 + elapsed);
            }
        }
        if tsc0 != 0 && rate == 0 {
            // Waiting for a span long enough to measure the rate: one OS read until then.
            let os = os_now_ns();
            if os < os0 + RATE_SPAN_NS {
                return Some(os);
            }
        }
        // No anchor yet, the span to measure the rate is complete, or the anchor is old:
        // take a new anchor from the OS clock, and learn the rate from the span since the
        // last one.
        let (tsc1, os1) = take_anchor(&ticks, &os_now_ns)?;
        if tsc0 != 0 && tsc1 > tsc0 && os1 >= os0 + RATE_SPAN_NS {
            let measured = (u128::from(os1 - os0) << 32) / u128::from(tsc1 - tsc0);
            let measured = u64::try_from(measured).unwrap_or(0);
            // A jump of the OS clock inside the span (a suspended machine, a clock that
            // steps) shows as a rate far from the known one (or from any counter's): the
            // span is not used, the new anchor is.
            let plausible = if rate == 0 {
                (MIN_RATE..=MAX_RATE).contains(&measured)
            } else {
                measured.abs_diff(rate) <= rate / 1_000
            };
            if plausible {
                self.rate.store(measured, Ordering::Relaxed);
            }
        }
        anchor.set((tsc1, os1));
        Some(os1)
    }
}

/// A (counter, OS) pair read close together, or `None` if every try was interrupted.
fn take_anchor(ticks: &impl Fn() -> u64, os_now_ns: &impl Fn() -> u64) -> Option<(u64, u64)> {
    for _ in 0..4 {
        let before = os_now_ns();
        let tsc = ticks();
        let after = os_now_ns();
        if after >= before && after - before <= ANCHOR_TOLERANCE_NS {
            return Some((tsc, before + (after - before) / 2));
        }
    }
    None
}

#[cfg(test)]
mod tests {
    //! The estimate against a counter made from the OS's monotonic clock (3 ticks a
    //! nanosecond, offset so it does not start near zero): the logic is tested on every
    //! machine, whatever the kernel's clock source. (The real counter's reads are covered
    //! by the tests of `Time::now_mono`, which hold whichever way the clock is read.)
    use super::*;
    use std::sync::atomic::AtomicBool;
    use std::time::{Duration, Instant};

    fn os_ns() -> u64 {
        super::super::os_ns(libc::CLOCK_MONOTONIC)
    }

    /// A 3 GHz counter.
    fn fake_ticks() -> u64 {
        os_ns() * 3 + 12_345_678_901
    }

    /// Reads until `ms` after `start`, one a millisecond.
    fn read_until(
        est: &Estimator,
        anchor: &Cell<(u64, u64)>,
        os: &impl Fn() -> u64,
        start: Instant,
        ms: u64,
    ) {
        while start.elapsed() < Duration::from_millis(ms) {
            assert!(est.read(anchor, fake_ticks, os).is_some());
            std::thread::sleep(Duration::from_millis(1));
        }
    }

    #[test]
    fn the_rate_is_learned_and_reads_then_come_from_the_counter() {
        let (est, anchor) = (Estimator::new(), Cell::new((0, 0)));
        let start = Instant::now();
        read_until(&est, &anchor, &os_ns, start, 3 * RATE_SPAN_NS / 1_000_000);
        let rate = est.rate.load(Ordering::Relaxed);
        // A third of a nanosecond a tick, in 32.32 fixed point.
        let expected = (1u64 << 32) / 3;
        assert!(
            rate.abs_diff(expected) <= expected / 1_000,
            "{rate} against {expected}, after {:?}",
            start.elapsed()
        );
        // A fast read never consults the OS clock: one that panics is never called.
        let read = est
            .read(&anchor, fake_ticks, || panic!("the OS clock was read"))
            .unwrap();
        let os = os_ns();
        assert!(read.abs_diff(os) < 50_000, "{read} against {os}");
    }

    #[test]
    fn a_jump_of_the_os_clock_is_followed_and_leaves_the_rate_alone() {
        let (est, anchor) = (Estimator::new(), Cell::new((0, 0)));
        let offset = AtomicU64::new(0);
        let jumped = || os_ns() + offset.load(Ordering::Relaxed);
        let start = Instant::now();
        read_until(&est, &anchor, &jumped, start, 3 * RATE_SPAN_NS / 1_000_000);
        let rate = est.rate.load(Ordering::Relaxed);
        assert_ne!(rate, 0);
        // The OS clock jumps 10 s ahead: within an anchor's life the reads follow it.
        offset.store(10_000_000_000, Ordering::Relaxed);
        let until = 3 * RATE_SPAN_NS / 1_000_000 + 2 * ANCHOR_LIFE_NS / 1_000_000;
        read_until(&est, &anchor, &jumped, start, until);
        let read = est.read(&anchor, fake_ticks, jumped).unwrap();
        assert!(
            read.abs_diff(jumped()) < 50_000,
            "{read} against {}",
            jumped()
        );
        let after = est.rate.load(Ordering::Relaxed);
        assert!(
            after.abs_diff(rate) <= rate / 1_000,
            "{rate} became {after}"
        );
    }

    #[test]
    fn an_anchor_read_across_an_interruption_is_refused() {
        let (est, anchor) = (Estimator::new(), Cell::new((0, 0)));
        // Each OS read lands 10 µs after the one before, as if the thread was preempted
        // between them: no anchor is taken, the caller reads the OS clock itself.
        let fake = Cell::new(1_000_000_000u64);
        let interrupted = || {
            fake.set(fake.get() + 10_000);
            fake.get()
        };
        assert_eq!(est.read(&anchor, fake_ticks, interrupted), None);
        assert_eq!(anchor.get(), (0, 0));
    }

    /// The real counter, where the kernel keeps time with it: reads come from it once the
    /// rate is known. Elsewhere `now_ns` must leave every read to the OS.
    #[test]
    fn the_real_counter_is_used_exactly_where_the_kernel_uses_it() {
        let start = Instant::now();
        while start.elapsed() < Duration::from_millis(3 * RATE_SPAN_NS / 1_000_000) {
            assert_eq!(now_ns(os_ns).is_some(), usable());
            std::thread::sleep(Duration::from_millis(1));
        }
        let called = AtomicBool::new(false);
        let read = now_ns(|| {
            called.store(true, Ordering::Relaxed);
            os_ns()
        });
        if usable() {
            let read = read.expect("a usable counter gives a reading");
            assert!(!called.load(Ordering::Relaxed), "the OS clock was read");
            let os = os_ns();
            assert!(read.abs_diff(os) < 50_000, "{read} against {os}");
        } else {
            assert_eq!(read, None);
            assert!(!called.load(Ordering::Relaxed));
        }
    }
}

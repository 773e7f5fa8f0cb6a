//! The wall clock read from the CPU's time-stamp counter.
//!
//! `clock_gettime` costs about 26 ns on the machines we measure, a quarter of an in-process
//! send's budget; `rdtsc` costs 10. Each thread keeps an anchor, a (counter, wall time) pair
//! read together, and converts the counter's ticks since then with a rate that is measured,
//! not assumed: the first anchors of the process give it, each re-anchoring refines it. An
//! anchor is renewed from the OS clock every [`ANCHOR_LIFE_NS`], so a step of the system
//! clock (NTP, an operator) shows within that time, and the estimate drifts from the OS
//! clock by well under a microsecond in between (70 ns a second was measured here).
//!
//! Used only where the kernel itself keeps time with the counter (its clock source is
//! `tsc`, which it picks only when the counter is invariant and synchronised across CPUs);
//! elsewhere every read goes to the OS.

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

/// The range of counter rates believed, in [`RATE`]'s units: 20 GHz to 100 MHz.
const MIN_RATE: u64 = (1 << 32) / 20;
const MAX_RATE: u64 = 10 << 32;

/// Nanoseconds per tick, as a 32.32 fixed-point number (0: not measured yet).
static RATE: AtomicU64 = AtomicU64::new(0);

thread_local! {
    /// This thread's (counter, wall nanoseconds) pair; (0, 0) before the first read.
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

/// Nanoseconds since the UNIX epoch: from the counter when it is usable, else `None` (the
/// caller reads the OS clock).
pub(super) fn now_ns(os_now_ns: impl Fn() -> u64) -> Option<u64> {
    if !usable() {
        return None;
    }
    let now = ticks();
    let (tsc0, wall0) = ANCHOR.get();
    let rate = RATE.load(Ordering::Relaxed);
    if tsc0 != 0 && rate != 0 {
        let elapsed = ((u128::from(now.wrapping_sub(tsc0)) * u128::from(rate)) >> 32) as u64;
        if elapsed < ANCHOR_LIFE_NS {
            return Some(wall0 + elapsed);
        }
    }
    if tsc0 != 0 && rate == 0 {
        // Waiting for a span long enough to measure the rate: one OS read until then.
        let wall = os_now_ns();
        if wall < wall0 + RATE_SPAN_NS {
            return Some(wall);
        }
    }
    // No anchor yet, the span to measure the rate is complete, or the anchor is old: take
    // a new anchor from the OS clock, and learn the rate from the span since the last one.
    let (tsc1, wall1) = anchor(&os_now_ns)?;
    if tsc0 != 0 && tsc1 > tsc0 && wall1 >= wall0 + RATE_SPAN_NS {
        let measured = (u128::from(wall1 - wall0) << 32) / u128::from(tsc1 - tsc0);
        let measured = u64::try_from(measured).unwrap_or(0);
        // A step of the system clock inside the span shows as a rate far from the known
        // one (or from any counter's): the span is not used, the new anchor is.
        let plausible = if rate == 0 {
            (MIN_RATE..=MAX_RATE).contains(&measured)
        } else {
            measured.abs_diff(rate) <= rate / 1_000
        };
        if plausible {
            RATE.store(measured, Ordering::Relaxed);
        }
    }
    ANCHOR.set((tsc1, wall1));
    Some(wall1)
}

/// A (counter, wall) pair read close together, or `None` if every try was interrupted.
fn anchor(os_now_ns: &impl Fn() -> u64) -> Option<(u64, u64)> {
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
    use super::*;

    fn os_ns() -> u64 {
        std::time::SystemTime::now()
            .duration_since(std::time::UNIX_EPOCH)
            .unwrap()
            .as_nanos() as u64
    }

    #[test]
    fn the_rate_is_learned_and_reads_then_come_from_the_counter() {
        if !usable() {
            eprintln!("the kernel's clock source is not tsc here: nothing to test");
            return;
        }
        let start = std::time::Instant::now();
        while start.elapsed() < std::time::Duration::from_millis(3 * RATE_SPAN_NS / 1_000_000) {
            assert!(now_ns(os_ns).is_some());
            std::thread::sleep(std::time::Duration::from_millis(1));
        }
        let rate = RATE.load(Ordering::Relaxed);
        assert_ne!(rate, 0, "measured after {:?}", start.elapsed());
        // A fast read never consults the OS clock: one that panics is never called.
        let read = now_ns(|| panic!("the OS clock was read")).unwrap();
        let os = os_ns();
        assert!(read.abs_diff(os) < 50_000, "{read} against {os}");
    }

    #[test]
    fn a_step_of_the_system_clock_is_followed_and_leaves_the_rate_alone() {
        if !usable() {
            return;
        }
        let offset = std::sync::atomic::AtomicU64::new(0);
        let stepped = || os_ns() + offset.load(Ordering::Relaxed);
        let start = std::time::Instant::now();
        let until = |ms| {
            while start.elapsed() < std::time::Duration::from_millis(ms) {
                now_ns(stepped);
                std::thread::sleep(std::time::Duration::from_millis(1));
            }
        };
        until(3 * RATE_SPAN_NS / 1_000_000);
        let rate = RATE.load(Ordering::Relaxed);
        assert_ne!(rate, 0);
        // The system clock jumps 10 s ahead: within an anchor's life the reads follow it.
        offset.store(10_000_000_000, Ordering::Relaxed);
        until(3 * RATE_SPAN_NS / 1_000_000 + 2 * ANCHOR_LIFE_NS / 1_000_000);
        let read = now_ns(stepped).unwrap();
        assert!(
            read.abs_diff(stepped()) < 50_000,
            "{read} against {}",
            stepped()
        );
        let after = RATE.load(Ordering::Relaxed);
        assert!(
            after.abs_diff(rate) <= rate / 1_000,
            "{rate} became {after}"
        );
    }

    #[test]
    fn an_anchor_read_across_an_interruption_is_refused() {
        if !usable() {
            return;
        }
        // Each OS read lands 10 µs after the one before, as if the thread was preempted
        // between them: no anchor is taken, the caller reads the OS clock itself.
        let fresh = std::thread::spawn(|| {
            let fake = std::cell::Cell::new(1_000_000_000u64);
            now_ns(|| {
                fake.set(fake.get() + 10_000);
                fake.get()
            })
        });
        let fresh = fresh.join().unwrap();
        assert_eq!(fresh, None);
    }
}

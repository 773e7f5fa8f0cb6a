//! How fast this machine seals and opens frames (AES-256-GCM, ring): bytes per second
//! for a few sizes. `cargo run --release -p hetcomm-security --example seal_speed`.
//!
//! Each figure is given twice: by the wall clock, and by the CPU time of the measuring thread,
//! which is what to compare on a machine that other processes share (a thread that waits for
//! a core is not charged for the wait).

use std::time::{Duration, Instant};

use hetcomm_core::SystemId;
use hetcomm_security::envelope::DirectionKey;

/// The CPU time this thread has used so far.
fn thread_cpu() -> Duration {
    let mut t = libc::timespec {
        tv_sec: 0,
        tv_nsec: 0,
    };
    // SAFETY: `t` is a valid, writable timespec; the clock id is a constant Linux supports.
    let rc = unsafe { libc::clock_gettime(libc::CLOCK_THREAD_CPUTIME_ID, &mut t) };
    assert_eq!(rc, 0, "clock_gettime(CLOCK_THREAD_CPUTIME_ID)");
    Duration::new(t.tv_sec as u64, t.tv_nsec as u32)
}

/// Runs `f` `iters` times: (wall, CPU) per call, in seconds.
fn per_call(iters: usize, mut f: impl FnMut(usize)) -> (f64, f64) {
    let (wall, cpu) = (Instant::now(), thread_cpu());
    for i in 0..iters {
        f(i);
    }
    let n = iters as f64;
    (
        wall.elapsed().as_secs_f64() / n,
        (thread_cpu() - cpu).as_secs_f64() / n,
    )
}

fn main() {
    let key = DirectionKey::new(&[7; 32]);
    let ids = (SystemId(1), SystemId(2));
    for size in [64usize, 1024, 64 * 1024, 1 << 20] {
        let body = vec![5u8; size];
        let mut out = Vec::new();
        let iters = (256 << 20) / size.max(1024);
        let seal = per_call(iters, |i| key.seal(&mut out, ids, 1, i as u64, &[], &body));
        let mut inner = vec![0; size];
        let open = per_call(iters, |_| assert!(key.open_into(&out, &mut inner)));
        let show = |(wall, cpu): (f64, f64)| {
            format!(
                "{:.2} µs wall, {:.2} µs CPU ({:.2} GB/s)",
                wall * 1e6,
                cpu * 1e6,
                size as f64 / cpu / 1e9
            )
        };
        println!("{size:>8} B: seal {}, open {}", show(seal), show(open));
    }
}

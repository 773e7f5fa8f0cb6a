//! How fast this machine seals and opens frames (AES-256-GCM, aws-lc-rs): bytes per second
//! for a few sizes. `cargo run --release -p hetcomm-security --example seal_speed`.

use std::time::Instant;

use hetcomm_core::SystemId;
use hetcomm_security::envelope::DirectionKey;

fn main() {
    let key = DirectionKey::new(&[7; 32]);
    for size in [64usize, 1024, 64 * 1024, 1 << 20] {
        let body = vec![5u8; size];
        let mut out = Vec::new();
        let iters = (256 << 20) / size.max(1024);
        let t = Instant::now();
        for i in 0..iters {
            key.seal(
                &mut out,
                (SystemId(1), SystemId(2)),
                1,
                i as u64,
                &[],
                &body,
            );
        }
        let seal = t.elapsed();
        let t = Instant::now();
        for _ in 0..iters {
            let mut f = out.clone();
            assert!(key.open(&mut f));
        }
        let open = t.elapsed();
        let per = |d: std::time::Duration| d.as_secs_f64() / iters as f64;
        println!(
            "{size:>8} B: seal {:.2} µs ({:.2} GB/s), open+copy {:.2} µs ({:.2} GB/s)",
            per(seal) * 1e6,
            size as f64 / per(seal) / 1e9,
            per(open) * 1e6,
            size as f64 / per(open) / 1e9
        );
    }
}

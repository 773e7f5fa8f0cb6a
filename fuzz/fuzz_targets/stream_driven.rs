//! The `stream_records` inputs, read by a driven `StreamLink` (`StreamConfig::driven`) over a
//! Unix socket pair: the target writes the stream in the chunks the input chooses and calls
//! `Readable::read_ready` after each, so that records are interrupted by an empty
//! non-blocking socket at arbitrary points and resumed (`StreamEnd::Pending`, the `partial`
//! large frame, reading ahead after a large frame), and in hand-out mode large frames are read
//! with `readv` into uninitialised pool buffers. The checks are `stream_records`': the frames,
//! labels and counts of the model of `docs/wire-format.md`, no panic, no hang, and the heap
//! bound. The `read_ready` budget (1–4 records) comes from the parameter's top bits.
#![no_main]

#[path = "common/mod.rs"]
mod common;
#[path = "common/stream.rs"]
mod stream;

#[global_allocator]
static ALLOC: common::Counting = common::Counting;

use libfuzzer_sys::fuzz_target;

fuzz_target!(|data: &[u8]| {
    let input = stream::parse(data);
    let (expected, largest, bound) = stream::expect(&input);
    let budget = 1 + usize::from(data.get(2).copied().unwrap_or(0) >> 6);
    let got = stream::run_driven(&input, &input.reads, budget, &expected);
    stream::check("driven", &input, got, &expected, largest, bound);
});

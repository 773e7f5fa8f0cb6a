//! A byte stream, cut into reads at arbitrary points, into the receive side of a real
//! `stream::StreamLink`: hello (or no hello, per identity mode), then the record reader.
//!
//! The record reader and the hello reading are private, so the target drives them through the
//! smallest public surface that reaches them: a `StreamTransport` whose listener hands out one
//! in-memory connection serving the fuzz bytes. The link's own accept and reader threads then
//! run the real code (`identify`, `RecordReader::next_record`, `fill`, `read_large`,
//! `finish_large`, hand-out mode with its `BufferPool`).
//!
//! Every input runs twice — the stream in one piece, and the stream cut into the reads the
//! input chooses (a read size of 0 is an `Interrupted` error) — and both runs must agree with a
//! model of `docs/wire-format.md` written here from the spec: the same frames in the same
//! order, the same dropped-frame and rejected-connection counts. Checked too: no panic, no
//! hang, the public `decode_hello` / `decode_record_header` agree with the model on every header
//! the model reads, and the heap the link takes while reading stays within its read buffer
//! plus twice the largest record actually announced (rounded up to the pool's 4 KiB step) —
//! never anything for records it never reached, nor beyond `max_frame`.
//!
//! Input: flags, max-message parameter, read sizes, then the stream (literal or run-length
//! expanded); see `parse`.
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
    let whole = stream::run_threads(&input, Vec::new(), &expected);
    stream::check("in one piece", &input, whole, &expected, largest, bound);
    let cut = stream::run_threads(&input, input.reads.clone(), &expected);
    stream::check("cut into reads", &input, cut, &expected, largest, bound);
});

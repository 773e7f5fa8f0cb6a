//! Arbitrary bytes into the frame decoder: it must never panic, `peek_frame_len` must agree
//! with `decode`, and a frame that decodes must re-encode to the same bytes (up to the
//! reserved byte, which the decoder ignores and the encoder writes as zero).
#![no_main]

use hetcomm_core::wire::{self, DecodeError, HEADER_LEN, MAX_PAYLOAD};
use libfuzzer_sys::fuzz_target;

/// Offset of the reserved header byte.
const RESERVED: usize = 7;
/// Offset of the CRC-32 field.
const CRC: usize = 44;

fuzz_target!(|data: &[u8]| {
    let peeked = wire::peek_frame_len(data);
    if let Ok(total) = peeked {
        assert!((HEADER_LEN..=HEADER_LEN + MAX_PAYLOAD).contains(&total));
    }
    match wire::decode(data) {
        Ok(frame) => {
            // Whatever decodes passed the header checks and has exactly its declared length.
            assert_eq!(peeked, Ok(data.len()));
            assert_eq!(frame.payload, &data[HEADER_LEN..]);
            let again = wire::encode(&frame.header, frame.payload);
            assert_eq!(again.len(), data.len());
            if data[RESERVED] == 0 {
                assert_eq!(again, data, "re-encoding a decoded frame changed it");
            } else {
                // The encoder zeroes the reserved byte, so only it and the CRC may differ.
                assert_eq!(again[RESERVED], 0);
                assert_eq!(again[..RESERVED], data[..RESERVED]);
                assert_eq!(again[RESERVED + 1..CRC], data[RESERVED + 1..CRC]);
                assert_eq!(again[CRC + 4..], data[CRC + 4..]);
            }
            let round = wire::decode(&again).expect("a re-encoded frame decodes");
            assert_eq!(round.header, frame.header);
            assert_eq!(round.payload, frame.payload);
        }
        Err(e) => {
            // The header-only checks are the first checks of a full decode, so any error
            // `peek_frame_len` reports is the one `decode` reports.
            if let Err(p) = &peeked {
                assert_eq!(p, &e);
            }
            // Error messages must format without panicking.
            let _ = e.to_string();
            if let DecodeError::TooShort { len } = e {
                assert_eq!(len, data.len());
            }
        }
    }
});

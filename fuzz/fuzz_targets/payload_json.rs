//! Arbitrary bytes into the type-less payload decoder `payload::to_json`: it must never panic
//! (deep nesting, huge declared lengths, invalid UTF-8, ext types), and whatever it returns must
//! be JSON that `payload::from_json` can encode again.
#![no_main]

use hetcomm_core::payload;
use libfuzzer_sys::fuzz_target;

fuzz_target!(|data: &[u8]| {
    if let Some(json) = payload::to_json(data) {
        let text = json.to_string();
        let _ = text.len();
        let bytes = payload::from_json(&json).expect("JSON from to_json re-encodes");
        // The re-encoded value is itself one MessagePack value that reads back to the same
        // JSON, except that floats may not survive exactly as JSON numbers (NaN becomes null).
        let again = payload::to_json(&bytes).expect("re-encoded JSON is one value");
        let _ = again;
    }
});

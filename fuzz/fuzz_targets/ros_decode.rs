//! Arbitrary bytes into the ROS bridges' decoders (`hetcomm_rosmsg::codec::decode`), as a ROS
//! message body of any shipped type (ROS 1 serialization, or CDR in either byte order, XCDR1
//! or XCDR2): it must never panic, hang or allocate for lengths the bytes cannot hold, and a
//! body that decodes must convert back (`encode`) into a body that decodes to the same
//! encoding again.
#![no_main]

use std::sync::OnceLock;

use hetcomm_rosmsg::codec::{decode, encode, Wire};
use hetcomm_rosmsg::schema::{Flavour, RosType};
use libfuzzer_sys::fuzz_target;

fn types() -> &'static [(Flavour, &'static RosType)] {
    static ALL: OnceLock<Vec<(Flavour, &'static RosType)>> = OnceLock::new();
    ALL.get_or_init(|| {
        hetcomm_rosmsg::registry::every_shipped_type().expect("the shipped types resolve")
    })
}

fuzz_target!(|data: &[u8]| {
    // Two bytes choose the type, one the encoding; the rest is the body.
    let [a, b, mode, body @ ..] = data else {
        return;
    };
    let all = types();
    let (flavour, ty) = all[usize::from(u16::from_le_bytes([*a, *b])) % all.len()];
    let wire = match (flavour, mode % 4) {
        (Flavour::Ros1, _) => Wire::Ros1,
        (_, m) => Wire::Cdr {
            little: m & 1 == 0,
            xcdr2: m & 2 != 0,
        },
    };
    let Ok(value) = decode(body, ty, wire) else {
        return;
    };
    // Written back in the flavour's own encoding (CDR: XCDR1 little endian).
    let out = match flavour {
        Flavour::Ros1 => Wire::Ros1,
        Flavour::Ros2 => Wire::CDR,
    };
    let first = encode(&value, ty, out, "fuzzed").expect("a decoded value encodes");
    let again = decode(&first, ty, out).expect("an encoded value decodes");
    let second = encode(&again, ty, out, "fuzzed").expect("and encodes again");
    assert_eq!(first, second, "{}", ty.name);
});

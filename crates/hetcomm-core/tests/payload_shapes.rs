//! Pins down how each Rust shape is written as MessagePack by `hetcomm_core::payload`
//! (rmp-serde with struct maps), and what the decoder accepts from other writers.
//! `docs/wire-format.md` quotes these bytes: if a dependency upgrade changes any of them, this
//! test fails before a peer written in another language notices.

use std::collections::BTreeMap;
use std::fmt::Debug;

use hetcomm_core::payload;
use serde::{de::DeserializeOwned, Deserialize, Serialize};
use serde_json::json;

fn hex(bytes: &[u8]) -> String {
    bytes.iter().map(|b| format!("{b:02x}")).collect()
}

fn unhex(s: &str) -> Vec<u8> {
    let s: String = s.split_whitespace().collect();
    (0..s.len())
        .step_by(2)
        .map(|i| u8::from_str_radix(&s[i..i + 2], 16).unwrap())
        .collect()
}

/// `value` encodes to exactly `expected_hex`, reads back as JSON `expected_json`, and decodes
/// back to itself.
fn check<T>(value: T, expected_hex: &str, expected_json: serde_json::Value)
where
    T: Serialize + DeserializeOwned + PartialEq + Debug,
{
    let bytes = payload::encode(&value).unwrap();
    assert_eq!(
        hex(&bytes),
        expected_hex.replace(' ', ""),
        "bytes of {value:?}"
    );
    assert_eq!(
        payload::to_json(&bytes).unwrap(),
        expected_json,
        "json of {value:?}"
    );
    assert_eq!(
        payload::decode::<T>(&bytes).unwrap(),
        value,
        "round trip of {value:?}"
    );
}

#[derive(Serialize, Deserialize, Debug, PartialEq)]
struct Wheels {
    left: f64,
    right: f64,
}

#[derive(Serialize, Deserialize, Debug, PartialEq)]
struct Pair(u8, u8);

#[derive(Serialize, Deserialize, Debug, PartialEq)]
struct Meters(f64);

#[derive(Serialize, Deserialize, Debug, PartialEq)]
struct Unit;

#[derive(Serialize, Deserialize, Debug, PartialEq)]
enum Cmd {
    Stop,
    Speed(f32),
    Turn(i8, i8),
    Go { x: u8 },
}

#[derive(Serialize, Deserialize, Debug, PartialEq)]
#[serde(tag = "type")]
enum Tagged {
    A { x: u8 },
}

#[derive(Serialize, Deserialize, Debug, PartialEq)]
struct Blob {
    #[serde(with = "serde_bytes")]
    data: Vec<u8>,
}

#[derive(Serialize, Deserialize, Debug, PartialEq)]
struct Opt {
    a: Option<u8>,
    #[serde(default, skip_serializing_if = "Option::is_none")]
    b: Option<u8>,
}

#[derive(Serialize, Deserialize, Debug, PartialEq)]
struct Renamed {
    #[serde(rename = "speedMps")]
    speed: u8,
}

#[test]
fn struct_is_a_map_keyed_by_field_name_in_declaration_order() {
    check(
        Wheels {
            left: -10.0,
            right: 10.0,
        },
        "82 a46c656674 cbc024000000000000 a57269676874 cb4024000000000000",
        json!({"left": -10.0, "right": 10.0}),
    );
    check(
        Renamed { speed: 3 },
        "81 a873706565644d7073 03",
        json!({"speedMps": 3}),
    );
}

#[test]
fn tuple_struct_is_an_array() {
    check(Pair(1, 2), "92 01 02", json!([1, 2]));
}

#[test]
fn newtype_struct_is_its_inner_value() {
    check(Meters(1.5), "cb3ff8000000000000", json!(1.5));
}

#[test]
fn unit_struct_is_an_empty_array_and_unit_is_nil() {
    check(Unit, "90", json!([]));
    check((), "c0", json!(null));
}

#[test]
fn enum_variants() {
    check(Cmd::Stop, "a4 53746f70", json!("Stop"));
    check(
        Cmd::Speed(0.5),
        "81 a5 5370656564 ca3f000000",
        json!({"Speed": 0.5}),
    );
    check(
        Cmd::Turn(-1, 1),
        "81 a4 5475726e 92 ff 01",
        json!({"Turn": [-1, 1]}),
    );
    check(
        Cmd::Go { x: 3 },
        "81 a2 476f 81 a1 78 03",
        json!({"Go": {"x": 3}}),
    );
    check(
        Tagged::A { x: 3 },
        "82 a4 74797065 a1 41 a1 78 03",
        json!({"type": "A", "x": 3}),
    );
}

#[test]
fn option_is_nil_or_the_value() {
    check(None::<u8>, "c0", json!(null));
    check(Some(5u8), "05", json!(5));
    check(Opt { a: None, b: None }, "81 a161 c0", json!({"a": null}));
    check(
        Opt {
            a: Some(1),
            b: Some(2),
        },
        "82 a161 01 a162 02",
        json!({"a": 1, "b": 2}),
    );
}

#[test]
fn bytes_are_an_int_array_unless_serde_bytes() {
    check(vec![1u8, 2, 255], "93 01 02 ccff", json!([1, 2, 255]));
    check([1u8, 2, 3, 4], "94 01 02 03 04", json!([1, 2, 3, 4]));
    // bin 8; to_json shows binary as an array of numbers too.
    check(
        Blob {
            data: vec![1, 2, 255],
        },
        "81 a464617461 c4 03 0102ff",
        json!({"data": [1, 2, 255]}),
    );
}

#[test]
fn floats_keep_their_width() {
    check(0.5f32, "ca3f000000", json!(0.5));
    check(0.5f64, "cb3fe0000000000000", json!(0.5));
    check(1.0f64, "cb3ff0000000000000", json!(1.0));
}

#[test]
fn integers_use_the_smallest_encoding_for_the_value() {
    check(5u64, "05", json!(5));
    check(5i32, "05", json!(5));
    check(200u8, "ccc8", json!(200));
    check(200i16, "ccc8", json!(200));
    check(-1i64, "ff", json!(-1));
    check(-100i64, "d09c", json!(-100));
    check(u64::MAX, "cfffffffffffffffff", json!(u64::MAX));
    check(i64::MIN, "d38000000000000000", json!(i64::MIN));
}

#[test]
fn wide_integers_are_16_byte_big_endian_bin() {
    check(
        1i128,
        "c410 00000000000000000000000000000001",
        json!([0, 0, 0, 0, 0, 0, 0, 0, 0, 0, 0, 0, 0, 0, 0, 1]),
    );
    check(
        u128::MAX,
        "c410 ffffffffffffffffffffffffffffffff",
        serde_json::Value::from(vec![255u8; 16]),
    );
}

#[test]
fn scalars_strings_tuples_and_maps() {
    check(true, "c3", json!(true));
    check(false, "c2", json!(false));
    check('é', "a2 c3a9", json!("é"));
    check("hi".to_string(), "a2 6869", json!("hi"));
    check(
        (1u8, "a".to_string(), true),
        "93 01 a161 c3",
        json!([1, "a", true]),
    );
    let by_str: BTreeMap<String, u8> = [("k".to_string(), 1)].into();
    check(by_str, "81 a16b 01", json!({"k": 1}));
    // Non-string keys stay integers on the wire; to_json prints them as strings.
    let by_int: BTreeMap<u16, String> = [(1, "a".to_string()), (2, "b".to_string())].into();
    check(by_int, "82 01 a161 02 a162", json!({"1": "a", "2": "b"}));
}

#[test]
fn decoder_accepts_what_other_writers_produce() {
    // Keys in any order, unknown keys ignored.
    let reordered = unhex("83 a5657874726105 a5726967687402 a46c656674 01");
    assert_eq!(
        payload::decode::<Wheels>(&reordered).unwrap(),
        Wheels {
            left: 1.0,
            right: 2.0
        }
    );
    // A struct written as an array of its fields, in declaration order.
    let as_array = unhex("92 cb3ff0000000000000 cb4000000000000000");
    assert_eq!(
        payload::decode::<Wheels>(&as_array).unwrap(),
        Wheels {
            left: 1.0,
            right: 2.0
        }
    );
    // Integers and float32 where the field is f64.
    let ints = payload::from_json(&json!({"left": 1, "right": 2})).unwrap();
    assert_eq!(
        payload::decode::<Wheels>(&ints).unwrap(),
        Wheels {
            left: 1.0,
            right: 2.0
        }
    );
    let f32s = unhex("82 a46c656674 ca3f000000 a57269676874 ca3e800000");
    assert_eq!(
        payload::decode::<Wheels>(&f32s).unwrap(),
        Wheels {
            left: 0.5,
            right: 0.25
        }
    );
    // A missing Option field is None.
    assert_eq!(
        payload::decode::<Opt>(&unhex("80")).unwrap(),
        Opt { a: None, b: None }
    );
    // A unit variant also as {name: nil} or as its index.
    assert_eq!(
        payload::decode::<Cmd>(&unhex("81 a453746f70 c0")).unwrap(),
        Cmd::Stop
    );
    assert_eq!(payload::decode::<Cmd>(&unhex("00")).unwrap(), Cmd::Stop);
}

#[test]
fn decoder_rejects_wrong_shapes() {
    // Out of range for the field type.
    assert!(payload::decode::<u8>(&unhex("cd012c")).is_err());
    // A missing non-Option field.
    assert!(payload::decode::<Wheels>(&unhex("81 a46c656674 01")).is_err());
    // An unknown variant name.
    assert!(payload::decode::<Cmd>(&unhex("a4 4a756d70")).is_err());
    // Trailing bytes.
    assert!(matches!(
        payload::decode::<u8>(&unhex("01 02")),
        Err(payload::PayloadError::Trailing { extra: 1, .. })
    ));
}

#[test]
fn from_json_writes_objects_as_maps_and_keeps_numbers_apart() {
    // serde_json's map is sorted by key.
    assert_eq!(
        hex(&payload::from_json(&json!({"b": 1, "a": 2})).unwrap()),
        "82a16102a16201"
    );
    assert_eq!(hex(&payload::from_json(&json!(1)).unwrap()), "01");
    assert_eq!(
        hex(&payload::from_json(&json!(1.0)).unwrap()),
        "cb3ff0000000000000"
    );
}

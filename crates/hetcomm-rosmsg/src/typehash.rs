//! ROS 2's type hash (REP 2011, `RIHS01_` and 64 hex digits): what Iron and later ROS 2
//! endpoints offer in their DDS `USER_DATA` as `typehash=RIHS01_…;`, so that two definitions
//! that share a type name but not a layout are told apart.
//!
//! The hash is SHA-256 of a JSON text: the type's own description (its name, then each
//! field's name and type) and the descriptions of every type it uses at any depth, sorted by
//! name. Default values, constants and comments are not part of it. A field's type is a
//! number (`type_id`: the primitive, `+ 48` for `T[N]`, `+ 96` for `T[<=N]`, `+ 144` for
//! `T[]`) with the array's size or bound (`capacity`), a string's bound
//! (`string_capacity`) and a nested type's name (`pkg/msg/Type`). As rosidl reads a `.msg`
//! file, `byte` is an octet (its own type id) and `char` is a `uint8`; an empty message has
//! one `uint8` field named `structure_needs_at_least_one_member`.
//!
//! [`crate::registry`] computes each ROS 2 type's [`description`] and hash when it resolves
//! the type ([`RosType::type_hash`]).

use std::collections::BTreeMap;

use sha2::{Digest, Sha256};

use crate::msgfile::{Array, Base, Field, Prim};
use crate::schema::{RosType, Ty};

/// `pkg/Type` as REP 2011 names it: `pkg/msg/Type`.
pub fn ros2_name(name: &str) -> String {
    match name.split_once('/') {
        Some((pkg, ty)) if !ty.contains('/') => format!("{pkg}/msg/{ty}"),
        _ => name.to_string(),
    }
}

/// rosidl's `FieldType` number of a field's base type (before its array part).
fn base_id(field: &Field) -> u8 {
    match &field.ty.base {
        Base::Msg(_) => 1,
        // rosidl reads `byte` as an octet and `char` as a uint8 (both are `Prim::U8` here).
        Base::Prim(Prim::U8) if field.ty.text.starts_with("byte") => 16,
        Base::Prim(p) => match p {
            Prim::I8 => 2,
            Prim::U8 => 3,
            Prim::I16 => 4,
            Prim::U16 => 5,
            Prim::I32 => 6,
            Prim::U32 => 7,
            Prim::I64 => 8,
            Prim::U64 => 9,
            Prim::F32 => 10,
            Prim::F64 => 11,
            Prim::Bool => 15,
        },
        Base::Str(None) => 17,
        Base::WStr(None) => 18,
        Base::Str(Some(_)) => 21,
        Base::WStr(Some(_)) => 22,
        // ROS 1 only; a ROS 2 file never has them.
        Base::Time | Base::Duration => 0,
    }
}

fn field_json(field: &Field) -> String {
    let (offset, capacity) = match field.ty.array {
        Array::No => (0, 0),
        Array::Fixed(n) => (48, n),
        Array::Bounded(n) => (96, n),
        Array::Unbounded => (144, 0),
    };
    let string_capacity = match field.ty.base {
        Base::Str(Some(n)) | Base::WStr(Some(n)) => n,
        _ => 0,
    };
    let nested = match &field.ty.base {
        Base::Msg(m) => ros2_name(m),
        _ => String::new(),
    };
    format!(
        "{{\"name\": \"{}\", \"type\": {{\"type_id\": {}, \"capacity\": {capacity}, \
         \"string_capacity\": {string_capacity}, \"nested_type_name\": \"{nested}\"}}}}",
        field.name,
        base_id(field) + offset,
    )
}

/// The individual type description of `name` (`pkg/Type`) with `fields`, as hashed: REP
/// 2011's JSON, default values left out. Names are ASCII letters, digits, `_` and `/`
/// (checked when the file was read), so nothing needs escaping.
pub fn description(name: &str, fields: &[Field]) -> String {
    let fields: Vec<String> = if fields.is_empty() {
        vec![format!(
            "{{\"name\": \"structure_needs_at_least_one_member\", \"type\": {{\"type_id\": 3, \
             \"capacity\": 0, \"string_capacity\": 0, \"nested_type_name\": \"\"}}}}"
        )]
    } else {
        fields.iter().map(field_json).collect()
    };
    format!(
        "{{\"type_name\": \"{}\", \"fields\": [{}]}}",
        ros2_name(name),
        fields.join(", ")
    )
}

/// The `RIHS01_…` hash of a type whose own description is `own` and whose fields use the
/// resolved types `deps` (each of which brings the types it uses).
pub fn type_hash(own: &str, deps: &[&'static RosType]) -> String {
    fn collect(t: &'static RosType, out: &mut BTreeMap<String, &'static str>) {
        if out.insert(ros2_name(t.name), t.description).is_none() {
            for (_, ty) in t.fields {
                let mut ty = ty;
                while let Ty::Array(e, _) | Ty::Seq(e, _) = ty {
                    ty = e;
                }
                if let Ty::Msg(m) = ty {
                    collect(m, out);
                }
            }
        }
    }
    let mut used = BTreeMap::new();
    for d in deps {
        collect(d, &mut used);
    }
    let used: Vec<&str> = used.into_values().collect();
    let json = format!(
        "{{\"type_description\": {own}, \"referenced_type_descriptions\": [{}]}}",
        used.join(", ")
    );
    let digest = Sha256::digest(json.as_bytes());
    let hex: String = digest.iter().map(|b| format!("{b:02x}")).collect();
    format!("RIHS01_{hex}")
}

/// The type hash a DDS endpoint offers in its `USER_DATA` (`typehash=RIHS01_…;`, among
/// other `key=value;` entries), if it offers one. `user_data` may be the parameter's raw
/// value (its CDR length first, padding after), as rustdds's discovery keeps it.
pub fn offered(user_data: &[u8]) -> Option<&str> {
    const KEY: &[u8] = b"typehash=";
    let at = user_data.windows(KEY.len()).position(|w| w == KEY)? + KEY.len();
    let rest = &user_data[at..];
    let end = rest.iter().position(|&b| b == b';').unwrap_or(rest.len());
    std::str::from_utf8(&rest[..end])
        .ok()
        .filter(|h| h.starts_with("RIHS01_"))
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::registry::Registry;
    use crate::schema::Flavour;

    /// Hashes that ROS 2 Jazzy endpoints offer for these types (as `ros2 topic info -v`
    /// prints them), for every shipped type whose hash was found published.
    const JAZZY: &str = include_str!("../msg/ros2-type-hashes.txt");

    #[test]
    fn shipped_types_hash_as_ros_2_jazzy_offers_them() {
        let mut n = 0;
        for line in JAZZY
            .lines()
            .filter(|l| !l.starts_with('#') && !l.is_empty())
        {
            let (name, hash) = line.split_once(' ').unwrap();
            let t = Flavour::Ros2
                .lookup(name)
                .unwrap_or_else(|| panic!("{name}"));
            assert_eq!(t.type_hash, hash, "{name}");
            n += 1;
        }
        assert!(n >= 30, "{n} hashes checked");
    }

    #[test]
    fn bounded_strings_and_every_array_form_hash_as_rosbags_computes_them() {
        // rosbags' own test vector (its test_msgs/msg/Hash), without its `char[4]` field:
        // rosbags reads `char` as rosidl's CHAR, rosidl as a uint8 (the shipped test above
        // checks std_msgs/Char). The expected value was computed by a script that gives
        // rosbags' published value for the full vector when `char` is read as CHAR.
        let dir = std::env::temp_dir().join(format!("hc-typehash-{}", std::process::id()));
        let msg = dir.join("test_msgs/msg");
        std::fs::create_dir_all(&msg).unwrap();
        std::fs::write(
            msg.join("Hash.msg"),
            "byte[4] array\nbyte[] sequence\nbyte[<=4] bounded_sequence\nstring str\n\
             string[4] array_of_str\nstring<=8 bounded_str\nstring<=8[4] array_of_bounded_str\n\
             string<=8[] sequence_of_bounded_str\nstring<=8[<=4] bounded_sequence_of_bounded_str\n",
        )
        .unwrap();
        let r = Registry::from_dirs(Flavour::Ros2, std::slice::from_ref(&dir)).unwrap();
        let t = r.resolve("test_msgs/Hash").unwrap();
        assert_eq!(
            t.type_hash,
            "RIHS01_480db448cf971df0a588aeb6fe21c85f65edc463dc7875f5d04c1763660d7fa2"
        );
        let _ = std::fs::remove_dir_all(&dir);
    }

    #[test]
    fn offered_hashes_are_read_from_user_data() {
        let h = "RIHS01_df668c740482bbd48fb39d76a70dfd4bd59db1288021743503259e948f6b1a18";
        assert_eq!(offered(format!("typehash={h};").as_bytes()), Some(h));
        assert_eq!(
            offered(format!("a=b;typehash={h};c=d;").as_bytes()),
            Some(h)
        );
        assert_eq!(offered(b""), None);
        assert_eq!(offered(b"typehash=;"), None);
        assert_eq!(offered(&[0xff, 0xfe]), None);
        // As rustdds keeps it: the CDR length first, padding after.
        let raw = [
            &[79u8, 0, 0, 0][..],
            format!("typehash={h};").as_bytes(),
            &[0],
        ]
        .concat();
        assert_eq!(offered(&raw), Some(h));
        assert_eq!(
            Flavour::Ros1.lookup("std_msgs/String").unwrap().type_hash,
            ""
        );
    }
}

//! Property tests of the conversion written from the definitions: every shipped type of both
//! flavours, over generated values (`uint8` arrays as bytes), encodes and decodes back to the same value in its wire
//! encoding (ROS 1 serialization for ROS 1 types, CDR for ROS 2 types); any cut of an
//! encoding, and arbitrary bytes in any encoding, are an error or a value, never a panic.

use hetcomm_rosmsg::codec::{decode, encode, Wire};
use hetcomm_rosmsg::schema::{Flavour, RosType, Ty};
use proptest::prelude::*;
use proptest::test_runner::{Config, TestRunner};
use rmpv::Value;

/// Generated values of `ty`; arrays without a fixed size get 0 to 3 elements.
fn value_of(ty: &'static Ty) -> BoxedStrategy<Value> {
    match ty {
        Ty::Bool => any::<bool>().prop_map(Value::from).boxed(),
        Ty::I8 => any::<i8>().prop_map(Value::from).boxed(),
        Ty::U8 => any::<u8>().prop_map(Value::from).boxed(),
        Ty::I16 => any::<i16>().prop_map(Value::from).boxed(),
        Ty::U16 => any::<u16>().prop_map(Value::from).boxed(),
        Ty::I32 => any::<i32>().prop_map(Value::from).boxed(),
        Ty::U32 => any::<u32>().prop_map(Value::from).boxed(),
        Ty::I64 => any::<i64>().prop_map(Value::from).boxed(),
        Ty::U64 => any::<u64>().prop_map(Value::from).boxed(),
        // Finite, so that a value equals itself.
        Ty::F32 => proptest::num::f32::NORMAL.prop_map(Value::F32).boxed(),
        Ty::F64 => proptest::num::f64::NORMAL.prop_map(Value::F64).boxed(),
        Ty::Str => "[a-zA-Z0-9 _é∂]{0,12}".prop_map(Value::from).boxed(),
        Ty::BoundedStr(n) => proptest::collection::vec(
            any::<char>().prop_filter("ascii", char::is_ascii_alphanumeric),
            0..=*n,
        )
        .prop_map(|c| Value::from(c.into_iter().collect::<String>()))
        .boxed(),
        // uint8 arrays come back as bytes (MessagePack bin).
        Ty::Array(Ty::U8, n) => proptest::collection::vec(any::<u8>(), *n)
            .prop_map(Value::Binary)
            .boxed(),
        Ty::Seq(Ty::U8, bound) => {
            proptest::collection::vec(any::<u8>(), 0..=bound.unwrap_or(3).min(3))
                .prop_map(Value::Binary)
                .boxed()
        }
        Ty::Array(elem, n) => proptest::collection::vec(value_of(elem), *n)
            .prop_map(Value::Array)
            .boxed(),
        Ty::Seq(elem, bound) => {
            proptest::collection::vec(value_of(elem), 0..=bound.unwrap_or(3).min(3))
                .prop_map(Value::Array)
                .boxed()
        }
        Ty::Msg(m) => message_of(m),
    }
}

fn message_of(m: &'static RosType) -> BoxedStrategy<Value> {
    let fields: Vec<BoxedStrategy<(Value, Value)>> = m
        .fields
        .iter()
        .map(|(name, ty)| {
            let name = Value::from(*name);
            value_of(ty).prop_map(move |v| (name.clone(), v)).boxed()
        })
        .collect();
    fields.prop_map(Value::Map).boxed()
}

fn every_shipped_type() -> Vec<(Flavour, &'static RosType)> {
    hetcomm_rosmsg::registry::every_shipped_type().expect("the shipped types resolve")
}

fn wire(f: Flavour) -> Wire {
    match f {
        Flavour::Ros1 => Wire::Ros1,
        Flavour::Ros2 => Wire::CDR,
    }
}

#[test]
fn every_shipped_type_round_trips_over_generated_values() {
    let types = every_shipped_type();
    assert!(types.len() > 200, "{}", types.len());
    for (flavour, ty) in types {
        let mut runner = TestRunner::new(Config {
            cases: 24,
            failure_persistence: None,
            ..Config::default()
        });
        let w = wire(flavour);
        runner
            .run(&message_of(ty), |value| {
                let body = encode(&value, ty, w, "generated").map_err(TestCaseError::fail)?;
                let back = decode(&body, ty, w).map_err(TestCaseError::fail)?;
                prop_assert_eq!(&back, &value);
                // Every cut is an error (ROS 1 also refuses extra bytes), never a panic.
                for cut in 0..body.len() {
                    let _ = decode(&body[..cut], ty, w);
                }
                if w == Wire::Ros1 && !body.is_empty() {
                    prop_assert!(decode(&body[..body.len() - 1], ty, w).is_err());
                    let mut longer = body.clone();
                    longer.push(0);
                    prop_assert!(decode(&longer, ty, w).is_err());
                }
                Ok(())
            })
            .unwrap_or_else(|e| panic!("{flavour:?} {}: {e}", ty.name));
    }
}

#[test]
fn arbitrary_bytes_never_panic_and_huge_lengths_do_not_allocate() {
    let types = every_shipped_type();
    let mut runner = TestRunner::new(Config {
        cases: 64,
        failure_persistence: None,
        ..Config::default()
    });
    runner
        .run(&proptest::collection::vec(any::<u8>(), 0..96), |bytes| {
            for (flavour, ty) in &types {
                let _ = decode(&bytes, ty, wire(*flavour));
                let _ = decode(
                    &bytes,
                    ty,
                    Wire::Cdr {
                        little: false,
                        xcdr2: true,
                    },
                );
            }
            Ok(())
        })
        .unwrap();
    // sensor_msgs/PointCloud2's first unbounded array announcing 4 billion fields is refused
    // for the bytes left, at once.
    let cloud = Flavour::Ros1.lookup("sensor_msgs/PointCloud2").unwrap();
    let mut body = vec![0u8; 12]; // header: seq, stamp
    body.extend_from_slice(&0u32.to_le_bytes()); // frame_id ""
    body.extend_from_slice(&[0; 8]); // height, width
    body.extend_from_slice(&u32::MAX.to_le_bytes()); // fields[] length
    let e = decode(&body, cloud, Wire::Ros1).unwrap_err();
    assert_eq!(
        e,
        "`fields` has 4294967295 elements, more than the 0 bytes left can hold"
    );
}

#[test]
fn a_ros_2_custom_type_with_bounds_defaults_and_time_converts_and_checks_its_bounds() {
    let dir = std::env::temp_dir().join(format!("hc_ros2_msgs_{}", std::process::id()));
    let pkg = dir.join("share/my_robot_msgs/msg");
    std::fs::create_dir_all(&pkg).unwrap();
    std::fs::write(
        pkg.join("Status.msg"),
        "uint8 OK = 0\nstd_msgs/Header header\nstring<=4 code \"ok\"\nint16[<=2] levels\n\
         builtin_interfaces/Duration uptime\nuint64 count 7\n",
    )
    .unwrap();
    let r =
        hetcomm_rosmsg::registry::Registry::from_dirs(Flavour::Ros2, &[dir.join("share")]).unwrap();
    let ty = r.resolve("my_robot_msgs/msg/Status").unwrap();
    let map = |pairs: Vec<(&str, Value)>| {
        Value::Map(
            pairs
                .into_iter()
                .map(|(k, v)| (Value::from(k), v))
                .collect(),
        )
    };
    let value = |code: &str, levels: Vec<i16>| {
        map(vec![
            (
                "header",
                map(vec![
                    ("stamp", map(vec![("sec", 1.into()), ("nanosec", 2.into())])),
                    ("frame_id", "base".into()),
                ]),
            ),
            ("code", code.into()),
            (
                "levels",
                Value::Array(levels.into_iter().map(Value::from).collect()),
            ),
            (
                "uptime",
                map(vec![("sec", (-3).into()), ("nanosec", 4.into())]),
            ),
            ("count", u64::MAX.into()),
        ])
    };
    let v = value("warn", vec![-1, 2]);
    let cdr = encode(&v, ty, Wire::CDR, "Status").unwrap();
    assert_eq!(decode(&cdr, ty, Wire::CDR).unwrap(), v);
    assert_eq!(
        encode(&value("broken", vec![]), ty, Wire::CDR, "Status").unwrap_err(),
        "Status does not convert to my_robot_msgs/Status: field `code` has 6 bytes, the ROS \
         field has at most 4"
    );
    assert_eq!(
        encode(&value("ok", vec![1, 2, 3]), ty, Wire::CDR, "Status").unwrap_err(),
        "Status does not convert to my_robot_msgs/Status: field `levels` has 3 elements, the \
         ROS field has at most 2"
    );
    std::fs::remove_dir_all(&dir).unwrap();
}

//! Tests of `codec.rs`: round trips and refusals of both encodings.

use super::*;
use crate::schema::Flavour;

fn ros1(name: &str) -> &'static RosType {
    Flavour::Ros1.lookup(name).unwrap()
}

fn ros2(name: &str) -> &'static RosType {
    Flavour::Ros2.lookup(name).unwrap()
}

fn map(pairs: &[(&str, Value)]) -> Value {
    Value::Map(
        pairs
            .iter()
            .map(|(k, v)| (Value::from(*k), v.clone()))
            .collect(),
    )
}

fn vec3(x: f64, y: f64, z: f64) -> Value {
    map(&[("x", x.into()), ("y", y.into()), ("z", z.into())])
}

fn pose() -> Value {
    map(&[
        ("position", vec3(1.0, 2.0, 0.0)),
        (
            "orientation",
            map(&[
                ("x", 0.0.into()),
                ("y", 0.0.into()),
                ("z", 0.0.into()),
                ("w", 1.0.into()),
            ]),
        ),
    ])
}

#[test]
fn a_twist_round_trips_and_its_cdr_is_what_ros_2_writes() {
    let twist = map(&[
        ("linear", vec3(0.5, 0.0, 0.0)),
        ("angular", vec3(0.0, 0.0, 0.25)),
    ]);
    let cdr = encode(
        &twist,
        ros2("geometry_msgs/Twist"),
        Wire::CDR,
        "Command (type 40)",
    )
    .unwrap();
    assert_eq!(cdr.len(), 48);
    assert_eq!(&cdr[..8], &0.5f64.to_le_bytes());
    assert_eq!(
        decode(&cdr, ros2("geometry_msgs/Twist"), Wire::CDR).unwrap(),
        twist
    );
    // Six float64s have no padding either way: ROS 1's body is the same bytes.
    assert_eq!(
        encode(&twist, ros2("geometry_msgs/Twist"), Wire::Ros1, "C").unwrap(),
        cdr
    );
}

#[test]
fn strings_and_nested_headers_are_aligned_as_cdr_says() {
    let header = map(&[
        ("stamp", map(&[("sec", 5.into()), ("nanosec", 7u32.into())])),
        ("frame_id", "map".into()),
    ]);
    let stamped = map(&[("header", header), ("pose", pose())]);
    let cdr = encode(
        &stamped,
        ros2("geometry_msgs/PoseStamped"),
        Wire::CDR,
        "Fix",
    )
    .unwrap();
    // sec, nanosec, len 4, "map\0", then the first float64 at offset 16.
    assert_eq!(&cdr[8..16], &[4, 0, 0, 0, b'm', b'a', b'p', 0]);
    assert_eq!(&cdr[16..24], &1.0f64.to_le_bytes());
    let back = decode(&cdr, ros2("geometry_msgs/PoseStamped"), Wire::CDR).unwrap();
    assert_eq!(back, stamped);
}

#[test]
fn ros_1_bodies_are_packed_with_a_seq_and_strings_without_nul() {
    let header = map(&[
        ("seq", 9u32.into()),
        (
            "stamp",
            map(&[("secs", 5u32.into()), ("nsecs", 7u32.into())]),
        ),
        ("frame_id", "map".into()),
    ]);
    let stamped = map(&[("header", header), ("pose", pose())]);
    let body = encode(
        &stamped,
        ros1("geometry_msgs/PoseStamped"),
        Wire::Ros1,
        "Fix",
    )
    .unwrap();
    // seq, secs, nsecs, len 3, "map", then the first float64 right after (byte 19).
    assert_eq!(&body[..4], &9u32.to_le_bytes());
    assert_eq!(&body[12..19], &[3, 0, 0, 0, b'm', b'a', b'p']);
    assert_eq!(&body[19..27], &1.0f64.to_le_bytes());
    assert_eq!(body.len(), 19 + 7 * 8);
    assert_eq!(
        decode(&body, ros1("geometry_msgs/PoseStamped"), Wire::Ros1).unwrap(),
        stamped
    );
    // A ROS 2 header is not a ROS 1 header: the field is named.
    let ros2_header = map(&[
        (
            "header",
            map(&[("stamp", map(&[])), ("frame_id", "".into())]),
        ),
        ("pose", pose()),
    ]);
    let err = encode(
        &ros2_header,
        ros1("geometry_msgs/PoseStamped"),
        Wire::Ros1,
        "Fix",
    )
    .unwrap_err();
    assert_eq!(
        err,
        "Fix does not convert to geometry_msgs/PoseStamped: field `header.seq` of \
         std_msgs/Header is missing"
    );
}

#[test]
fn mismatches_name_both_types_and_the_field() {
    let missing = map(&[("linear", vec3(1.0, 0.0, 0.0))]);
    assert_eq!(
        encode(
            &missing,
            ros2("geometry_msgs/Twist"),
            Wire::CDR,
            "Command (type 40)"
        )
        .unwrap_err(),
        "Command (type 40) does not convert to geometry_msgs/Twist: field `angular` of \
         geometry_msgs/Twist is missing"
    );
    let extra = map(&[("data", 1.0.into()), ("unit", "m".into())]);
    assert_eq!(
        encode(
            &extra,
            ros2("std_msgs/Float64"),
            Wire::Ros1,
            "Range (type 7)"
        )
        .unwrap_err(),
        "Range (type 7) does not convert to std_msgs/Float64: field `unit` has no \
         counterpart in std_msgs/Float64"
    );
    let wrong = map(&[("data", "high".into())]);
    assert_eq!(
        encode(
            &wrong,
            ros2("std_msgs/Float64"),
            Wire::CDR,
            "Range (type 7)"
        )
        .unwrap_err(),
        "Range (type 7) does not convert to std_msgs/Float64: field `data` is a string, \
         the ROS field is float64"
    );
}

#[test]
fn truncated_or_garbled_bodies_are_an_error_not_a_panic() {
    for wire in [Wire::CDR, Wire::Ros1] {
        let body = encode(
            &map(&[("data", "hello".into())]),
            ros2("std_msgs/String"),
            wire,
            "T",
        )
        .unwrap();
        for cut in 0..body.len() - 1 {
            assert!(
                decode(&body[..cut], ros2("std_msgs/String"), wire).is_err(),
                "cut at {cut}"
            );
        }
        let mut huge = body.clone();
        huge[..4].copy_from_slice(&u32::MAX.to_le_bytes());
        assert!(decode(&huge, ros2("std_msgs/String"), wire).is_err());
        assert!(decode(&[1, 2, 3], ros1("nav_msgs/Odometry"), wire).is_err());
    }
    // A std_msgs/String "abcdef" read as a Float64 on ROS 1 is refused for its length.
    let s = encode(
        &map(&[("data", "abcdef".into())]),
        ros2("std_msgs/String"),
        Wire::Ros1,
        "T",
    )
    .unwrap();
    assert_eq!(
        decode(&s, ros2("std_msgs/Float64"), Wire::Ros1).unwrap_err(),
        "2 bytes are left after the message (10 bytes)"
    );
}

fn image(data: Value, ros1_header: bool) -> Value {
    let stamp = match ros1_header {
        true => map(&[("secs", 5u32.into()), ("nsecs", 7u32.into())]),
        false => map(&[("sec", 5.into()), ("nanosec", 7u32.into())]),
    };
    let mut header = vec![("stamp", stamp), ("frame_id", "camera".into())];
    if ros1_header {
        header.insert(0, ("seq", 3u32.into()));
    }
    map(&[
        ("header", map(&header)),
        ("height", 480u32.into()),
        ("width", 640u32.into()),
        ("encoding", "rgb8".into()),
        ("is_bigendian", 0u8.into()),
        ("step", 1920u32.into()),
        ("data", data),
    ])
}

#[test]
fn a_640_by_480_image_goes_whole_from_bytes_or_integers_and_comes_back_as_bytes() {
    let pixels: Vec<u8> = (0..640 * 480 * 3).map(|i| (i % 251) as u8).collect();
    let as_ints = Value::Array(pixels.iter().map(|b| Value::from(*b)).collect());
    for (wire, flavour) in [
        (Wire::CDR, ros2("sensor_msgs/Image")),
        (Wire::Ros1, ros1("sensor_msgs/Image")),
    ] {
        let ros1 = wire == Wire::Ros1;
        let body = encode(
            &image(Value::Binary(pixels.clone()), ros1),
            flavour,
            wire,
            "Image",
        )
        .unwrap();
        // The pixels are the message's last bytes, after their length.
        assert_eq!(&body[body.len() - pixels.len()..], &pixels[..]);
        let len = body.len() - pixels.len() - 4;
        assert_eq!(&body[len..len + 4], &(pixels.len() as u32).to_le_bytes());
        assert_eq!(
            encode(&image(as_ints.clone(), ros1), flavour, wire, "Image").unwrap(),
            body
        );
        assert_eq!(
            decode(&body, flavour, wire).unwrap(),
            image(Value::Binary(pixels.clone()), ros1)
        );
        // One byte short: the pixels do not fit, whatever the wire.
        assert!(decode(&body[..body.len() - 1], flavour, wire).is_err());
    }
    // An element that does not convert is named by its index.
    let mut bad = pixels.iter().map(|b| Value::from(*b)).collect::<Vec<_>>();
    bad[1000] = Value::from(256);
    let e = encode(
        &image(Value::Array(bad), false),
        ros2("sensor_msgs/Image"),
        Wire::CDR,
        "Image",
    )
    .unwrap_err();
    assert!(
        e.ends_with("field `data[1000]` is an integer (256), the ROS field is uint8"),
        "{e}"
    );
}

//! ROS 2 types read from `.idl` files (what a package that ships only IDL installs): the
//! schema and type hash are those of the same type read from its `.msg`, and malformed IDL is
//! an error at `file:line`.

use std::path::{Path, PathBuf};

use hetcomm_rosmsg::registry::Registry;
use hetcomm_rosmsg::schema::Flavour;

fn temp(tag: &str) -> PathBuf {
    let d = std::env::temp_dir().join(format!("hc-idl-{tag}-{}", std::process::id()));
    let _ = std::fs::remove_dir_all(&d);
    d
}

fn write(dir: &Path, rel: &str, text: &str) {
    let p = dir.join(rel);
    std::fs::create_dir_all(p.parent().unwrap()).unwrap();
    std::fs::write(p, text).unwrap();
}

/// As rosidl_adapter writes them from the upstream `.msg` files.
const POSE_WITH_COVARIANCE: &str = r#"// generated from rosidl_adapter/resource/msg.idl.em
// with input from geometry_msgs/msg/PoseWithCovariance.msg
// generated code does not contain a copyright notice

#include "geometry_msgs/msg/Pose.idl"

module geometry_msgs {
  module msg {
    typedef double double__36[36];
    @verbatim (language="comment", text=
      "This represents a pose in free space with uncertainty.")
    struct PoseWithCovariance {
      geometry_msgs::msg::Pose pose;

      @verbatim (language="comment", text=
        "Row-major representation of the 6x6 covariance matrix" "\n"
        "The orientation parameters use a fixed-axis representation.")
      double__36 covariance;
    };
  };
};
"#;

const NAV_SAT_STATUS: &str = r#"// generated from rosidl_adapter/resource/msg.idl.em
module sensor_msgs {
  module msg {
    module NavSatStatus_Constants {
      @verbatim (language="comment", text=
        "unable to fix position")
      const int8 STATUS_NO_FIX = -1;
      const int8 STATUS_FIX = 0;
      const int8 STATUS_SBAS_FIX = 1;
      const int8 STATUS_GBAS_FIX = 2;
      const uint16 SERVICE_GPS = 1;
      const uint16 SERVICE_GLONASS = 2;
      const uint16 SERVICE_COMPASS = 4;
      const uint16 SERVICE_GALILEO = 8;
    };
    /* Navigation Satellite fix status for any Global Navigation Satellite System. */
    struct NavSatStatus {
      int8 status;
      uint16 service;
    };
  };
};
"#;

const EMPTY: &str = r#"module std_msgs {
  module msg {
    struct Empty {
      uint8 structure_needs_at_least_one_member;
    };
  };
};
"#;

/// Every member form, and the `.msg` that says the same.
const STATUS_IDL: &str = r#"#include "builtin_interfaces/msg/Duration.idl"
#include "geometry_msgs/msg/Point.idl"
module my_robot_msgs {
  module msg {
    module Status_Constants {
      const uint8 MODE_IDLE = 0;
      const string NAME = "rover";
    };
    typedef float float__3[3];
    typedef geometry_msgs::msg::Point geometry_msgs__msg__Point__2[2];
    typedef string<8> string__8__4[4];
    struct Status {
      boolean ok;
      octet raw;
      uint8 mode;
      @default (value=7)
      int16 level;
      unsigned short count;
      long steps;
      unsigned long ticks;
      long long big;
      unsigned long long bigger;
      double speed;
      float__3 gains;
      string name;
      string<16> label;
      string__8__4 tags;
      sequence<string<8>> notes;
      sequence<string<8>, 4> few_notes;
      sequence<octet> data;
      sequence<double, 10> history;
      builtin_interfaces::msg::Duration age;
      geometry_msgs__msg__Point__2 ends;
      sequence<geometry_msgs::msg::Point> path;
      Sub sub;
    };
  };
};
"#;

const SUB_IDL: &str = r#"module my_robot_msgs { module msg { struct Sub { int32 x; }; }; };"#;

const STATUS_MSG: &str =
    "uint8 MODE_IDLE=0\nstring NAME=\"rover\"\nbool ok\nbyte raw\nuint8 mode\n\
int16 level 7\nuint16 count\nint32 steps\nuint32 ticks\nint64 big\nuint64 bigger\nfloat64 speed\n\
float32[3] gains\nstring name\nstring<=16 label\nstring<=8[4] tags\nstring<=8[] notes\n\
string<=8[<=4] few_notes\nbyte[] data\nfloat64[<=10] history\nbuiltin_interfaces/Duration age\n\
geometry_msgs/Point[2] ends\ngeometry_msgs/Point[] path\nSub sub\n";

#[test]
fn shipped_types_read_from_idl_have_the_schema_and_hash_of_their_msg() {
    let dir = temp("shipped");
    write(
        &dir,
        "geometry_msgs/msg/PoseWithCovariance.idl",
        POSE_WITH_COVARIANCE,
    );
    write(&dir, "sensor_msgs/msg/NavSatStatus.idl", NAV_SAT_STATUS);
    write(&dir, "std_msgs/msg/Empty.idl", EMPTY);
    let r = Registry::from_dirs(Flavour::Ros2, std::slice::from_ref(&dir)).unwrap();
    for (name, hash) in [
        (
            "geometry_msgs/PoseWithCovariance",
            "RIHS01_9a7c0fd234b7f45c6098745ecccd773ca1085670e64107135397aee31c02e1bb",
        ),
        (
            "sensor_msgs/NavSatStatus",
            "RIHS01_d1ed3befa628e09571bd273b888ba1c1fd187c9a5e0006b385d7e5e9095a3204",
        ),
        (
            "std_msgs/Empty",
            "RIHS01_20b625256f32d5dbc0d04fee44f43c41e51c70d3502f84b4a08e7a9c26a96312",
        ),
    ] {
        let from_idl = r.resolve(name).unwrap();
        let from_msg = Flavour::Ros2.lookup(name).unwrap();
        assert!(
            !std::ptr::eq(from_idl, from_msg),
            "{name} was read from its IDL"
        );
        assert_eq!(from_idl.type_hash, hash, "{name}");
        assert_eq!(
            format!("{:?}", from_idl.fields),
            format!("{:?}", from_msg.fields),
            "{name}"
        );
    }
    let status = r.resolve("sensor_msgs/NavSatStatus").unwrap();
    assert_eq!(status.constants.len(), 8);
    assert_eq!(status.constants[0], ("int8", "STATUS_NO_FIX", "-1"));
    let _ = std::fs::remove_dir_all(&dir);
}

#[test]
fn every_member_form_reads_as_its_msg_spelling() {
    let (idl, msg) = (temp("status-idl"), temp("status-msg"));
    write(&idl, "my_robot_msgs/msg/Status.idl", STATUS_IDL);
    write(&idl, "my_robot_msgs/msg/Sub.idl", SUB_IDL);
    write(&msg, "my_robot_msgs/msg/Status.msg", STATUS_MSG);
    write(&msg, "my_robot_msgs/msg/Sub.msg", "int32 x\n");
    let a = Registry::from_dirs(Flavour::Ros2, std::slice::from_ref(&idl)).unwrap();
    let b = Registry::from_dirs(Flavour::Ros2, std::slice::from_ref(&msg)).unwrap();
    let (a, b) = (
        a.resolve("my_robot_msgs/Status").unwrap(),
        b.resolve("my_robot_msgs/Status").unwrap(),
    );
    // All but the last field (`Sub sub`, whose definition text is its IDL or its .msg).
    assert_eq!(a.fields.len(), 22);
    assert_eq!(
        format!("{:?}", &a.fields[..21]),
        format!("{:?}", &b.fields[..21])
    );
    let sub = |t: &hetcomm_rosmsg::schema::Ty| match t {
        hetcomm_rosmsg::schema::Ty::Msg(m) => (format!("{:?}", m.fields), m.type_hash),
        other => panic!("{other:?}"),
    };
    assert_eq!(sub(&a.fields[21].1), sub(&b.fields[21].1));
    assert_eq!(a.constants, b.constants);
    assert_eq!(a.type_hash, b.type_hash);
    assert!(a.type_hash.starts_with("RIHS01_"));
    let _ = std::fs::remove_dir_all(&idl);
    let _ = std::fs::remove_dir_all(&msg);
}

#[test]
fn a_msg_beside_an_idl_of_the_same_type_is_the_one_read() {
    let dir = temp("both");
    write(&dir, "my_robot_msgs/msg/Sub.idl", SUB_IDL);
    write(&dir, "my_robot_msgs/msg/Sub.msg", "int64 y\n");
    let r = Registry::from_dirs(Flavour::Ros2, std::slice::from_ref(&dir)).unwrap();
    assert_eq!(r.resolve("my_robot_msgs/Sub").unwrap().fields[0].0, "y");
    // ROS 1 reads no IDL.
    let dir1 = temp("ros1");
    write(&dir1, "my_robot_msgs/msg/Sub.idl", SUB_IDL);
    let r1 = Registry::from_dirs(Flavour::Ros1, std::slice::from_ref(&dir1)).unwrap();
    assert!(r1.resolve("my_robot_msgs/Sub").is_err());
    let _ = std::fs::remove_dir_all(&dir);
    let _ = std::fs::remove_dir_all(&dir1);
}

#[test]
fn malformed_idl_is_an_error_at_its_line() {
    let cases = [
        (
            "module p { module msg {\n struct T {\n  int32 x\n };\n}; };",
            "T.idl:4: expected `;`, found `}`",
        ),
        (
            "module p { module msg {\n struct T {\n  char c;\n }; }; };",
            "T.idl:3: IDL `char` is not converted by the bridges (a `.msg` `char` is IDL `uint8`)",
        ),
        (
            "module p { module msg {\n struct T {\n  sequence<sequence<int32>> x;\n }; }; };",
            "T.idl:3: a sequence of sequences has no ROS message type",
        ),
        (
            "module p { module msg {\n struct T {\n  int32 Bad;\n }; }; };",
            "T.idl:3: `Bad` is not a field name",
        ),
        (
            "module p { module msg {\n struct U { int32 x; };\n }; };",
            "T.idl:1: no `struct T` in `module p { module msg { … }; };`",
        ),
        (
            "module p { module msg {\n /* open\n\n struct T { int32 x; }; }; };",
            "T.idl:2: a `/*` comment is never closed",
        ),
        (
            "module p { module msg {\n union T { int32 x; };\n }; };",
            "T.idl:2: unexpected `union`: a message's IDL has modules, typedefs, constants and one struct",
        ),
        (
            "module p { module msg {\n module T_Constants {\n  const uint8 BIG = 300;\n };\n struct T { int32 x; }; }; };",
            "T.idl:3: constant `BIG`: ",
        ),
        ("module p {", "T.idl:1: the file ends inside a declaration"),
    ];
    for (text, expected) in cases {
        let e = hetcomm_rosmsg::idlfile::parse(text, "T.idl", "p", "T")
            .unwrap_err()
            .to_string();
        assert!(
            e.starts_with(expected),
            "{text}\n  gave: {e}\n  want: {expected}"
        );
    }
}

#[test]
fn every_cut_of_an_idl_file_is_an_error_never_a_panic() {
    for (text, pkg, name) in [
        (STATUS_IDL, "my_robot_msgs", "Status"),
        (POSE_WITH_COVARIANCE, "geometry_msgs", "PoseWithCovariance"),
        (NAV_SAT_STATUS, "sensor_msgs", "NavSatStatus"),
    ] {
        assert!(hetcomm_rosmsg::idlfile::parse(text, "c.idl", pkg, name).is_ok());
        for (cut, _) in text
            .char_indices()
            .filter(|&(i, _)| i < text.trim_end().len())
        {
            // Every proper prefix lacks the struct or ends inside a declaration.
            let r = hetcomm_rosmsg::idlfile::parse(&text[..cut], "c.idl", pkg, name);
            assert!(r.is_err(), "{name} cut at {cut} parsed");
        }
    }
}

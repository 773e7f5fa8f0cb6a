//! The standard ROS message types a bridge knows, as schemas ([`RosType`]), for ROS 1
//! ([`ros1`]) and ROS 2 ([`ros2`]).
//!
//! Both flavours share every type but the header: ROS 1's `std_msgs/Header` is `seq`, `stamp`
//! (`time`: `secs`, `nsecs`) and `frame_id`; ROS 2's is `stamp` (`builtin_interfaces/Time`:
//! `sec`, `nanosec`) and `frame_id`. So `geometry_msgs/PoseStamped`, `nav_msgs/Odometry` and
//! `sensor_msgs/NavSatFix` exist once per flavour; the others once.

/// A field's type.
#[derive(Debug)]
pub enum Ty {
    /// `bool`.
    Bool,
    /// `int8`.
    I8,
    /// `uint8`.
    U8,
    /// `uint16`.
    U16,
    /// `int32`.
    I32,
    /// `uint32`.
    U32,
    /// `float64`.
    F64,
    /// `string`.
    Str,
    /// `T[N]`: exactly N elements, no length on the wire.
    Array(&'static Ty, usize),
    /// A nested message.
    Msg(&'static RosType),
}

/// A ROS message type: its name (`pkg/Type`) and fields in order.
#[derive(Debug)]
pub struct RosType {
    /// `pkg/Type`, e.g. `geometry_msgs/Twist`.
    pub name: &'static str,
    /// Fields, in wire order.
    pub fields: &'static [(&'static str, Ty)],
}

/// Which ROS a schema is for.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum Flavour {
    /// ROS 1 (TCPROS, ROS 1 serialization).
    Ros1,
    /// ROS 2 (DDS, CDR).
    Ros2,
}

impl Flavour {
    /// "ROS 1" or "ROS 2", for messages.
    pub fn label(self) -> &'static str {
        match self {
            Flavour::Ros1 => "ROS 1",
            Flavour::Ros2 => "ROS 2",
        }
    }

    /// The types a bridge of this flavour can map.
    pub fn known(self) -> &'static [&'static RosType; 7] {
        match self {
            Flavour::Ros1 => &ros1::KNOWN,
            Flavour::Ros2 => &ros2::KNOWN,
        }
    }

    /// The known type named `name` (`pkg/Type` or `pkg/msg/Type`).
    pub fn lookup(self, name: &str) -> Option<&'static RosType> {
        let short = match name.split('/').collect::<Vec<_>>()[..] {
            [pkg, "msg", ty] => format!("{pkg}/{ty}"),
            _ => name.to_string(),
        };
        self.known().iter().copied().find(|t| t.name == short)
    }

    /// The names of the known types, for help texts.
    pub fn known_names(self) -> String {
        let names: Vec<_> = self.known().iter().map(|t| t.name).collect();
        names.join(", ")
    }
}

macro_rules! ros_type {
    ($id:ident, $name:literal, [$(($f:literal, $t:expr)),* $(,)?]) => {
        #[doc = concat!("`", $name, "`.")]
        pub static $id: RosType = RosType { name: $name, fields: &[$(($f, $t)),*] };
    };
}

ros_type!(STRING, "std_msgs/String", [("data", Ty::Str)]);
ros_type!(FLOAT64, "std_msgs/Float64", [("data", Ty::F64)]);
ros_type!(
    VECTOR3,
    "geometry_msgs/Vector3",
    [("x", Ty::F64), ("y", Ty::F64), ("z", Ty::F64)]
);
ros_type!(
    POINT,
    "geometry_msgs/Point",
    [("x", Ty::F64), ("y", Ty::F64), ("z", Ty::F64)]
);
ros_type!(
    QUATERNION,
    "geometry_msgs/Quaternion",
    [
        ("x", Ty::F64),
        ("y", Ty::F64),
        ("z", Ty::F64),
        ("w", Ty::F64)
    ]
);
ros_type!(
    TWIST,
    "geometry_msgs/Twist",
    [
        ("linear", Ty::Msg(&VECTOR3)),
        ("angular", Ty::Msg(&VECTOR3))
    ]
);
ros_type!(
    POSE,
    "geometry_msgs/Pose",
    [
        ("position", Ty::Msg(&POINT)),
        ("orientation", Ty::Msg(&QUATERNION))
    ]
);
static COV: Ty = Ty::F64;
ros_type!(
    POSE_WITH_COVARIANCE,
    "geometry_msgs/PoseWithCovariance",
    [
        ("pose", Ty::Msg(&POSE)),
        ("covariance", Ty::Array(&COV, 36))
    ]
);
ros_type!(
    TWIST_WITH_COVARIANCE,
    "geometry_msgs/TwistWithCovariance",
    [
        ("twist", Ty::Msg(&TWIST)),
        ("covariance", Ty::Array(&COV, 36))
    ]
);
ros_type!(
    NAV_SAT_STATUS,
    "sensor_msgs/NavSatStatus",
    [("status", Ty::I8), ("service", Ty::U16)]
);

/// The types that contain a header, and the list of known types, for one flavour's `HEADER`.
macro_rules! stamped_types {
    () => {
        use super::*;

        ros_type!(
            POSE_STAMPED,
            "geometry_msgs/PoseStamped",
            [("header", Ty::Msg(&HEADER)), ("pose", Ty::Msg(&POSE))]
        );
        ros_type!(
            ODOMETRY,
            "nav_msgs/Odometry",
            [
                ("header", Ty::Msg(&HEADER)),
                ("child_frame_id", Ty::Str),
                ("pose", Ty::Msg(&POSE_WITH_COVARIANCE)),
                ("twist", Ty::Msg(&TWIST_WITH_COVARIANCE)),
            ]
        );
        ros_type!(
            NAV_SAT_FIX,
            "sensor_msgs/NavSatFix",
            [
                ("header", Ty::Msg(&HEADER)),
                ("status", Ty::Msg(&NAV_SAT_STATUS)),
                ("latitude", Ty::F64),
                ("longitude", Ty::F64),
                ("altitude", Ty::F64),
                ("position_covariance", Ty::Array(&COV, 9)),
                ("position_covariance_type", Ty::U8),
            ]
        );

        /// The types a bridge can map.
        pub static KNOWN: [&RosType; 7] = [
            &STRING,
            &FLOAT64,
            &TWIST,
            &POSE,
            &POSE_STAMPED,
            &ODOMETRY,
            &NAV_SAT_FIX,
        ];
    };
}

/// ROS 1's header and the types that contain it.
pub mod ros1 {
    stamped_types!();

    ros_type!(TIME, "time", [("secs", Ty::U32), ("nsecs", Ty::U32)]);
    ros_type!(
        HEADER,
        "std_msgs/Header",
        [
            ("seq", Ty::U32),
            ("stamp", Ty::Msg(&TIME)),
            ("frame_id", Ty::Str)
        ]
    );
}

/// ROS 2's header and the types that contain it.
pub mod ros2 {
    stamped_types!();

    ros_type!(
        TIME,
        "builtin_interfaces/Time",
        [("sec", Ty::I32), ("nanosec", Ty::U32)]
    );
    ros_type!(
        HEADER,
        "std_msgs/Header",
        [("stamp", Ty::Msg(&TIME)), ("frame_id", Ty::Str)]
    );
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn both_flavours_know_the_seven_types_by_either_spelling() {
        for f in [Flavour::Ros1, Flavour::Ros2] {
            assert_eq!(
                f.lookup("nav_msgs/msg/Odometry").unwrap().name,
                "nav_msgs/Odometry"
            );
            assert!(f.lookup("nav_msgs/Path").is_none());
            assert_eq!(f.known_names().split(", ").count(), 7);
        }
        let header = |f: Flavour| match f.lookup("nav_msgs/Odometry").unwrap().fields[0].1 {
            Ty::Msg(h) => h.fields.len(),
            _ => 0,
        };
        assert_eq!((header(Flavour::Ros1), header(Flavour::Ros2)), (3, 2));
    }
}

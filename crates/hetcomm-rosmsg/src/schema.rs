//! The ROS message types a bridge maps, as schemas ([`RosType`]) read from their definitions
//! (the [`crate::registry`]), for ROS 1 and ROS 2 ([`Flavour`]).
//!
//! The two flavours differ in their header: ROS 1's `std_msgs/Header` is `seq`, `stamp`
//! (`time`: `secs`, `nsecs`) and `frame_id`; ROS 2's is `stamp` (`builtin_interfaces/Time`:
//! `sec`, `nanosec`) and `frame_id`. So every type with a header exists once per flavour.

use std::sync::OnceLock;

use crate::registry::Registry;

/// A field's type.
#[derive(Debug)]
pub enum Ty {
    /// `bool`.
    Bool,
    /// `int8` (ROS 1's `byte`).
    I8,
    /// `uint8` (`char`, ROS 2's `byte`).
    U8,
    /// `int16`.
    I16,
    /// `uint16`.
    U16,
    /// `int32`.
    I32,
    /// `uint32`.
    U32,
    /// `int64`.
    I64,
    /// `uint64`.
    U64,
    /// `float32`.
    F32,
    /// `float64`.
    F64,
    /// `string`.
    Str,
    /// `string<=N` (ROS 2): at most N bytes.
    BoundedStr(usize),
    /// `T[N]`: exactly N elements, no length on the wire.
    Array(&'static Ty, usize),
    /// `T[]` (no bound) or `T[<=N]` (ROS 2, a bound): a `uint32` length, then the elements.
    Seq(&'static Ty, Option<usize>),
    /// A nested message (also ROS 1's `time` and `duration`, two fields each).
    Msg(&'static RosType),
}

/// A ROS message type: its name (`pkg/Type`), fields in order, and what identifies it.
#[derive(Debug)]
pub struct RosType {
    /// `pkg/Type`, e.g. `geometry_msgs/Twist`.
    pub name: &'static str,
    /// Fields, in wire order.
    pub fields: &'static [(&'static str, Ty)],
    /// Its constants: (type, name, value as written).
    pub constants: &'static [(&'static str, &'static str, &'static str)],
    /// ROS 1's MD5 sum of the definition (hex); empty for ROS 2 types and builtins.
    pub md5: &'static str,
    /// The full definition ROS 1 sends in a connection header (the type's text, then each
    /// type it uses after a line of `=` and `MSG: pkg/Type`); for ROS 2, the type's text.
    pub definition: &'static str,
    /// ROS 2's type hash (`RIHS01_…`, [`crate::typehash`]); empty for ROS 1 types and
    /// builtins.
    pub type_hash: &'static str,
    /// ROS 2's individual type description, as hashed ([`crate::typehash::description`]);
    /// empty for ROS 1 types and builtins.
    pub description: &'static str,
}

/// Which ROS a schema is for.
#[derive(Clone, Copy, Debug, PartialEq, Eq, Hash, PartialOrd, Ord)]
pub enum Flavour {
    /// ROS 1 (TCPROS, ROS 1 serialization).
    Ros1,
    /// ROS 2 (DDS, CDR).
    Ros2,
}

/// The types the bridges mapped before they read definitions, and the fleet files' examples
/// use.
const CLASSIC: [&str; 7] = [
    "std_msgs/String",
    "std_msgs/Float64",
    "geometry_msgs/Twist",
    "geometry_msgs/Pose",
    "geometry_msgs/PoseStamped",
    "nav_msgs/Odometry",
    "sensor_msgs/NavSatFix",
];

impl Flavour {
    /// "ROS 1" or "ROS 2", for messages.
    pub fn label(self) -> &'static str {
        match self {
            Flavour::Ros1 => "ROS 1",
            Flavour::Ros2 => "ROS 2",
        }
    }

    /// The shipped definitions of this flavour (std_msgs, geometry_msgs, sensor_msgs,
    /// nav_msgs, diagnostic_msgs, tf2_msgs; builtin_interfaces in ROS 2), no directories.
    pub fn shipped(self) -> &'static Registry {
        static REGISTRIES: [OnceLock<Registry>; 2] = [OnceLock::new(), OnceLock::new()];
        REGISTRIES[self as usize].get_or_init(|| Registry::shipped(self))
    }

    /// Seven common types (`std_msgs/String`, `Float64`, `geometry_msgs/Twist`, `Pose`,
    /// `PoseStamped`, `nav_msgs/Odometry`, `sensor_msgs/NavSatFix`), from the shipped
    /// definitions.
    pub fn known(self) -> &'static [&'static RosType; 7] {
        static KNOWN: [OnceLock<[&'static RosType; 7]>; 2] = [OnceLock::new(), OnceLock::new()];
        KNOWN[self as usize].get_or_init(|| {
            CLASSIC.map(|name| {
                self.shipped()
                    .resolve(name)
                    .unwrap_or_else(|e| panic!("the shipped definition of {name}: {e}"))
            })
        })
    }

    /// The shipped type named `name` (`pkg/Type` or `pkg/msg/Type`).
    pub fn lookup(self, name: &str) -> Option<&'static RosType> {
        self.shipped().resolve(name).ok()
    }

    /// The packages whose definitions ship with hetcomm, for help texts.
    pub fn known_names(self) -> String {
        self.shipped().packages().join(", ")
    }
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
            assert!(f.lookup("nav_msgs/Path").is_some());
            assert!(f.lookup("nav_msgs/Paht").is_none());
            assert_eq!(f.known().len(), 7);
        }
        let header = |f: Flavour| match f.lookup("nav_msgs/Odometry").unwrap().fields[0].1 {
            Ty::Msg(h) => h.fields.len(),
            _ => 0,
        };
        assert_eq!((header(Flavour::Ros1), header(Flavour::Ros2)), (3, 2));
    }
}

//! The ROS 2 message types a bridge knows ([`lookup`]), as schemas ([`RosType`]), and the
//! conversion between a hetcomm payload (MessagePack, structs as maps keyed by serde field
//! names) and a ROS 2 message in CDR (XCDR1, the encoding every ROS 2 middleware uses), field
//! by field, by name. The schemas and the conversion are shared with the ROS 1 bridge: they
//! live in `hetcomm_rosmsg` (its `schema` and `codec`); this module is their ROS 2 face.

use hetcomm_rosmsg::codec::{self, Wire};
use hetcomm_rosmsg::schema::Flavour;
use rmpv::Value;

pub use hetcomm_rosmsg::schema::{RosType, Ty};

/// The shipped type named `name` (`pkg/Type` or `pkg/msg/Type`).
pub fn lookup(name: &str) -> Option<&'static RosType> {
    Flavour::Ros2.lookup(name)
}

/// The packages of the shipped definitions, for help texts.
pub fn known_names() -> String {
    Flavour::Ros2.known_names()
}

/// Converts a MessagePack value (a hetcomm payload) into `ty`'s CDR body (little endian, no
/// encapsulation header). `what` names the hetcomm type in errors.
pub fn to_cdr(value: &Value, ty: &'static RosType, what: &str) -> Result<Vec<u8>, String> {
    codec::encode(value, ty, Wire::CDR, what)
}

/// Reads `ty`'s CDR body (after the 4-byte encapsulation header; `little` tells the byte
/// order) into a MessagePack value: a map of every field by name.
pub fn from_cdr(
    body: &[u8],
    little: bool,
    xcdr2: bool,
    ty: &'static RosType,
) -> Result<Value, String> {
    codec::decode(body, ty, Wire::Cdr { little, xcdr2 })
}

//! Checking a mapping when the bridge opens: does a declared message type's [`Shape`]
//! convert to (publish) or from (subscribe) the ROS type, by the rules the per-message
//! conversion ([`crate::codec`]) applies? The reasons read as the per-message ones do, so a
//! user sees the same sentence whether the mismatch is found at open or at a send.
//!
//! What only a value can tell (an integer out of a field's range, a `Vec` of the wrong length
//! for a fixed array) is left to the per-message check; so is anything the shape tracer could
//! not follow ([`Shape::Unknown`]) and enums (whose encoding depends on the variant).

use hetcomm_link::shape::Shape;

use crate::schema::{RosType, Ty};

/// Which way a mapping converts.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum Direction {
    /// A hetcomm message becomes a ROS message (a `publish` mapping): every ROS field must be
    /// there and no other.
    ToRos,
    /// A ROS message becomes a hetcomm message (a `subscribe` mapping): the hetcomm type may
    /// take only some of the ROS fields, but each it has must be there (or be an `Option`).
    FromRos,
}

/// Whether a value of `shape` converts to or from `ty` in `direction`; the error names the
/// field and what is wrong, as the per-message conversion would.
pub fn check(shape: &Shape, ty: &RosType, direction: Direction) -> Result<(), String> {
    match shape {
        Shape::Struct { fields, .. } => message(fields, ty, "", direction),
        Shape::Unknown | Shape::Map(..) | Shape::Enum(_) => Ok(()),
        other => Err(format!(
            "the message is {}, {} is a message (a struct with its fields)",
            other.describe(),
            ty.name
        )),
    }
}

fn path_of(prefix: &str, name: &str) -> String {
    if prefix.is_empty() {
        name.to_string()
    } else {
        format!("{prefix}.{name}")
    }
}

fn message(
    fields: &[(String, Shape)],
    ty: &RosType,
    prefix: &str,
    direction: Direction,
) -> Result<(), String> {
    for (name, shape) in fields {
        let p = path_of(prefix, name);
        match ty.fields.iter().find(|(f, _)| f == name) {
            Some((_, ros)) => value(shape, ros, &p, direction)?,
            // serde gives a missing Option field None.
            None if direction == Direction::FromRos && matches!(shape, Shape::Option(_)) => {}
            None => return Err(format!("field `{p}` has no counterpart in {}", ty.name)),
        }
    }
    if direction == Direction::ToRos {
        if let Some((name, _)) = ty
            .fields
            .iter()
            .find(|(f, _)| !fields.iter().any(|(n, _)| n == f))
        {
            return Err(format!(
                "field `{}` of {} is missing",
                path_of(prefix, name),
                ty.name
            ));
        }
    }
    Ok(())
}

fn value(shape: &Shape, ros: &Ty, path: &str, direction: Direction) -> Result<(), String> {
    let integer = matches!(
        ros,
        Ty::I8 | Ty::U8 | Ty::I16 | Ty::U16 | Ty::I32 | Ty::U32 | Ty::I64 | Ty::U64
    );
    let float = matches!(ros, Ty::F32 | Ty::F64);
    let fits = match (shape, ros) {
        (Shape::Unknown | Shape::Enum(_), _) => true,
        // Towards ROS a None has no ROS value; from ROS the value fills the Some.
        (Shape::Option(inner), _) if direction == Direction::FromRos => {
            return value(inner, ros, path, direction)
        }
        (Shape::Bool, Ty::Bool) | (Shape::Str, Ty::Str | Ty::BoundedStr(_)) => true,
        (Shape::Int, _) if integer => true,
        // An integer converts to float64 towards ROS; from ROS a float fills an integer
        // field only if it is one, which serde refuses.
        (Shape::Int, _) if float => direction == Direction::ToRos,
        (Shape::Float, _) if float => true,
        (Shape::Float, _) if integer => direction == Direction::FromRos,
        (Shape::Seq(elem), Ty::Array(ros_elem, _) | Ty::Seq(ros_elem, _)) => {
            return value(elem, ros_elem, &format!("{path}[]"), direction)
        }
        (Shape::Tuple(items), Ty::Seq(ros_elem, bound)) => {
            if let Some(max) = bound.filter(|max| items.len() > *max) {
                return Err(format!(
                    "field `{path}` has {} elements, the ROS field has at most {max}",
                    items.len()
                ));
            }
            for (i, item) in items.iter().enumerate() {
                value(item, ros_elem, &format!("{path}[{i}]"), direction)?;
            }
            return Ok(());
        }
        (Shape::Tuple(items), Ty::Array(ros_elem, n)) => {
            if items.len() != *n {
                return Err(format!(
                    "field `{path}` has {} elements, the ROS field has {n}",
                    items.len()
                ));
            }
            for (i, item) in items.iter().enumerate() {
                value(item, ros_elem, &format!("{path}[{i}]"), direction)?;
            }
            return Ok(());
        }
        // Bytes are a uint8 array either way (MessagePack bin towards ROS, an array back).
        (Shape::Bytes, Ty::Array(e, _) | Ty::Seq(e, _)) => matches!(e, Ty::U8),
        (Shape::Struct { fields, .. }, Ty::Msg(m)) => return message(fields, m, path, direction),
        (Shape::Map(..), Ty::Msg(_)) => true,
        _ => false,
    };
    if fits {
        Ok(())
    } else {
        Err(format!(
            "field `{path}` is {}, the ROS field is {}",
            shape.describe(),
            crate::codec::ty_name(ros)
        ))
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::schema::Flavour;

    fn ty(name: &str) -> &'static RosType {
        Flavour::Ros2.lookup(name).unwrap()
    }

    fn st(name: &str, fields: Vec<(&str, Shape)>) -> Shape {
        Shape::Struct {
            name: name.into(),
            fields: fields
                .into_iter()
                .map(|(n, s)| (n.to_string(), s))
                .collect(),
        }
    }

    fn vec3() -> Shape {
        st(
            "Vector3",
            vec![
                ("x", Shape::Float),
                ("y", Shape::Float),
                ("z", Shape::Float),
            ],
        )
    }

    #[test]
    fn a_twist_shaped_struct_converts_both_ways() {
        let vec3_int_z = st(
            "Vector3",
            vec![("x", Shape::Float), ("y", Shape::Float), ("z", Shape::Int)],
        );
        let drive = st("Drive", vec![("linear", vec3_int_z), ("angular", vec3())]);
        assert_eq!(
            check(&drive, ty("geometry_msgs/Twist"), Direction::ToRos),
            Ok(())
        );
        // From ROS, `z: i64` cannot take a float64.
        assert_eq!(
            check(&drive, ty("geometry_msgs/Twist"), Direction::FromRos),
            Err("field `linear.z` is an integer, the ROS field is float64".into())
        );
    }

    #[test]
    fn extra_missing_and_mistyped_fields_are_named_with_the_ros_type() {
        let twist = ty("geometry_msgs/Twist");
        let extra = st(
            "Drive",
            vec![
                ("linear", vec3()),
                ("angular", vec3()),
                ("speed", Shape::Float),
            ],
        );
        assert_eq!(
            check(&extra, twist, Direction::ToRos),
            Err("field `speed` has no counterpart in geometry_msgs/Twist".into())
        );
        let missing = st("Drive", vec![("linear", vec3())]);
        assert_eq!(
            check(&missing, twist, Direction::ToRos),
            Err("field `angular` of geometry_msgs/Twist is missing".into())
        );
        // From ROS a subset is fine.
        assert_eq!(check(&missing, twist, Direction::FromRos), Ok(()));
        let mistyped = st("Speed", vec![("data", Shape::Str)]);
        assert_eq!(
            check(&mistyped, ty("std_msgs/Float64"), Direction::ToRos),
            Err("field `data` is a string, the ROS field is float64".into())
        );
    }

    #[test]
    fn nested_messages_arrays_and_options_follow_the_conversion_rules() {
        let odom = ty("nav_msgs/Odometry");
        let pose = st(
            "Pose",
            vec![(
                "position",
                st(
                    "P",
                    vec![
                        ("x", Shape::Float),
                        ("y", Shape::Float),
                        ("z", Shape::Float),
                    ],
                ),
            )],
        );
        let covariance = Shape::Tuple(vec![Shape::Float; 36]);
        let wanted = st(
            "Odom",
            vec![
                ("child_frame_id", Shape::Str),
                ("note", Shape::Option(Box::new(Shape::Str))),
                (
                    "pose",
                    st(
                        "PoseWithCovariance",
                        vec![("pose", pose), ("covariance", covariance)],
                    ),
                ),
            ],
        );
        assert_eq!(check(&wanted, odom, Direction::FromRos), Ok(()));
        let short = st(
            "Odom",
            vec![(
                "pose",
                st(
                    "PoseWithCovariance",
                    vec![("covariance", Shape::Tuple(vec![Shape::Float; 9]))],
                ),
            )],
        );
        assert_eq!(
            check(&short, odom, Direction::FromRos),
            Err("field `pose.covariance` has 9 elements, the ROS field has 36".into())
        );
        // A Vec's length is the value's: checked per message.
        let any_len = st(
            "Odom",
            vec![(
                "pose",
                st(
                    "PoseWithCovariance",
                    vec![("covariance", Shape::Seq(Box::new(Shape::Float)))],
                ),
            )],
        );
        assert_eq!(check(&any_len, odom, Direction::FromRos), Ok(()));
        // Towards ROS, an Option cannot always give a value.
        let optional = st("Say", vec![("data", Shape::Option(Box::new(Shape::Str)))]);
        assert_eq!(
            check(&optional, ty("std_msgs/String"), Direction::ToRos),
            Err("field `data` is an Option of a string, the ROS field is string".into())
        );
    }

    #[test]
    fn a_message_that_is_not_a_struct_and_unknown_shapes() {
        assert_eq!(
            check(&Shape::Float, ty("std_msgs/Float64"), Direction::ToRos),
            Err(
                "the message is a float, std_msgs/Float64 is a message (a struct with its fields)"
                    .into()
            )
        );
        assert_eq!(
            check(&Shape::Unknown, ty("std_msgs/Float64"), Direction::ToRos),
            Ok(())
        );
    }
}

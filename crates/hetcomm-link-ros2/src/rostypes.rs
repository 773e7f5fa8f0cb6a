//! The ROS 2 message types a bridge knows ([`lookup`]), as schemas ([`Ty`]), and the
//! conversion between a hetcomm payload (MessagePack, structs as maps keyed by serde field
//! names) and a ROS 2 message in CDR (XCDR1, the encoding every ROS 2 middleware uses), field
//! by field, by name.
//!
//! A hetcomm message maps to a ROS type when its serde fields are named as the ROS type's:
//! `struct Twist { linear: Vector3, angular: Vector3 }` with `struct Vector3 { x: f64, y: f64,
//! z: f64 }` is `geometry_msgs/Twist`. Towards ROS, every ROS field must be present (numbers
//! convert when they fit) and no other field may be: a mismatch is an error naming both types
//! and the field. From ROS, the message becomes a map of every ROS field; a hetcomm struct may
//! declare only some of them (serde ignores the rest).

use rmpv::Value;

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

/// A ROS 2 message type: its name (`pkg/Type`) and fields in order.
#[derive(Debug)]
pub struct RosType {
    /// `pkg/Type`, e.g. `geometry_msgs/Twist`.
    pub name: &'static str,
    /// Fields, in wire order.
    pub fields: &'static [(&'static str, Ty)],
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
    TIME,
    "builtin_interfaces/Time",
    [("sec", Ty::I32), ("nanosec", Ty::U32)]
);
ros_type!(
    HEADER,
    "std_msgs/Header",
    [("stamp", Ty::Msg(&TIME)), ("frame_id", Ty::Str)]
);
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
ros_type!(
    POSE_STAMPED,
    "geometry_msgs/PoseStamped",
    [("header", Ty::Msg(&HEADER)), ("pose", Ty::Msg(&POSE))]
);
static COV36: Ty = Ty::F64;
ros_type!(
    POSE_WITH_COVARIANCE,
    "geometry_msgs/PoseWithCovariance",
    [
        ("pose", Ty::Msg(&POSE)),
        ("covariance", Ty::Array(&COV36, 36))
    ]
);
ros_type!(
    TWIST_WITH_COVARIANCE,
    "geometry_msgs/TwistWithCovariance",
    [
        ("twist", Ty::Msg(&TWIST)),
        ("covariance", Ty::Array(&COV36, 36))
    ]
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
    NAV_SAT_STATUS,
    "sensor_msgs/NavSatStatus",
    [("status", Ty::I8), ("service", Ty::U16)]
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
        ("position_covariance", Ty::Array(&COV36, 9)),
        ("position_covariance_type", Ty::U8),
    ]
);

/// The types a bridge can map, by name.
pub static KNOWN: [&RosType; 7] = [
    &STRING,
    &FLOAT64,
    &TWIST,
    &POSE,
    &POSE_STAMPED,
    &ODOMETRY,
    &NAV_SAT_FIX,
];

/// The known type named `name` (`pkg/Type` or `pkg/msg/Type`).
pub fn lookup(name: &str) -> Option<&'static RosType> {
    let short = match name.split('/').collect::<Vec<_>>()[..] {
        [pkg, "msg", ty] => format!("{pkg}/{ty}"),
        _ => name.to_string(),
    };
    KNOWN.iter().copied().find(|t| t.name == short)
}

/// The names of [`KNOWN`], for help texts.
pub fn known_names() -> String {
    KNOWN.iter().map(|t| t.name).collect::<Vec<_>>().join(", ")
}

/// Converts a MessagePack value (a hetcomm payload) into `ty`'s CDR body (little endian, no
/// encapsulation header). `what` names the hetcomm type in errors.
pub fn to_cdr(value: &Value, ty: &'static RosType, what: &str) -> Result<Vec<u8>, String> {
    let mut out = Vec::with_capacity(64);
    write_msg(&mut out, value, ty, "")
        .map_err(|e| format!("{what} does not convert to {}: {e}", ty.name))?;
    Ok(out)
}

fn align(out: &mut Vec<u8>, n: usize) {
    while !out.len().is_multiple_of(n) {
        out.push(0);
    }
}

fn field_path(prefix: &str, name: &str) -> String {
    if prefix.is_empty() {
        name.to_string()
    } else {
        format!("{prefix}.{name}")
    }
}

fn write_msg(out: &mut Vec<u8>, value: &Value, ty: &RosType, path: &str) -> Result<(), String> {
    let Value::Map(entries) = value else {
        return Err(format!(
            "`{}` is {}, {} is a message",
            if path.is_empty() { "the message" } else { path },
            kind_of(value),
            ty.name
        ));
    };
    for (k, _) in entries {
        let name = k.as_str().unwrap_or_default();
        if !ty.fields.iter().any(|(f, _)| *f == name) {
            return Err(format!(
                "field `{}` has no counterpart in {}",
                field_path(path, name),
                ty.name
            ));
        }
    }
    for (name, fty) in ty.fields {
        let p = field_path(path, name);
        let v = entries
            .iter()
            .find(|(k, _)| k.as_str() == Some(name))
            .map(|(_, v)| v)
            .ok_or_else(|| format!("field `{p}` of {} is missing", ty.name))?;
        write_value(out, v, fty, &p)?;
    }
    Ok(())
}

fn kind_of(v: &Value) -> &'static str {
    match v {
        Value::Nil => "nil",
        Value::Boolean(_) => "a boolean",
        Value::Integer(_) => "an integer",
        Value::F32(_) | Value::F64(_) => "a float",
        Value::String(_) => "a string",
        Value::Binary(_) => "bytes",
        Value::Array(_) => "an array",
        Value::Map(_) => "a map",
        Value::Ext(..) => "an extension",
    }
}

fn int_in(v: &Value, path: &str, min: i64, max: i64, ros: &str) -> Result<i64, String> {
    let n = match v {
        Value::Integer(i) => i.as_i64(),
        _ => None,
    };
    match n {
        Some(n) if (min..=max).contains(&n) => Ok(n),
        _ => Err(format!(
            "field `{path}` is {} ({v}), the ROS field is {ros}",
            kind_of(v)
        )),
    }
}

fn write_value(out: &mut Vec<u8>, v: &Value, ty: &Ty, path: &str) -> Result<(), String> {
    match ty {
        Ty::Bool => match v {
            Value::Boolean(b) => out.push(*b as u8),
            _ => {
                return Err(format!(
                    "field `{path}` is {}, the ROS field is bool",
                    kind_of(v)
                ))
            }
        },
        Ty::I8 => out.push(int_in(v, path, i8::MIN as i64, i8::MAX as i64, "int8")? as i8 as u8),
        Ty::U8 => out.push(int_in(v, path, 0, u8::MAX as i64, "uint8")? as u8),
        Ty::U16 => {
            let n = int_in(v, path, 0, u16::MAX as i64, "uint16")? as u16;
            align(out, 2);
            out.extend_from_slice(&n.to_le_bytes());
        }
        Ty::I32 => {
            let n = int_in(v, path, i32::MIN as i64, i32::MAX as i64, "int32")? as i32;
            align(out, 4);
            out.extend_from_slice(&n.to_le_bytes());
        }
        Ty::U32 => {
            let n = int_in(v, path, 0, u32::MAX as i64, "uint32")? as u32;
            align(out, 4);
            out.extend_from_slice(&n.to_le_bytes());
        }
        Ty::F64 => {
            let x = match v {
                Value::F64(x) => *x,
                Value::F32(x) => *x as f64,
                Value::Integer(i) => i.as_f64().unwrap_or(f64::NAN),
                _ => {
                    return Err(format!(
                        "field `{path}` is {}, the ROS field is float64",
                        kind_of(v)
                    ))
                }
            };
            align(out, 8);
            out.extend_from_slice(&x.to_le_bytes());
        }
        Ty::Str => {
            let Value::String(s) = v else {
                return Err(format!(
                    "field `{path}` is {}, the ROS field is string",
                    kind_of(v)
                ));
            };
            let bytes = s.as_bytes();
            align(out, 4);
            out.extend_from_slice(&(bytes.len() as u32 + 1).to_le_bytes());
            out.extend_from_slice(bytes);
            out.push(0);
        }
        Ty::Array(elem, n) => {
            let Value::Array(items) = v else {
                return Err(format!(
                    "field `{path}` is {}, the ROS field is an array of {n}",
                    kind_of(v)
                ));
            };
            if items.len() != *n {
                return Err(format!(
                    "field `{path}` has {} elements, the ROS field has {n}",
                    items.len()
                ));
            }
            for (i, item) in items.iter().enumerate() {
                write_value(out, item, elem, &format!("{path}[{i}]"))?;
            }
        }
        Ty::Msg(inner) => write_msg(out, v, inner, path)?,
    }
    Ok(())
}

/// Reads `ty`'s CDR body (after the 4-byte encapsulation header; `little` tells the byte
/// order) into a MessagePack value: a map of every field by name.
pub fn from_cdr(
    body: &[u8],
    little: bool,
    xcdr2: bool,
    ty: &'static RosType,
) -> Result<Value, String> {
    let mut r = Reader {
        body,
        pos: 0,
        little,
        max_align: if xcdr2 { 4 } else { 8 },
    };
    let v = r.msg(ty, "")?;
    Ok(v)
}

struct Reader<'a> {
    body: &'a [u8],
    pos: usize,
    little: bool,
    /// 8 for plain CDR, 4 for XCDR2.
    max_align: usize,
}

impl Reader<'_> {
    fn take(&mut self, n: usize, path: &str) -> Result<&[u8], String> {
        let a = n.min(self.max_align);
        if !self.pos.is_multiple_of(a) {
            self.pos += a - self.pos % a;
        }
        let end = self.pos + n;
        let bytes = self.body.get(self.pos..end).ok_or_else(|| {
            format!(
                "the message ends at byte {} while reading `{path}`",
                self.body.len()
            )
        })?;
        self.pos = end;
        Ok(bytes)
    }

    fn num<const N: usize>(&mut self, path: &str) -> Result<[u8; N], String> {
        let mut a = [0u8; N];
        a.copy_from_slice(self.take(N, path)?);
        if !self.little {
            a.reverse();
        }
        Ok(a)
    }

    fn msg(&mut self, ty: &'static RosType, path: &str) -> Result<Value, String> {
        let mut map = Vec::with_capacity(ty.fields.len());
        for (name, fty) in ty.fields {
            let p = field_path(path, name);
            map.push((Value::from(*name), self.value(fty, &p)?));
        }
        Ok(Value::Map(map))
    }

    fn value(&mut self, ty: &Ty, path: &str) -> Result<Value, String> {
        Ok(match ty {
            Ty::Bool => Value::Boolean(self.take(1, path)?[0] != 0),
            Ty::I8 => Value::from(self.take(1, path)?[0] as i8),
            Ty::U8 => Value::from(self.take(1, path)?[0]),
            Ty::U16 => Value::from(u16::from_le_bytes(self.num(path)?)),
            Ty::I32 => Value::from(i32::from_le_bytes(self.num(path)?)),
            Ty::U32 => Value::from(u32::from_le_bytes(self.num(path)?)),
            Ty::F64 => Value::F64(f64::from_le_bytes(self.num(path)?)),
            Ty::Str => {
                let len = u32::from_le_bytes(self.num(path)?) as usize;
                if len == 0 {
                    return Err(format!("string `{path}` has length 0 (no terminating NUL)"));
                }
                let raw = self
                    .body
                    .get(self.pos..self.pos.saturating_add(len))
                    .ok_or_else(|| format!("string `{path}` runs past the end of the message"))?;
                self.pos += len;
                let text = std::str::from_utf8(&raw[..len - 1])
                    .map_err(|_| format!("string `{path}` is not UTF-8"))?;
                Value::from(text)
            }
            Ty::Array(elem, n) => {
                let mut items = Vec::with_capacity(*n);
                for i in 0..*n {
                    items.push(self.value(elem, &format!("{path}[{i}]"))?);
                }
                Value::Array(items)
            }
            Ty::Msg(inner) => self.msg(inner, path)?,
        })
    }
}

#[cfg(test)]
mod tests {
    use super::*;

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

    #[test]
    fn a_twist_round_trips_and_its_cdr_is_what_ros_2_writes() {
        let twist = map(&[
            ("linear", vec3(0.5, 0.0, 0.0)),
            ("angular", vec3(0.0, 0.0, 0.25)),
        ]);
        let cdr = to_cdr(&twist, &TWIST, "Command (type 40)").unwrap();
        assert_eq!(cdr.len(), 48);
        assert_eq!(&cdr[..8], &0.5f64.to_le_bytes());
        assert_eq!(from_cdr(&cdr, true, false, &TWIST).unwrap(), twist);
    }

    #[test]
    fn strings_and_nested_headers_are_aligned_as_cdr_says() {
        let header = map(&[
            ("stamp", map(&[("sec", 5.into()), ("nanosec", 7u32.into())])),
            ("frame_id", "map".into()),
        ]);
        let pose = map(&[
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
        ]);
        let stamped = map(&[("header", header), ("pose", pose)]);
        let cdr = to_cdr(&stamped, &POSE_STAMPED, "Fix").unwrap();
        // sec, nanosec, len 4, "map\0", then the first float64 at offset 16.
        assert_eq!(&cdr[8..16], &[4, 0, 0, 0, b'm', b'a', b'p', 0]);
        assert_eq!(&cdr[16..24], &1.0f64.to_le_bytes());
        assert_eq!(from_cdr(&cdr, true, false, &POSE_STAMPED).unwrap(), stamped);
    }

    #[test]
    fn mismatches_name_both_types_and_the_field() {
        let missing = map(&[("linear", vec3(1.0, 0.0, 0.0))]);
        assert_eq!(
            to_cdr(&missing, &TWIST, "Command (type 40)").unwrap_err(),
            "Command (type 40) does not convert to geometry_msgs/Twist: field `angular` of \
             geometry_msgs/Twist is missing"
        );
        let extra = map(&[("data", 1.0.into()), ("unit", "m".into())]);
        assert_eq!(
            to_cdr(&extra, &FLOAT64, "Range (type 7)").unwrap_err(),
            "Range (type 7) does not convert to std_msgs/Float64: field `unit` has no \
             counterpart in std_msgs/Float64"
        );
        let wrong = map(&[("data", "high".into())]);
        assert_eq!(
            to_cdr(&wrong, &FLOAT64, "Range (type 7)").unwrap_err(),
            "Range (type 7) does not convert to std_msgs/Float64: field `data` is a string, \
             the ROS field is float64"
        );
    }

    #[test]
    fn truncated_or_garbled_cdr_is_an_error_not_a_panic() {
        let cdr = to_cdr(&map(&[("data", "hello".into())]), &STRING, "T").unwrap();
        for cut in 0..cdr.len() - 1 {
            assert!(
                from_cdr(&cdr[..cut], true, false, &STRING).is_err(),
                "cut at {cut}"
            );
        }
        let mut huge = cdr.clone();
        huge[..4].copy_from_slice(&u32::MAX.to_le_bytes());
        assert!(from_cdr(&huge, true, false, &STRING).is_err());
        assert!(from_cdr(&[1, 2, 3], true, false, &ODOMETRY).is_err());
        assert_eq!(
            lookup("nav_msgs/msg/Odometry").unwrap().name,
            "nav_msgs/Odometry"
        );
        assert!(lookup("nav_msgs/Path").is_none());
    }
}

//! Reading one `.msg` file ([`parse`]) into its declarations ([`MsgFile`]), as ROS 1
//! (genmsg) and ROS 2 (rosidl) read them. A file that is not a valid message is a
//! [`ParseError`] at `file:line` saying what is wrong.
//!
//! A line is a field (`TYPE NAME`, and in ROS 2 an optional default value after it), a
//! constant (`TYPE NAME=VALUE`, a primitive or string type) or only a comment (`#` to the end
//! of the line, except in a string constant's value, which in ROS 1 is the rest of the line).
//! Types are primitives, `string` (ROS 2 also `string<=N`, a bounded string), ROS 1's `time`
//! and `duration`, or a message `Type` (this package's) or `pkg/Type`; ROS 1 reads a bare
//! `Header` as `std_msgs/Header`. Any of them may be an array: `T[N]` (fixed), `T[]`
//! (unbounded) or, in ROS 2, `T[<=N]` (bounded).
//!
//! (roslibrust's parser, in `roslibrust_codegen`, was not used: it belongs to a code generator
//! that brings syn, quote, serde_json, sha2, walkdir and xml-rs along, its errors carry no line
//! numbers, and it accepts invalid names and ROS 2 syntax in ROS 1 files.)

use std::fmt;

use crate::schema::Flavour;

/// A primitive type.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum Prim {
    /// `bool`.
    Bool,
    /// `int8`, and ROS 1's `byte` (its deprecated alias).
    I8,
    /// `uint8`, `char`, and ROS 2's `byte` (an octet).
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
}

impl Prim {
    fn from_name(name: &str, flavour: Flavour) -> Option<Prim> {
        Some(match name {
            "bool" => Prim::Bool,
            "int8" => Prim::I8,
            "byte" if flavour == Flavour::Ros1 => Prim::I8,
            "uint8" | "char" | "byte" => Prim::U8,
            "int16" => Prim::I16,
            "uint16" => Prim::U16,
            "int32" => Prim::I32,
            "uint32" => Prim::U32,
            "int64" => Prim::I64,
            "uint64" => Prim::U64,
            "float32" => Prim::F32,
            "float64" => Prim::F64,
            _ => return None,
        })
    }
}

/// A field's type without its array part.
#[derive(Clone, Debug, PartialEq, Eq)]
pub enum Base {
    /// A primitive.
    Prim(Prim),
    /// `string`, or `string<=N` (at most N bytes).
    Str(Option<usize>),
    /// `wstring` (ROS 2), read but not converted by the bridges.
    WStr(Option<usize>),
    /// ROS 1's `time` (`uint32 secs`, `uint32 nsecs`).
    Time,
    /// ROS 1's `duration` (`int32 secs`, `int32 nsecs`).
    Duration,
    /// Another message, `package/Name`.
    Msg(String),
}

/// Whether and how a field is an array.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum Array {
    /// A single value.
    No,
    /// `T[N]`.
    Fixed(usize),
    /// `T[<=N]` (ROS 2).
    Bounded(usize),
    /// `T[]`.
    Unbounded,
}

/// A field's type, with its spelling for ROS 1's MD5 sum.
#[derive(Clone, Debug, PartialEq, Eq)]
pub struct FieldType {
    /// The type.
    pub base: Base,
    /// Its array part.
    pub array: Array,
    /// As written, with message names made full (`Header` is `std_msgs/Header`).
    pub text: String,
}

/// A field: `TYPE NAME [DEFAULT]`.
#[derive(Clone, Debug, PartialEq, Eq)]
pub struct Field {
    /// Its name.
    pub name: String,
    /// Its type.
    pub ty: FieldType,
    /// ROS 2's default value, as written.
    pub default: Option<String>,
    /// Its line in the file (from 1).
    pub line: usize,
}

/// A constant: `TYPE NAME=VALUE`.
#[derive(Clone, Debug, PartialEq, Eq)]
pub struct Constant {
    /// Its type, as written.
    pub ty: String,
    /// Its name.
    pub name: String,
    /// Its value, as written (trimmed; for ROS 1 strings, the rest of the line).
    pub value: String,
}

/// A parsed `.msg` file.
#[derive(Clone, Debug, PartialEq, Eq)]
pub struct MsgFile {
    /// `package/Name`.
    pub name: String,
    /// Fields in order.
    pub fields: Vec<Field>,
    /// Constants in order.
    pub constants: Vec<Constant>,
    /// The file's text (ROS 1 sends it in the connection header's definition).
    pub text: String,
    /// Where it was read from, for messages.
    pub file: String,
}

/// A malformed `.msg` file: where, and what is wrong.
#[derive(Clone, Debug, PartialEq, Eq)]
pub struct ParseError {
    /// The file.
    pub file: String,
    /// The line (from 1).
    pub line: usize,
    /// What is wrong and what to write instead.
    pub what: String,
}

impl fmt::Display for ParseError {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        write!(f, "{}:{}: {}", self.file, self.line, self.what)
    }
}

impl std::error::Error for ParseError {}

/// Whether `name` is a valid package name (`[a-z][a-z0-9_]*`).
pub fn valid_package(name: &str) -> bool {
    let mut chars = name.chars();
    chars.next().is_some_and(|c| c.is_ascii_lowercase())
        && chars.all(|c| c.is_ascii_lowercase() || c.is_ascii_digit() || c == '_')
}

/// A name as ROS 1 spells fields, constants and types: a letter, then letters, digits, `_`.
fn ros1_name(name: &str) -> bool {
    let mut chars = name.chars();
    chars.next().is_some_and(|c| c.is_ascii_alphabetic())
        && chars.all(|c| c.is_ascii_alphanumeric() || c == '_')
}

/// A letter that `first` accepts, then characters that `rest` accepts.
fn spelled(name: &str, first: fn(&char) -> bool, rest: fn(char) -> bool) -> bool {
    let mut chars = name.chars();
    chars.next().is_some_and(|c| first(&c)) && chars.all(rest)
}

/// Whether `name` is a valid message name (a letter, then letters, digits; ROS 1 also `_`).
pub fn valid_message(name: &str, flavour: Flavour) -> bool {
    match flavour {
        Flavour::Ros1 => ros1_name(name),
        Flavour::Ros2 => spelled(name, char::is_ascii_uppercase, |c| {
            c.is_ascii_alphanumeric()
        }),
    }
}

pub(crate) fn valid_field(name: &str, flavour: Flavour) -> bool {
    match flavour {
        Flavour::Ros1 => ros1_name(name),
        // rosidl: lower case, digits and single underscores, not ending in one.
        Flavour::Ros2 => {
            spelled(name, char::is_ascii_lowercase, |c| {
                c.is_ascii_lowercase() || c.is_ascii_digit() || c == '_'
            }) && !name.contains("__")
                && !name.ends_with('_')
        }
    }
}

fn valid_constant(name: &str, flavour: Flavour) -> bool {
    match flavour {
        Flavour::Ros1 => ros1_name(name),
        Flavour::Ros2 => spelled(name, char::is_ascii_uppercase, |c| {
            c.is_ascii_uppercase() || c.is_ascii_digit() || c == '_'
        }),
    }
}

/// Reads the `.msg` text of `package/name` (`file` names it in errors) as `flavour` reads it.
pub fn parse(
    text: &str,
    file: &str,
    package: &str,
    name: &str,
    flavour: Flavour,
) -> Result<MsgFile, ParseError> {
    let mut out = MsgFile {
        name: format!("{package}/{name}"),
        fields: Vec::new(),
        constants: Vec::new(),
        text: text.to_string(),
        file: file.to_string(),
    };
    for (i, raw) in text.lines().enumerate() {
        let line = i + 1;
        let err = |what: String| ParseError {
            file: file.to_string(),
            line,
            what,
        };
        let (ty_text, rest) = match raw.trim_start().split_once(char::is_whitespace) {
            Some((t, r)) => (t, r),
            None => (raw.trim(), ""),
        };
        if ty_text.is_empty() || ty_text.starts_with('#') {
            continue;
        }
        if ty_text == "---" {
            return Err(err(
                "`---` separates a service's or an action's parts: a .msg file has one part".into(),
            ));
        }
        let ty_text = ty_text.split('#').next().unwrap_or_default();
        let ty = parse_type(ty_text, package, flavour).map_err(err)?;
        let is_string = matches!(ty.base, Base::Str(_) | Base::WStr(_));
        // A constant has `=` after its name; a string constant's value keeps its `#`s.
        let uncommented = match rest.find('=') {
            Some(eq) if is_string && !rest[..eq].contains('#') => rest,
            _ => rest.split('#').next().unwrap_or_default(),
        };
        if let Some((cname, value)) = uncommented.split_once('=') {
            let cname = cname.trim();
            if !valid_constant(cname, flavour) {
                return Err(err(format!(
                    "`{cname}` is not a constant name ({})",
                    match flavour {
                        Flavour::Ros1 => "a letter, then letters, digits and `_`",
                        Flavour::Ros2 =>
                            "upper case letters, digits and `_`, starting with a letter",
                    }
                )));
            }
            if ty.array != Array::No || !matches!(ty.base, Base::Prim(_) | Base::Str(_)) {
                return Err(err(format!(
                    "constant `{cname}` is of type `{ty_text}`: a constant is a primitive or a string"
                )));
            }
            let value = constant_value(&ty.base, value)
                .map_err(|why| err(format!("constant `{cname}`: {why}")))?;
            if out.constants.iter().any(|c| c.name == cname) {
                return Err(err(format!("constant `{cname}` is declared twice")));
            }
            out.constants.push(Constant {
                ty: ty_text.to_string(),
                name: cname.to_string(),
                value,
            });
            continue;
        }
        let mut words = uncommented.split_whitespace();
        let Some(fname) = words.next() else {
            return Err(err(format!(
                "`{ty_text}` has no field name: write `{ty_text} NAME`"
            )));
        };
        if !valid_field(fname, flavour) {
            return Err(err(format!(
                "`{fname}` is not a field name ({})",
                match flavour {
                    Flavour::Ros1 => "a letter, then letters, digits and `_`",
                    Flavour::Ros2 => {
                        "lower case letters, digits and single `_`, starting with a letter, \
                         not ending with `_`"
                    }
                }
            )));
        }
        let rest: Vec<&str> = words.collect();
        let default = match (rest.is_empty(), flavour) {
            (true, _) => None,
            (false, Flavour::Ros1) => {
                return Err(err(format!(
                    "unexpected `{}` after field `{fname}` (ROS 1 fields have no default value)",
                    rest.join(" ")
                )))
            }
            (false, Flavour::Ros2) => Some(rest.join(" ")),
        };
        if out.fields.iter().any(|f| f.name == fname) {
            return Err(err(format!("field `{fname}` is declared twice")));
        }
        out.fields.push(Field {
            name: fname.to_string(),
            ty,
            default,
            line,
        });
    }
    Ok(out)
}

fn parse_size(text: &str, whole: &str) -> Result<usize, String> {
    match text.parse::<usize>() {
        Ok(n) if n > 0 && n <= u32::MAX as usize => Ok(n),
        _ => Err(format!(
            "`{whole}`: `{text}` is not an array size (a whole number from 1)"
        )),
    }
}

pub(crate) fn parse_type(text: &str, package: &str, flavour: Flavour) -> Result<FieldType, String> {
    let (elem, array) = match text.find('[') {
        None if text.contains(']') => return Err(format!("`{text}` has `]` without `[`")),
        None => (text, Array::No),
        Some(open) => {
            let Some(inner) = text[open + 1..].strip_suffix(']') else {
                return Err(format!("`{text}` is not a type: an array ends with `]`"));
            };
            let array = if inner.is_empty() {
                Array::Unbounded
            } else if let Some(bound) = inner.strip_prefix("<=") {
                if flavour == Flavour::Ros1 {
                    return Err(format!(
                        "`{text}`: bounded arrays are ROS 2 syntax (ROS 1 has `T[N]` and `T[]`)"
                    ));
                }
                Array::Bounded(parse_size(bound, text)?)
            } else {
                Array::Fixed(parse_size(inner, text)?)
            };
            (&text[..open], array)
        }
    };
    let (base, full) = parse_base(elem, package, flavour)?;
    let suffix = &text[elem.len()..];
    Ok(FieldType {
        base,
        array,
        text: format!("{full}{suffix}"),
    })
}

fn parse_base(text: &str, package: &str, flavour: Flavour) -> Result<(Base, String), String> {
    if let Some(p) = Prim::from_name(text, flavour) {
        return Ok((Base::Prim(p), text.into()));
    }
    for (word, wide) in [("string", false), ("wstring", true)] {
        let bound = if text == word {
            None
        } else if let Some(b) = text.strip_prefix(word).and_then(|t| t.strip_prefix("<=")) {
            if flavour == Flavour::Ros1 {
                return Err(format!(
                    "`{text}`: bounded strings are ROS 2 syntax (ROS 1 has `string`)"
                ));
            }
            Some(parse_size(b, text)?)
        } else {
            continue;
        };
        if wide && flavour == Flavour::Ros1 {
            return Err("`wstring` is ROS 2 syntax (ROS 1 has `string`)".into());
        }
        let base = if wide {
            Base::WStr(bound)
        } else {
            Base::Str(bound)
        };
        return Ok((base, text.into()));
    }
    match (text, flavour) {
        ("time", Flavour::Ros1) => return Ok((Base::Time, text.into())),
        ("duration", Flavour::Ros1) => return Ok((Base::Duration, text.into())),
        ("time" | "duration", Flavour::Ros2) => {
            return Err(format!(
                "`{text}` is a ROS 1 type: ROS 2 writes builtin_interfaces/{}",
                if text == "time" { "Time" } else { "Duration" }
            ))
        }
        ("Header", Flavour::Ros1) => {
            return Ok((
                Base::Msg("std_msgs/Header".into()),
                "std_msgs/Header".into(),
            ))
        }
        _ => {}
    }
    let parts: Vec<&str> = text.split('/').collect();
    let (pkg, name) = match parts[..] {
        [name] => (package, name),
        [pkg, name] => (pkg, name),
        [pkg, "msg", name] if flavour == Flavour::Ros2 => (pkg, name),
        _ => {
            return Err(format!(
                "`{text}` is not a type: write `Type` or `package/Type`"
            ))
        }
    };
    if !valid_package(pkg) || !valid_message(name, flavour) {
        return Err(format!(
            "`{text}` is not a type: a primitive (bool, int8 … float64, string{}), `Type` or \
             `package/Type`",
            if flavour == Flavour::Ros1 {
                ", time, duration"
            } else {
                ""
            }
        ));
    }
    let full = format!("{pkg}/{name}");
    Ok((Base::Msg(full.clone()), full))
}

pub(crate) fn constant_value(base: &Base, value: &str) -> Result<String, String> {
    let Base::Prim(p) = base else {
        // The rest of the line (ROS 2's quotes kept, as written).
        return Ok(value.trim().to_string());
    };
    let v = value.trim();
    let ok = match p {
        Prim::Bool => matches!(v, "true" | "false" | "True" | "False" | "0" | "1"),
        Prim::F32 | Prim::F64 => v.parse::<f64>().is_ok(),
        _ => {
            let (lo, hi) = int_range(*p);
            v.parse::<i128>().is_ok_and(|n| (lo..=hi).contains(&n))
        }
    };
    if ok {
        Ok(v.to_string())
    } else {
        Err(format!("`{v}` is not a value of its type"))
    }
}

fn int_range(p: Prim) -> (i128, i128) {
    match p {
        Prim::I8 => (i8::MIN as i128, i8::MAX as i128),
        Prim::U8 => (0, u8::MAX as i128),
        Prim::I16 => (i16::MIN as i128, i16::MAX as i128),
        Prim::U16 => (0, u16::MAX as i128),
        Prim::I32 => (i32::MIN as i128, i32::MAX as i128),
        Prim::U32 => (0, u32::MAX as i128),
        Prim::I64 => (i64::MIN as i128, i64::MAX as i128),
        _ => (0, u64::MAX as i128),
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    fn ros1(text: &str) -> Result<MsgFile, ParseError> {
        parse(
            text,
            "my_msgs/msg/Status.msg",
            "my_msgs",
            "Status",
            Flavour::Ros1,
        )
    }

    fn ros2(text: &str) -> Result<MsgFile, ParseError> {
        parse(
            text,
            "my_msgs/msg/Status.msg",
            "my_msgs",
            "Status",
            Flavour::Ros2,
        )
    }

    #[test]
    fn fields_constants_arrays_and_comments() {
        let m = ros1(
            "# a comment\nHeader header  # trailing\nuint8 OK=0\nuint8 ERROR = 2 # why\n\
             string NAME=a # b\nfloat64[9] covariance\nPoint[] points\nother_msgs/Part part\n\
             time stamp\nduration age\nbyte b\nchar c\n",
        )
        .unwrap();
        let names: Vec<_> = m.fields.iter().map(|f| f.name.as_str()).collect();
        assert_eq!(
            names,
            [
                "header",
                "covariance",
                "points",
                "part",
                "stamp",
                "age",
                "b",
                "c"
            ]
        );
        assert_eq!(m.fields[0].ty.base, Base::Msg("std_msgs/Header".into()));
        assert_eq!(m.fields[0].ty.text, "std_msgs/Header");
        assert_eq!(m.fields[1].ty.array, Array::Fixed(9));
        assert_eq!(m.fields[1].ty.text, "float64[9]");
        assert_eq!(m.fields[2].ty.base, Base::Msg("my_msgs/Point".into()));
        assert_eq!(m.fields[2].ty.array, Array::Unbounded);
        assert_eq!(m.fields[2].ty.text, "my_msgs/Point[]");
        assert_eq!(m.fields[3].ty.base, Base::Msg("other_msgs/Part".into()));
        assert_eq!(m.fields[4].ty.base, Base::Time);
        assert_eq!(m.fields[6].ty.base, Base::Prim(Prim::I8));
        assert_eq!(m.fields[7].ty.base, Base::Prim(Prim::U8));
        let consts: Vec<_> = m
            .constants
            .iter()
            .map(|c| (c.ty.as_str(), c.name.as_str(), c.value.as_str()))
            .collect();
        assert_eq!(
            consts,
            [
                ("uint8", "OK", "0"),
                ("uint8", "ERROR", "2"),
                ("string", "NAME", "a # b")
            ]
        );
    }

    #[test]
    fn ros_2_has_bounds_defaults_and_no_time() {
        let m = ros2(
            "string<=8 name \"x\"\nint32[<=3] ids [1, 2]\nbuiltin_interfaces/Time stamp\n\
             uint8 LEVEL = 1\nstd_msgs/msg/Header header\n",
        )
        .unwrap();
        assert_eq!(m.fields[0].ty.base, Base::Str(Some(8)));
        assert_eq!(m.fields[0].default.as_deref(), Some("\"x\""));
        assert_eq!(m.fields[1].ty.array, Array::Bounded(3));
        assert_eq!(m.fields[1].default.as_deref(), Some("[1, 2]"));
        assert_eq!(m.fields[3].ty.base, Base::Msg("std_msgs/Header".into()));
        let e = ros2("time stamp\n").unwrap_err();
        assert_eq!(
            e.to_string(),
            "my_msgs/msg/Status.msg:1: `time` is a ROS 1 type: ROS 2 writes builtin_interfaces/Time"
        );
    }

    #[test]
    fn malformed_lines_are_errors_at_file_and_line() {
        let cases = [
            (
                "int32 a\nint32[3 b\n",
                2,
                "`int32[3` is not a type: an array ends with `]`",
            ),
            (
                "float64\n",
                1,
                "`float64` has no field name: write `float64 NAME`",
            ),
            ("int32 2x\n", 1, "`2x` is not a field name"),
            ("int32 a\nint32 a\n", 2, "field `a` is declared twice"),
            (
                "uint8 X=300\n",
                1,
                "constant `X`: `300` is not a value of its type",
            ),
            ("int32[0] a\n", 1, "`int32[0]`: `0` is not an array size"),
            ("int32[<=3] a\n", 1, "bounded arrays are ROS 2 syntax"),
            (
                "float64 x 1.0\n",
                1,
                "unexpected `1.0` after field `x` (ROS 1 fields have",
            ),
            ("Foo/Bar/Baz x\n", 1, "`Foo/Bar/Baz` is not a type"),
            ("int32 a\n---\nint32 b\n", 2, "`---` separates"),
            ("time[2] T=1\n", 1, "a constant is a primitive or a string"),
        ];
        for (text, line, what) in cases {
            let e = ros1(text).unwrap_err();
            assert_eq!(e.line, line, "{text:?}: {e}");
            assert!(e.what.contains(what), "{text:?}: {e}");
            assert!(e
                .to_string()
                .starts_with(&format!("my_msgs/msg/Status.msg:{line}: ")));
        }
        assert!(ros2("int32 Bad\n").unwrap_err().what.contains("lower case"));
        assert!(ros2("int32 bad_\n").is_err());
        assert!(ros2("uint8 lower=1\n").is_err());
    }
}

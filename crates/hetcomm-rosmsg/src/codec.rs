//! Conversion between a hetcomm payload (MessagePack, structs as maps keyed by serde field
//! names) and a ROS message on the wire, field by field, by name, for both encodings:
//! ROS 2's CDR (XCDR1 little endian when writing; either byte order and XCDR2 when reading)
//! and ROS 1's serialization (little endian, packed, strings without a NUL).
//!
//! A hetcomm message maps to a ROS type when its serde fields are named as the ROS type's:
//! `struct Twist { linear: Vector3, angular: Vector3 }` with `struct Vector3 { x: f64, y: f64,
//! z: f64 }` is `geometry_msgs/Twist`. Towards ROS, every ROS field must be present (numbers
//! convert when they fit) and no other field may be: a mismatch is an error naming both types
//! and the field. From ROS, the message becomes a map of every ROS field; a hetcomm struct may
//! declare only some of them (serde ignores the rest). `uint8` arrays (an image's pixels, a
//! point cloud's points) are copied whole each way: MessagePack bytes from ROS, and bytes or
//! an array of integers towards it.

use rmpv::Value;

use crate::schema::{RosType, Ty};

/// A wire encoding of ROS messages.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum Wire {
    /// ROS 2's CDR body (after the 4-byte encapsulation header). `little` is the byte order;
    /// `xcdr2` caps alignment at 4 bytes. [`encode`] writes XCDR1 little endian only.
    Cdr {
        /// Little endian.
        little: bool,
        /// XCDR2 (8-byte values aligned to 4).
        xcdr2: bool,
    },
    /// ROS 1's serialization of a message body (without TCPROS's 4-byte length): little
    /// endian, no padding, strings as a `u32` length and the bytes, fixed arrays bare.
    Ros1,
}

impl Wire {
    /// What ROS 2 writes: XCDR1, little endian.
    pub const CDR: Wire = Wire::Cdr {
        little: true,
        xcdr2: false,
    };

    /// Largest alignment (0: none, as in ROS 1).
    fn max_align(self) -> usize {
        match self {
            Wire::Cdr { xcdr2: true, .. } => 4,
            Wire::Cdr { .. } => 8,
            Wire::Ros1 => 0,
        }
    }
}

/// Converts a MessagePack value (a hetcomm payload) into `ty`'s body in `wire` (CDR is
/// written XCDR1 little endian whatever `wire` says). `what` names the hetcomm type in errors.
pub fn encode(value: &Value, ty: &RosType, wire: Wire, what: &str) -> Result<Vec<u8>, String> {
    let mut w = Writer {
        out: Vec::with_capacity(64),
        cdr: wire != Wire::Ros1,
    };
    w.msg(value, ty, "")
        .map_err(|e| format!("{what} does not convert to {}: {e}", ty.name))?;
    Ok(w.out)
}

/// Reads `ty`'s body in `wire` into a MessagePack value: a map of every field by name. ROS 1
/// bodies must end where the message does (trailing bytes are an error: another type).
pub fn decode(body: &[u8], ty: &RosType, wire: Wire) -> Result<Value, String> {
    let mut r = Reader {
        body,
        pos: 0,
        little: !matches!(wire, Wire::Cdr { little: false, .. }),
        max_align: wire.max_align(),
    };
    let v = r.msg(ty, "")?;
    if wire == Wire::Ros1 && r.pos != body.len() {
        return Err(format!(
            "{} bytes are left after the message ({} bytes)",
            body.len() - r.pos,
            body.len()
        ));
    }
    Ok(v)
}

fn field_path(prefix: &str, name: &str) -> String {
    if prefix.is_empty() {
        name.to_string()
    } else {
        format!("{prefix}.{name}")
    }
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

struct Writer {
    out: Vec<u8>,
    /// CDR (aligned, strings with a NUL) rather than ROS 1.
    cdr: bool,
}

impl Writer {
    fn put(&mut self, bytes: &[u8]) {
        if self.cdr {
            while !self.out.len().is_multiple_of(bytes.len()) {
                self.out.push(0);
            }
        }
        self.out.extend_from_slice(bytes);
    }

    fn msg(&mut self, value: &Value, ty: &RosType, path: &str) -> Result<(), String> {
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
            self.value(v, fty, &p)?;
        }
        Ok(())
    }

    fn value(&mut self, v: &Value, ty: &Ty, path: &str) -> Result<(), String> {
        match ty {
            Ty::Bool => match v {
                Value::Boolean(b) => self.out.push(*b as u8),
                _ => {
                    return Err(format!(
                        "field `{path}` is {}, the ROS field is bool",
                        kind_of(v)
                    ))
                }
            },
            Ty::I8 => {
                let n = int_in(v, path, i8::MIN as i64, i8::MAX as i64, "int8")?;
                self.out.push(n as i8 as u8)
            }
            Ty::U8 => self
                .out
                .push(int_in(v, path, 0, u8::MAX as i64, "uint8")? as u8),
            Ty::I16 => {
                let n = int_in(v, path, i16::MIN as i64, i16::MAX as i64, "int16")? as i16;
                self.put(&n.to_le_bytes());
            }
            Ty::U16 => {
                let n = int_in(v, path, 0, u16::MAX as i64, "uint16")? as u16;
                self.put(&n.to_le_bytes());
            }
            Ty::I32 => {
                let n = int_in(v, path, i32::MIN as i64, i32::MAX as i64, "int32")? as i32;
                self.put(&n.to_le_bytes());
            }
            Ty::U32 => {
                let n = int_in(v, path, 0, u32::MAX as i64, "uint32")? as u32;
                self.put(&n.to_le_bytes());
            }
            Ty::I64 => {
                let n = int_in(v, path, i64::MIN, i64::MAX, "int64")?;
                self.put(&n.to_le_bytes());
            }
            Ty::U64 => {
                let n = match v {
                    Value::Integer(i) => i.as_u64(),
                    _ => None,
                };
                let Some(n) = n else {
                    return Err(format!(
                        "field `{path}` is {} ({v}), the ROS field is uint64",
                        kind_of(v)
                    ));
                };
                self.put(&n.to_le_bytes());
            }
            Ty::F32 => {
                let x = float(v, path, "float32")? as f32;
                self.put(&x.to_le_bytes());
            }
            Ty::F64 => {
                let x = float(v, path, "float64")?;
                self.put(&x.to_le_bytes());
            }
            Ty::Str | Ty::BoundedStr(_) => {
                let Value::String(s) = v else {
                    return Err(format!(
                        "field `{path}` is {}, the ROS field is {}",
                        kind_of(v),
                        ty_name(ty)
                    ));
                };
                let bytes = s.as_bytes();
                if let Ty::BoundedStr(max) = ty {
                    if bytes.len() > *max {
                        return Err(format!(
                            "field `{path}` has {} bytes, the ROS field has at most {max}",
                            bytes.len()
                        ));
                    }
                }
                // CDR counts and writes a terminating NUL; ROS 1 has none.
                let nul = self.cdr as usize;
                self.put(&((bytes.len() + nul) as u32).to_le_bytes());
                self.out.extend_from_slice(bytes);
                if self.cdr {
                    self.out.push(0);
                }
            }
            Ty::Array(elem, n) => {
                if let (Value::Binary(b), Ty::U8) = (v, &**elem) {
                    if b.len() != *n {
                        return Err(format!(
                            "field `{path}` has {} elements, the ROS field has {n}",
                            b.len()
                        ));
                    }
                    self.out.extend_from_slice(b);
                    return Ok(());
                }
                let items = self.items(v, elem, path, &format!("an array of {n}"))?;
                if items.len() != *n {
                    return Err(format!(
                        "field `{path}` has {} elements, the ROS field has {n}",
                        items.len()
                    ));
                }
                self.elements(&items, elem, path)?;
            }
            Ty::Seq(elem, bound) => {
                if let (Value::Binary(b), Ty::U8) = (v, &**elem) {
                    // Bytes (an image's pixels) are copied whole, not element by element.
                    self.seq_len(b.len(), *bound, path)?;
                    self.out.extend_from_slice(b);
                    return Ok(());
                }
                let items = self.items(v, elem, path, "an array")?;
                self.seq_len(items.len(), *bound, path)?;
                self.elements(&items, elem, path)?;
            }
            Ty::Msg(inner) => self.msg(v, inner, path)?,
        }
        Ok(())
    }

    /// Writes a sequence's length, checked against its bound.
    fn seq_len(&mut self, len: usize, bound: Option<usize>, path: &str) -> Result<(), String> {
        if let Some(max) = bound {
            if len > max {
                return Err(format!(
                    "field `{path}` has {len} elements, the ROS field has at most {max}"
                ));
            }
        }
        let len = u32::try_from(len)
            .map_err(|_| format!("field `{path}` has more than 2^32 elements"))?;
        self.put(&len.to_le_bytes());
        Ok(())
    }

    /// The elements of an array value; bytes (MessagePack bin) are an array of `uint8`s.
    fn items<'v>(
        &self,
        v: &'v Value,
        elem: &Ty,
        path: &str,
        what: &str,
    ) -> Result<std::borrow::Cow<'v, [Value]>, String> {
        match v {
            Value::Array(items) => Ok(std::borrow::Cow::Borrowed(items)),
            Value::Binary(b) if matches!(elem, Ty::U8) => Ok(std::borrow::Cow::Owned(
                b.iter().map(|x| Value::from(*x)).collect(),
            )),
            _ => Err(format!(
                "field `{path}` is {}, the ROS field is {what}",
                kind_of(v)
            )),
        }
    }

    fn elements(&mut self, items: &[Value], elem: &Ty, path: &str) -> Result<(), String> {
        self.out
            .reserve(items.len().saturating_mul(min_size(elem, self.cdr)));
        for (i, item) in items.iter().enumerate() {
            // An element's path is formatted only when it fails (formatting one per element
            // cost more than the conversion of a large array): the failing one is written
            // again with its path, for the error.
            let start = self.out.len();
            if self.value(item, elem, path).is_err() {
                self.out.truncate(start);
                self.value(item, elem, &format!("{path}[{i}]"))?;
            }
        }
        Ok(())
    }
}

fn float(v: &Value, path: &str, ros: &str) -> Result<f64, String> {
    match v {
        Value::F64(x) => Ok(*x),
        Value::F32(x) => Ok(*x as f64),
        Value::Integer(i) => Ok(i.as_f64().unwrap_or(f64::NAN)),
        _ => Err(format!(
            "field `{path}` is {}, the ROS field is {ros}",
            kind_of(v)
        )),
    }
}

/// A field type's ROS name, as a `.msg` file writes it.
pub fn ty_name(ty: &Ty) -> String {
    match ty {
        Ty::Bool => "bool".into(),
        Ty::I8 => "int8".into(),
        Ty::U8 => "uint8".into(),
        Ty::I16 => "int16".into(),
        Ty::U16 => "uint16".into(),
        Ty::I32 => "int32".into(),
        Ty::U32 => "uint32".into(),
        Ty::I64 => "int64".into(),
        Ty::U64 => "uint64".into(),
        Ty::F32 => "float32".into(),
        Ty::F64 => "float64".into(),
        Ty::Str => "string".into(),
        Ty::BoundedStr(n) => format!("string<={n}"),
        Ty::Array(elem, n) => format!("{}[{n}]", ty_name(elem)),
        Ty::Seq(elem, None) => format!("{}[]", ty_name(elem)),
        Ty::Seq(elem, Some(n)) => format!("{}[<={n}]", ty_name(elem)),
        Ty::Msg(m) => m.name.into(),
    }
}

/// The fewest bytes a value of `ty` takes on the wire (without alignment): what a length
/// prefix is checked against before anything is allocated.
fn min_size(ty: &Ty, cdr: bool) -> usize {
    match ty {
        Ty::Bool | Ty::I8 | Ty::U8 => 1,
        Ty::I16 | Ty::U16 => 2,
        Ty::I32 | Ty::U32 | Ty::F32 => 4,
        Ty::I64 | Ty::U64 | Ty::F64 => 8,
        // A length, and in CDR its NUL.
        Ty::Str | Ty::BoundedStr(_) => 4 + cdr as usize,
        Ty::Seq(..) => 4,
        Ty::Array(elem, n) => min_size(elem, cdr).saturating_mul(*n),
        Ty::Msg(m) => m
            .fields
            .iter()
            .fold(0usize, |acc, (_, t)| acc.saturating_add(min_size(t, cdr))),
    }
}

/// Elements of zero size (empty messages) an array may announce: nothing bounds them by
/// the bytes left.
const MAX_EMPTY_ELEMENTS: usize = 1 << 16;

struct Reader<'a> {
    body: &'a [u8],
    pos: usize,
    little: bool,
    /// 8 for plain CDR, 4 for XCDR2, 0 for ROS 1 (no alignment, no NUL after strings).
    max_align: usize,
}

impl Reader<'_> {
    /// The next value of `n` bytes (a number), aligned to its size as the wire says.
    fn take(&mut self, n: usize, path: &str) -> Result<&[u8], String> {
        let a = n.min(self.max_align);
        if a > 1 && !self.pos.is_multiple_of(a) {
            self.pos += a - self.pos % a;
        }
        self.bytes(n, path)
    }

    /// The next `n` bytes, unaligned.
    fn bytes(&mut self, n: usize, path: &str) -> Result<&[u8], String> {
        let end = self.pos.saturating_add(n);
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

    fn msg(&mut self, ty: &RosType, path: &str) -> Result<Value, String> {
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
            Ty::I16 => Value::from(i16::from_le_bytes(self.num(path)?)),
            Ty::U16 => Value::from(u16::from_le_bytes(self.num(path)?)),
            Ty::I32 => Value::from(i32::from_le_bytes(self.num(path)?)),
            Ty::U32 => Value::from(u32::from_le_bytes(self.num(path)?)),
            Ty::I64 => Value::from(i64::from_le_bytes(self.num(path)?)),
            Ty::U64 => Value::from(u64::from_le_bytes(self.num(path)?)),
            Ty::F32 => Value::F32(f32::from_le_bytes(self.num(path)?)),
            Ty::F64 => Value::F64(f64::from_le_bytes(self.num(path)?)),
            Ty::Str | Ty::BoundedStr(_) => {
                let len = u32::from_le_bytes(self.num(path)?) as usize;
                let cdr = self.max_align > 0;
                if cdr && len == 0 {
                    return Err(format!("string `{path}` has length 0 (no terminating NUL)"));
                }
                let raw = self
                    .body
                    .get(self.pos..self.pos.saturating_add(len))
                    .ok_or_else(|| format!("string `{path}` runs past the end of the message"))?;
                self.pos += len;
                let text = if cdr { &raw[..len - 1] } else { raw };
                if let Ty::BoundedStr(max) = ty {
                    if text.len() > *max {
                        return Err(format!(
                            "string `{path}` has {} bytes, the ROS field has at most {max}",
                            text.len()
                        ));
                    }
                }
                let text = std::str::from_utf8(text)
                    .map_err(|_| format!("string `{path}` is not UTF-8"))?;
                Value::from(text)
            }
            Ty::Array(elem, n) => self.elements(elem, *n, path)?,
            Ty::Seq(elem, bound) => {
                let n = u32::from_le_bytes(self.num(path)?) as usize;
                if let Some(max) = bound {
                    if n > *max {
                        return Err(format!(
                            "`{path}` has {n} elements, the ROS field has at most {max}"
                        ));
                    }
                }
                self.elements(elem, n, path)?
            }
            Ty::Msg(inner) => self.msg(inner, path)?,
        })
    }

    /// `n` elements of `elem`, checked against the bytes left before allocating.
    fn elements(&mut self, elem: &Ty, n: usize, path: &str) -> Result<Value, String> {
        let left = self.body.len().saturating_sub(self.pos);
        let each = min_size(elem, self.max_align > 0);
        let fits = match each {
            0 => n <= MAX_EMPTY_ELEMENTS,
            _ => n <= left / each,
        };
        if !fits {
            return Err(format!(
                "`{path}` has {n} elements, more than the {left} bytes left can hold"
            ));
        }
        if matches!(elem, Ty::U8) {
            // Bytes (an image's pixels) in one copy, as MessagePack bin: rmp-serde reads them
            // into a `Vec<u8>`, `[u8; N]` or `serde_bytes`, Python as `bytes` (as rospy and
            // rclpy give them), where an array of integers cost 30 bytes of memory a pixel.
            let bytes = self.bytes(n, path)?;
            return Ok(Value::Binary(bytes.to_vec()));
        }
        let mut items = Vec::with_capacity(n);
        for i in 0..n {
            // As when writing: the path is formatted only for an element that fails, read
            // again from where it started.
            let start = self.pos;
            match self.value(elem, path) {
                Ok(v) => items.push(v),
                Err(_) => {
                    self.pos = start;
                    items.push(self.value(elem, &format!("{path}[{i}]"))?);
                }
            }
        }
        Ok(Value::Array(items))
    }
}

#[cfg(test)]
#[path = "codec_tests.rs"]
mod tests;

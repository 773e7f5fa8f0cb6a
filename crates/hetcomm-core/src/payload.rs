//! The language-neutral payload encoding: MessagePack, with structs written as maps keyed by
//! field name (so a Python program decodes a Rust module's message with any MessagePack
//! library and no generated code). See `docs/wire-format.md` for how each Rust shape maps.

use serde::{de::DeserializeOwned, Serialize};

/// Why a payload could not be encoded or decoded.
#[derive(Debug, thiserror::Error)]
#[non_exhaustive]
pub enum PayloadError {
    /// The value could not be written as MessagePack.
    #[error("cannot encode payload: {0}")]
    Encode(#[from] rmp_serde::encode::Error),
    /// The bytes are not a valid encoding of the expected type.
    #[error("cannot decode payload as {type_name}: {source}")]
    Decode {
        /// The Rust type that was expected.
        type_name: &'static str,
        /// What the decoder said.
        source: rmp_serde::decode::Error,
    },
    /// The bytes decoded, but bytes were left over.
    #[error("payload for {type_name} has {extra} trailing bytes")]
    Trailing {
        /// The Rust type that was expected.
        type_name: &'static str,
        /// Bytes left after the value.
        extra: usize,
    },
}

/// Encodes a value (appending to `out`).
pub fn encode_into<T: Serialize + ?Sized>(
    value: &T,
    out: &mut Vec<u8>,
) -> Result<(), PayloadError> {
    let mut ser = rmp_serde::Serializer::new(out).with_struct_map();
    value.serialize(&mut ser)?;
    Ok(())
}

/// Encodes a value into a new buffer.
pub fn encode<T: Serialize + ?Sized>(value: &T) -> Result<Vec<u8>, PayloadError> {
    let mut out = Vec::new();
    encode_into(value, &mut out)?;
    Ok(out)
}

/// Encodes a value into a [`crate::PayloadBuf`]: inline, with no allocation, when small.
pub fn encode_buf<T: Serialize + ?Sized>(value: &T) -> Result<crate::PayloadBuf, PayloadError> {
    let mut out = crate::PayloadBuf::new();
    let mut ser = rmp_serde::Serializer::new(&mut out).with_struct_map();
    value.serialize(&mut ser)?;
    Ok(out)
}

/// Decodes exactly one value; trailing bytes are an error.
pub fn decode<T: DeserializeOwned>(bytes: &[u8]) -> Result<T, PayloadError> {
    let type_name = std::any::type_name::<T>();
    let mut cursor = std::io::Cursor::new(bytes);
    let value = {
        let mut de = rmp_serde::Deserializer::new(&mut cursor);
        T::deserialize(&mut de).map_err(|source| PayloadError::Decode { type_name, source })?
    };
    let used = cursor.position() as usize;
    if used != bytes.len() {
        return Err(PayloadError::Trailing {
            type_name,
            extra: bytes.len() - used,
        });
    }
    Ok(value)
}

/// Decodes any payload into JSON without knowing its type (MessagePack is self-describing).
/// Tools such as `hetcomm listen` use it; `None` when the bytes are not one MessagePack value.
pub fn to_json(bytes: &[u8]) -> Option<serde_json::Value> {
    let mut cursor = std::io::Cursor::new(bytes);
    let value = rmpv::decode::read_value(&mut cursor).ok()?;
    if cursor.position() as usize != bytes.len() {
        return None;
    }
    serde_json::to_value(ValueAsJson(&value)).ok()
}

/// Encodes a JSON value as a MessagePack payload (objects become maps, as struct fields do).
pub fn from_json(value: &serde_json::Value) -> Result<Vec<u8>, PayloadError> {
    encode(value)
}

/// Serializes an `rmpv::Value` the way JSON users expect (binary as an array of numbers, map
/// keys as strings).
struct ValueAsJson<'a>(&'a rmpv::Value);

impl Serialize for ValueAsJson<'_> {
    fn serialize<S: serde::Serializer>(&self, s: S) -> Result<S::Ok, S::Error> {
        use rmpv::Value as V;
        use serde::ser::{SerializeMap, SerializeSeq};
        match self.0 {
            V::Nil => s.serialize_unit(),
            V::Boolean(b) => s.serialize_bool(*b),
            V::Integer(i) => {
                if let Some(v) = i.as_i64() {
                    s.serialize_i64(v)
                } else {
                    s.serialize_u64(i.as_u64().unwrap_or_default())
                }
            }
            V::F32(f) => s.serialize_f32(*f),
            V::F64(f) => s.serialize_f64(*f),
            V::String(text) => s.serialize_str(text.as_str().unwrap_or("<invalid utf-8>")),
            V::Binary(b) => s.collect_seq(b.iter()),
            V::Array(items) => {
                let mut seq = s.serialize_seq(Some(items.len()))?;
                for item in items {
                    seq.serialize_element(&ValueAsJson(item))?;
                }
                seq.end()
            }
            V::Map(entries) => {
                let mut map = s.serialize_map(Some(entries.len()))?;
                for (k, v) in entries {
                    let key = match k {
                        V::String(text) => text.as_str().unwrap_or_default().to_string(),
                        other => other.to_string(),
                    };
                    map.serialize_entry(&key, &ValueAsJson(v))?;
                }
                map.end()
            }
            V::Ext(tag, data) => {
                let mut map = s.serialize_map(Some(2))?;
                map.serialize_entry("ext", tag)?;
                map.serialize_entry("data", data)?;
                map.end()
            }
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use serde::Deserialize;

    #[derive(Serialize, Deserialize, Debug, PartialEq)]
    struct Wheels {
        left: f64,
        right: f64,
    }

    #[test]
    fn structs_are_maps_by_field_name() {
        let bytes = encode(&Wheels {
            left: -10.0,
            right: 10.0,
        })
        .unwrap();
        assert_eq!(
            to_json(&bytes).unwrap(),
            serde_json::json!({"left": -10.0, "right": 10.0})
        );
        assert_eq!(
            decode::<Wheels>(&bytes).unwrap(),
            Wheels {
                left: -10.0,
                right: 10.0
            }
        );
    }

    #[test]
    fn trailing_bytes_are_rejected() {
        let mut bytes = encode(&Wheels {
            left: 1.0,
            right: 1.0,
        })
        .unwrap();
        bytes.push(0xc0);
        assert!(matches!(
            decode::<Wheels>(&bytes),
            Err(PayloadError::Trailing { extra: 1, .. })
        ));
        assert!(to_json(&bytes).is_none());
    }

    #[test]
    fn json_round_trip() {
        let json = serde_json::json!({"left": 1.5, "right": 2.5});
        let bytes = from_json(&json).unwrap();
        assert_eq!(
            decode::<Wheels>(&bytes).unwrap(),
            Wheels {
                left: 1.5,
                right: 2.5
            }
        );
    }
}

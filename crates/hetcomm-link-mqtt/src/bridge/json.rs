//! The JSON side of an `mqtt_bridge`: a mapping's declared JSON fields ([`Field`]), the
//! checks of a payload against them and against a program's declared message type
//! ([`Shape`]), and the conversion of JSON to and from hetcomm's MessagePack payloads, field
//! by field. Every refusal is a sentence naming the field.

use hetcomm_link::shape::Shape;
use rmpv::Value as Mp;
use serde_json::{Map, Number, Value as Js};

/// The JSON type a mapping declares for a field (`orderId:string`).
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum JsonType {
    /// `string`.
    String,
    /// `number`: any JSON number (an integer too).
    Number,
    /// `integer`: a number without a fraction.
    Integer,
    /// `bool`.
    Bool,
    /// `object`.
    Object,
    /// `array`.
    Array,
    /// `any`: present, of any type.
    Any,
}

/// The names [`JsonType::parse`] reads, for help texts.
pub const TYPE_NAMES: &str = "string, number, integer, bool, object, array, any";

impl JsonType {
    /// `string`, `number`, … (see [`TYPE_NAMES`]).
    pub fn parse(text: &str) -> Option<JsonType> {
        Some(match text {
            "string" => JsonType::String,
            "number" => JsonType::Number,
            "integer" => JsonType::Integer,
            "bool" => JsonType::Bool,
            "object" => JsonType::Object,
            "array" => JsonType::Array,
            "any" => JsonType::Any,
            _ => return None,
        })
    }

    /// Its name in fleet files.
    pub fn name(self) -> &'static str {
        match self {
            JsonType::String => "string",
            JsonType::Number => "number",
            JsonType::Integer => "integer",
            JsonType::Bool => "bool",
            JsonType::Object => "object",
            JsonType::Array => "array",
            JsonType::Any => "any",
        }
    }

    fn admits(self, v: &Js) -> bool {
        match self {
            JsonType::String => v.is_string(),
            JsonType::Number => v.is_number(),
            JsonType::Integer => v.is_i64() || v.is_u64(),
            JsonType::Bool => v.is_boolean(),
            JsonType::Object => v.is_object(),
            JsonType::Array => v.is_array(),
            JsonType::Any => true,
        }
    }

    /// Whether a message field of `shape` can take (and give) this JSON type.
    fn fits(self, shape: &Shape) -> bool {
        match (self, shape) {
            (_, Shape::Unknown | Shape::Enum(_)) | (JsonType::Any, _) => true,
            (t, Shape::Option(inner)) => t.fits(inner),
            (JsonType::String, Shape::Str) => true,
            // An integer goes into a float field (serde widens it), not the other way round.
            (JsonType::Number, Shape::Float) => true,
            (JsonType::Integer, Shape::Int | Shape::Float) => true,
            (JsonType::Bool, Shape::Bool) => true,
            (JsonType::Object, Shape::Struct { .. } | Shape::Map(..)) => true,
            (JsonType::Array, Shape::Seq(_) | Shape::Tuple(_)) => true,
            _ => false,
        }
    }
}

/// One field a mapping declares: `name:type`, `name:type?` when it may be missing or null.
#[derive(Clone, Debug, PartialEq, Eq)]
pub struct Field {
    /// The JSON member's name, which is the message field's serde name.
    pub name: String,
    /// Its JSON type.
    pub ty: JsonType,
    /// `?`: it may be missing or `null`.
    pub optional: bool,
}

impl Field {
    /// Reads `name:type` or `name:type?`; the error says what is wrong.
    pub fn parse(text: &str) -> Result<Field, String> {
        let Some((name, ty)) = text.split_once(':') else {
            return Err(format!("`{text}` is not `FIELD:TYPE`"));
        };
        let (ty, optional) = match ty.strip_suffix('?') {
            Some(t) => (t, true),
            None => (ty, false),
        };
        if name.is_empty() {
            return Err(format!("`{text}` names no field"));
        }
        let ty = JsonType::parse(ty)
            .ok_or_else(|| format!("`{ty}` in `{text}` is not a JSON type ({TYPE_NAMES})"))?;
        Ok(Field {
            name: name.to_string(),
            ty,
            optional,
        })
    }
}

/// What a JSON value is, in words.
fn describe(v: &Js) -> &'static str {
    match v {
        Js::Null => "null",
        Js::Bool(_) => "a bool",
        Js::Number(n) if n.is_f64() => "a number with a fraction",
        Js::Number(_) => "an integer",
        Js::String(_) => "a string",
        Js::Array(_) => "an array",
        Js::Object(_) => "an object",
    }
}

/// Whether `object` has every declared field with its type; the error names the first that
/// does not.
pub fn check_fields(object: &Map<String, Js>, fields: &[Field]) -> Result<(), String> {
    for f in fields {
        match object.get(&f.name) {
            None | Some(Js::Null) if f.optional => {}
            None => return Err(format!("field `{}` is missing", f.name)),
            Some(v) if !f.ty.admits(v) => {
                return Err(format!(
                    "field `{}` is {}, the mapping says {}",
                    f.name,
                    describe(v),
                    f.ty.name()
                ))
            }
            Some(_) => {}
        }
    }
    Ok(())
}

fn path_of(prefix: &str, name: &str) -> String {
    match prefix.is_empty() {
        true => name.to_string(),
        false => format!("{prefix}.{name}"),
    }
}

/// Whether `v` decodes as a value of `shape` (a declared message type); the error names the
/// field (`agvPosition.x`) and what is wrong.
pub fn fits_shape(v: &Js, shape: &Shape, path: &str) -> Result<(), String> {
    let wrong = |wants: String| {
        let at = match path.is_empty() {
            true => "the message".to_string(),
            false => format!("field `{path}`"),
        };
        Err(format!(
            "{at} is {}, the message type wants {wants}",
            describe(v)
        ))
    };
    match shape {
        Shape::Unknown | Shape::Enum(_) | Shape::Bytes => Ok(()),
        Shape::Option(_) if v.is_null() => Ok(()),
        Shape::Option(inner) => fits_shape(v, inner, path),
        Shape::Bool if v.is_boolean() => Ok(()),
        Shape::Int if v.is_i64() || v.is_u64() => Ok(()),
        Shape::Float if v.is_number() => Ok(()),
        Shape::Str if v.is_string() => Ok(()),
        Shape::Unit if v.is_null() => Ok(()),
        Shape::Seq(inner) => match v {
            Js::Array(items) => items
                .iter()
                .enumerate()
                .try_for_each(|(i, item)| fits_shape(item, inner, &format!("{path}[{i}]"))),
            _ => wrong("an array".into()),
        },
        Shape::Tuple(items) => match v {
            Js::Array(values) if values.len() == items.len() => values
                .iter()
                .zip(items)
                .enumerate()
                .try_for_each(|(i, (v, s))| fits_shape(v, s, &format!("{path}[{i}]"))),
            _ => wrong(format!("an array of {}", items.len())),
        },
        Shape::Map(_, value) => match v {
            Js::Object(members) => members
                .iter()
                .try_for_each(|(k, v)| fits_shape(v, value, &path_of(path, k))),
            _ => wrong("an object".into()),
        },
        Shape::Struct { fields, .. } => match v {
            Js::Object(members) => fields.iter().try_for_each(|(name, s)| {
                let p = path_of(path, name);
                match members.get(name) {
                    Some(v) => fits_shape(v, s, &p),
                    None if matches!(s, Shape::Option(_)) => Ok(()),
                    None => Err(format!("field `{p}` is missing")),
                }
            }),
            _ => wrong("an object".into()),
        },
        other => wrong(other.describe()),
    }
}

/// Whether a declared message type (`shape`) and a mapping's declared JSON fields agree, in
/// the direction the mapping converts: towards MQTT (`to_mqtt`) every required JSON field
/// must be a field of the type, of a fitting type and not an `Option`; from MQTT every field
/// the type needs (not an `Option`) must be a required JSON field or a topic capture
/// (`captures`, strings), of a fitting type. A mapping that declares no fields is checked per
/// message against the type instead.
pub fn check_declared(
    shape: &Shape,
    fields: &[Field],
    captures: &[String],
    to_mqtt: bool,
) -> Result<(), String> {
    let Shape::Struct { name, fields: own } = shape else {
        return match shape {
            Shape::Unknown | Shape::Map(..) | Shape::Enum(_) => Ok(()),
            other => Err(format!(
                "the message is {}, a JSON payload is an object (a struct with its fields)",
                other.describe()
            )),
        };
    };
    if fields.is_empty() && captures.is_empty() {
        return Ok(());
    }
    for f in fields {
        let theirs = own.iter().find(|(n, _)| *n == f.name).map(|(_, s)| s);
        match theirs {
            Some(s) if !f.ty.fits(s) => {
                return Err(format!(
                    "field `{}` is {} in {name}, the mapping says {}",
                    f.name,
                    s.describe(),
                    f.ty.name()
                ))
            }
            Some(Shape::Option(_)) if to_mqtt && !f.optional => {
                return Err(format!(
                    "field `{}` is an Option in {name}, the mapping requires it (a None would \
                     be refused): write `{}:{}?`",
                    f.name,
                    f.name,
                    f.ty.name()
                ))
            }
            None if to_mqtt && !f.optional => {
                return Err(format!(
                    "the mapping requires field `{}`, which {name} does not have",
                    f.name
                ))
            }
            _ => {}
        }
    }
    if !to_mqtt {
        for (field, s) in own {
            if matches!(s, Shape::Option(_)) {
                continue;
            }
            let required = fields.iter().any(|f| f.name == *field && !f.optional);
            let captured = captures.contains(field);
            if captured && !JsonType::String.fits(s) {
                return Err(format!(
                    "field `{field}` takes a topic level (a string), it is {} in {name}",
                    s.describe()
                ));
            }
            if !required && !captured {
                return Err(format!(
                    "field `{field}` of {name} is not among the mapping's required fields, so a \
                     payload may lack it: add `{field}:TYPE` to the mapping, or make it an Option"
                ));
            }
        }
    }
    Ok(())
}

/// A JSON value as MessagePack (numbers keep their kind: integers as integers).
pub fn to_msgpack(v: &Js) -> Mp {
    match v {
        Js::Null => Mp::Nil,
        Js::Bool(b) => Mp::Boolean(*b),
        Js::Number(n) => match (n.as_u64(), n.as_i64()) {
            (Some(u), _) => Mp::from(u),
            (None, Some(i)) => Mp::from(i),
            _ => Mp::F64(n.as_f64().unwrap_or(f64::NAN)),
        },
        Js::String(s) => Mp::from(s.as_str()),
        Js::Array(items) => Mp::Array(items.iter().map(to_msgpack).collect()),
        Js::Object(members) => Mp::Map(
            members
                .iter()
                .map(|(k, v)| (Mp::from(k.as_str()), to_msgpack(v)))
                .collect(),
        ),
    }
}

/// A MessagePack value as JSON; the error names the field JSON cannot carry (bytes, a
/// non-string key, a non-finite float, an extension type).
pub fn to_json(v: &Mp, path: &str) -> Result<Js, String> {
    let at = |what: &str| match path.is_empty() {
        true => format!("the message is {what}, which JSON cannot carry"),
        false => format!("field `{path}` is {what}, which JSON cannot carry"),
    };
    Ok(match v {
        Mp::Nil => Js::Null,
        Mp::Boolean(b) => Js::Bool(*b),
        Mp::Integer(i) => match (i.as_u64(), i.as_i64()) {
            (Some(u), _) => Js::from(u),
            (None, Some(i)) => Js::from(i),
            _ => return Err(at("an integer out of range")),
        },
        Mp::F32(f) => Number::from_f64(*f as f64)
            .map(Js::Number)
            .ok_or_else(|| at("a non-finite float"))?,
        Mp::F64(f) => Number::from_f64(*f)
            .map(Js::Number)
            .ok_or_else(|| at("a non-finite float"))?,
        Mp::String(s) => match s.as_str() {
            Some(s) => Js::from(s),
            None => return Err(at("a string that is not UTF-8")),
        },
        Mp::Binary(_) => return Err(at("bytes")),
        Mp::Ext(..) => return Err(at("a MessagePack extension")),
        Mp::Array(items) => Js::Array(
            items
                .iter()
                .enumerate()
                .map(|(i, item)| to_json(item, &format!("{path}[{i}]")))
                .collect::<Result<_, _>>()?,
        ),
        Mp::Map(members) => {
            let mut out = Map::new();
            for (k, v) in members {
                let Some(k) = k.as_str() else {
                    return Err(at("a map with a key that is not a string"));
                };
                out.insert(k.to_string(), to_json(v, &path_of(path, k))?);
            }
            Js::Object(out)
        }
    })
}

#[cfg(test)]
mod tests {
    use super::*;
    use serde_json::json;

    fn fields(text: &str) -> Vec<Field> {
        text.split_whitespace()
            .map(|f| Field::parse(f).unwrap())
            .collect()
    }

    #[test]
    fn fields_parse_and_say_what_is_wrong() {
        assert_eq!(
            Field::parse("orderId:string?"),
            Ok(Field {
                name: "orderId".into(),
                ty: JsonType::String,
                optional: true
            })
        );
        assert!(Field::parse("orderId")
            .unwrap_err()
            .contains("not `FIELD:TYPE`"));
        assert!(Field::parse("x:text")
            .unwrap_err()
            .contains("not a JSON type"));
    }

    #[test]
    fn payloads_are_checked_field_by_field() {
        let f = fields("orderId:string driving:bool battery:object? n:integer");
        let ok = json!({"orderId": "o1", "driving": true, "n": 3, "extra": [1]});
        assert_eq!(check_fields(ok.as_object().unwrap(), &f), Ok(()));
        let bad = json!({"orderId": "o1", "driving": "yes", "n": 3});
        assert_eq!(
            check_fields(bad.as_object().unwrap(), &f),
            Err("field `driving` is a string, the mapping says bool".into())
        );
        let bad = json!({"driving": true, "n": 3});
        assert_eq!(
            check_fields(bad.as_object().unwrap(), &f),
            Err("field `orderId` is missing".into())
        );
        let bad = json!({"orderId": "o", "driving": true, "n": 3.5});
        assert_eq!(
            check_fields(bad.as_object().unwrap(), &f),
            Err("field `n` is a number with a fraction, the mapping says integer".into())
        );
    }

    #[test]
    fn json_and_msgpack_convert_both_ways() {
        let v = json!({"a": 1, "b": -2, "c": 1.5, "d": [true, null, "x"], "e": {"f": 18446744073709551615u64}});
        assert_eq!(to_json(&to_msgpack(&v), "").unwrap(), v);
        let bytes = Mp::Map(vec![(Mp::from("blob"), Mp::Binary(vec![1]))]);
        assert_eq!(
            to_json(&bytes, ""),
            Err("field `blob` is bytes, which JSON cannot carry".into())
        );
        let nan = Mp::Map(vec![(Mp::from("x"), Mp::F64(f64::NAN))]);
        assert!(to_json(&nan, "")
            .unwrap_err()
            .contains("`x` is a non-finite float"));
    }

    fn order_shape() -> Shape {
        Shape::Struct {
            name: "Order".into(),
            fields: vec![
                ("orderId".into(), Shape::Str),
                ("orderUpdateId".into(), Shape::Int),
                ("zone".into(), Shape::Option(Box::new(Shape::Str))),
                ("nodes".into(), Shape::Seq(Box::new(Shape::Unknown))),
            ],
        }
    }

    #[test]
    fn values_are_checked_against_a_declared_type() {
        let s = order_shape();
        let ok = json!({"orderId": "o", "orderUpdateId": 0, "nodes": []});
        assert_eq!(fits_shape(&ok, &s, ""), Ok(()));
        let bad = json!({"orderId": "o", "orderUpdateId": "0", "nodes": []});
        assert_eq!(
            fits_shape(&bad, &s, ""),
            Err("field `orderUpdateId` is a string, the message type wants an integer".into())
        );
        let bad = json!({"orderId": "o", "nodes": []});
        assert_eq!(
            fits_shape(&bad, &s, ""),
            Err("field `orderUpdateId` is missing".into())
        );
    }

    #[test]
    fn declared_types_are_compared_with_the_mappings_fields() {
        let s = order_shape();
        let f = fields("orderId:string orderUpdateId:integer nodes:array");
        assert_eq!(check_declared(&s, &f, &[], true), Ok(()));
        assert_eq!(check_declared(&s, &f, &[], false), Ok(()));
        let f2 = fields("orderId:integer orderUpdateId:integer nodes:array");
        assert_eq!(
            check_declared(&s, &f2, &[], true),
            Err("field `orderId` is a string in Order, the mapping says integer".into())
        );
        let f3 = fields("orderId:string nodes:array");
        assert!(check_declared(&s, &f3, &[], false)
            .unwrap_err()
            .contains("field `orderUpdateId` of Order is not among the mapping's required fields"));
        let f4 = fields("orderId:string orderUpdateId:integer nodes:array edges:array");
        assert_eq!(
            check_declared(&s, &f4, &[], true),
            Err("the mapping requires field `edges`, which Order does not have".into())
        );
        // A capture stands for a required string field.
        let f5 = fields("orderUpdateId:integer nodes:array");
        assert_eq!(check_declared(&s, &f5, &["orderId".into()], false), Ok(()));
    }
}

//! A message type's [`Shape`], read off its `Deserialize` implementation with
//! `serde-reflection`, so that a transport converting payloads (a ROS bridge) can check its
//! mappings when it opens ([`OpenOptions::message`](crate::OpenOptions::message)).

use hetcomm_link::shape::Shape;
use serde::de::DeserializeOwned;
use serde_reflection::{ContainerFormat, Format, Registry, Tracer, TracerConfig};

/// How deep nested containers are followed (a recursive type stops here, unchecked).
const MAX_DEPTH: usize = 32;

/// `T`'s shape; [`Shape::Unknown`] where the tracer cannot tell (a custom `Deserialize` that
/// validates its input, for instance), which leaves that part to the per-message check.
pub(crate) fn trace<T: DeserializeOwned>() -> Shape {
    let mut tracer = Tracer::new(TracerConfig::default());
    let Ok((format, _)) = tracer.trace_simple_type::<T>() else {
        return Shape::Unknown;
    };
    // Enums whose variants were not all seen are still usable here: variants are not
    // compared, only the enum's name.
    let registry = tracer.registry_unchecked();
    from_format(&format, &registry, 0)
}

fn from_format(format: &Format, registry: &Registry, depth: usize) -> Shape {
    if depth > MAX_DEPTH {
        return Shape::Unknown;
    }
    let inner = |f: &Format| Box::new(from_format(f, registry, depth + 1));
    match format {
        Format::Variable(_) => Shape::Unknown,
        Format::TypeName(name) => match registry.get(name) {
            Some(container) => from_container(name, container, registry, depth + 1),
            None => Shape::Unknown,
        },
        Format::Unit => Shape::Unit,
        Format::Bool => Shape::Bool,
        Format::I8
        | Format::I16
        | Format::I32
        | Format::I64
        | Format::I128
        | Format::U8
        | Format::U16
        | Format::U32
        | Format::U64
        | Format::U128 => Shape::Int,
        Format::F32 | Format::F64 => Shape::Float,
        Format::Char | Format::Str => Shape::Str,
        Format::Bytes => Shape::Bytes,
        Format::Option(f) => Shape::Option(inner(f)),
        Format::Seq(f) => Shape::Seq(inner(f)),
        Format::Map { key, value } => Shape::Map(inner(key), inner(value)),
        Format::Tuple(items) => Shape::Tuple(
            items
                .iter()
                .map(|f| from_format(f, registry, depth + 1))
                .collect(),
        ),
        Format::TupleArray { content, size } => {
            Shape::Tuple(vec![from_format(content, registry, depth + 1); *size])
        }
    }
}

fn from_container(
    name: &str,
    container: &ContainerFormat,
    registry: &Registry,
    depth: usize,
) -> Shape {
    match container {
        ContainerFormat::UnitStruct => Shape::Unit,
        // A newtype is encoded as its content (rmp-serde, like serde_json).
        ContainerFormat::NewTypeStruct(f) => from_format(f, registry, depth),
        ContainerFormat::TupleStruct(items) => Shape::Tuple(
            items
                .iter()
                .map(|f| from_format(f, registry, depth))
                .collect(),
        ),
        ContainerFormat::Struct(fields) => Shape::Struct {
            name: name.to_string(),
            fields: fields
                .iter()
                .map(|f| (f.name.clone(), from_format(&f.value, registry, depth)))
                .collect(),
        },
        ContainerFormat::Enum(_) => Shape::Enum(name.to_string()),
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use serde::Deserialize;

    #[derive(Deserialize)]
    #[allow(dead_code)]
    struct Vector3 {
        x: f64,
        y: f64,
        z: f64,
    }

    #[derive(Deserialize)]
    #[allow(dead_code)]
    struct Drive {
        linear: Vector3,
        #[serde(rename = "angular")]
        turn: Vector3,
        label: Option<String>,
        covariance: [f64; 3],
        path: Vec<u32>,
    }

    #[derive(Deserialize)]
    #[allow(dead_code)]
    struct Command(Drive);

    fn vec3() -> Shape {
        Shape::Struct {
            name: "Vector3".into(),
            fields: ["x", "y", "z"]
                .iter()
                .map(|f| (f.to_string(), Shape::Float))
                .collect(),
        }
    }

    #[test]
    fn a_struct_is_traced_by_serde_names_and_a_newtype_is_its_content() {
        let expected = Shape::Struct {
            name: "Drive".into(),
            fields: vec![
                ("linear".into(), vec3()),
                ("angular".into(), vec3()),
                ("label".into(), Shape::Option(Box::new(Shape::Str))),
                ("covariance".into(), Shape::Tuple(vec![Shape::Float; 3])),
                ("path".into(), Shape::Seq(Box::new(Shape::Int))),
            ],
        };
        assert_eq!(trace::<Drive>(), expected);
        assert_eq!(trace::<Command>(), expected);
    }

    #[test]
    fn a_type_the_tracer_cannot_follow_is_unknown() {
        // Refuses every input, as a validating Deserialize may refuse the tracer's samples.
        struct Picky;
        impl<'de> Deserialize<'de> for Picky {
            fn deserialize<D: serde::Deserializer<'de>>(_: D) -> Result<Self, D::Error> {
                Err(serde::de::Error::custom("no"))
            }
        }
        assert_eq!(trace::<Picky>(), Shape::Unknown);
    }
}

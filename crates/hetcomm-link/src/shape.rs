//! The shapes of a program's message types, as the serde data model sees them: what a
//! transport that converts payloads (a ROS bridge maps a message to a ROS type by field name)
//! needs to check a mapping when it opens, before any message is sent.
//!
//! The shapes come from the program (`hetcomm::OpenOptions::message`, which traces a type's
//! `Deserialize` implementation); a transport that converts payloads reads them from
//! [`OpenRequest::shapes`](crate::registry::OpenRequest::shapes). A type the program did not
//! declare has no shape, and its mapping is checked per message instead.

use std::collections::BTreeMap;

/// One value's shape in the serde data model (as MessagePack payloads carry it).
#[derive(Clone, Debug, PartialEq)]
pub enum Shape {
    /// `bool`.
    Bool,
    /// Any integer (`i8` … `u128`): whether a value fits is checked per message.
    Int,
    /// `f32` or `f64`.
    Float,
    /// `String`, `&str` or `char`.
    Str,
    /// Bytes (`serde_bytes`).
    Bytes,
    /// `()` or a unit struct.
    Unit,
    /// `Option<T>`: nil or the value.
    Option(Box<Shape>),
    /// A sequence of any length (`Vec<T>`, slices).
    Seq(Box<Shape>),
    /// A sequence of exactly this many elements (`[T; N]`, tuples, tuple structs).
    Tuple(Vec<Shape>),
    /// A map with keys of one shape and values of another.
    Map(Box<Shape>, Box<Shape>),
    /// A struct: its name and its fields, by their serde names, in order.
    Struct {
        /// The type's name (`Drive`).
        name: String,
        /// Fields, by serde name (after `rename`).
        fields: Vec<(String, Shape)>,
    },
    /// An enum, by name: its variants are not compared.
    Enum(String),
    /// Anything the tracer could not tell (a custom `Deserialize`): not checked.
    Unknown,
}

impl Shape {
    /// A short description for messages: "a string", "a struct Drive", "a sequence", …
    pub fn describe(&self) -> String {
        match self {
            Shape::Bool => "a bool".into(),
            Shape::Int => "an integer".into(),
            Shape::Float => "a float".into(),
            Shape::Str => "a string".into(),
            Shape::Bytes => "bytes".into(),
            Shape::Unit => "a unit".into(),
            Shape::Option(inner) => format!("an Option of {}", inner.describe()),
            Shape::Seq(_) => "a sequence".into(),
            Shape::Tuple(items) => format!("a tuple of {}", items.len()),
            Shape::Map(..) => "a map".into(),
            Shape::Struct { name, .. } => format!("a struct {name}"),
            Shape::Enum(name) => format!("an enum {name}"),
            Shape::Unknown => "of an unknown shape".into(),
        }
    }
}

/// A message type's name and shape.
#[derive(Clone, Debug, PartialEq)]
pub struct MessageShape {
    /// The type's name (`Message::NAME`).
    pub name: String,
    /// Its shape.
    pub shape: Shape,
}

/// The shapes of the message types a program declared, by message type id.
#[derive(Clone, Debug, Default, PartialEq)]
pub struct MessageShapes {
    by_id: BTreeMap<u32, MessageShape>,
}

impl MessageShapes {
    /// None declared.
    pub fn new() -> Self {
        Self::default()
    }

    /// Declares type `id`'s name and shape (replacing an earlier declaration of `id`).
    pub fn insert(&mut self, id: u32, name: impl Into<String>, shape: Shape) {
        self.by_id.insert(
            id,
            MessageShape {
                name: name.into(),
                shape,
            },
        );
    }

    /// Type `id`'s name and shape, if the program declared it.
    pub fn get(&self, id: u32) -> Option<&MessageShape> {
        self.by_id.get(&id)
    }

    /// Whether nothing is declared.
    pub fn is_empty(&self) -> bool {
        self.by_id.is_empty()
    }
}

/// No shapes: for [`OpenRequest`](crate::registry::OpenRequest)s made outside a program's
/// open (tests, tools).
pub static NO_SHAPES: MessageShapes = MessageShapes {
    by_id: BTreeMap::new(),
};

//! User message types and the registry that maps their numeric ids to names.

use rustc_hash::FxHashMap as HashMap;

use serde::{de::DeserializeOwned, Serialize};

use crate::ids::MessageType;

/// A user-defined message. Implement it with `#[derive(Message)]` from the `hetcomm` crate:
///
/// ```ignore
/// #[derive(Serialize, Deserialize, Message)]
/// #[message(id = 1)]
/// struct Wheels { left: f64, right: f64 }
/// ```
///
/// The payload is encoded with [`crate::payload`]; no hand-written serialization.
pub trait Message: Serialize + DeserializeOwned + Send + 'static {
    /// The stable numeric id of this type, the same in every program of the fleet.
    const TYPE: MessageType;
    /// A human-readable name, used in errors and by tools.
    const NAME: &'static str;
}

/// What the registry knows about one message type.
#[derive(Clone, Debug, PartialEq, Eq)]
pub struct TypeInfo {
    /// The numeric id.
    pub id: MessageType,
    /// The type's name.
    pub name: String,
}

/// Registering a type failed.
#[derive(Clone, Debug, PartialEq, Eq, thiserror::Error)]
#[non_exhaustive]
pub enum TypeRegistryError {
    /// Two different types claim the same id.
    #[error("message type id {id} is claimed by both `{existing}` and `{new}`: give one of them another id")]
    DuplicateId {
        /// The contested id.
        id: MessageType,
        /// The type registered first.
        existing: String,
        /// The type being registered.
        new: String,
    },
}

/// Maps message type ids to names; refuses two types with one id.
#[derive(Debug)]
pub struct TypeRegistry {
    /// Unique in the process, so callers may cache what they verified against this registry.
    id: u64,
    by_id: HashMap<MessageType, TypeInfo>,
}

static NEXT_REGISTRY_ID: std::sync::atomic::AtomicU64 = std::sync::atomic::AtomicU64::new(1);

impl Default for TypeRegistry {
    fn default() -> Self {
        TypeRegistry {
            id: NEXT_REGISTRY_ID.fetch_add(1, std::sync::atomic::Ordering::Relaxed),
            by_id: HashMap::default(),
        }
    }
}

/// A clone is a new registry (with its own [`TypeRegistry::id`]) holding the same types.
impl Clone for TypeRegistry {
    fn clone(&self) -> Self {
        TypeRegistry {
            by_id: self.by_id.clone(),
            ..Self::default()
        }
    }
}

impl TypeRegistry {
    /// An empty registry.
    pub fn new() -> Self {
        Self::default()
    }

    /// This registry's process-unique id. Types are never removed from a registry, so a
    /// check made against it (type `T` is registered under name `N`) stays true for the
    /// id's lifetime: callers key caches of such checks by this id.
    pub fn id(&self) -> u64 {
        self.id
    }

    /// Registers `M`. Registering the same type twice is fine; another type with the same id
    /// is an error naming both.
    pub fn register<M: Message>(&mut self) -> Result<(), TypeRegistryError> {
        self.register_raw(M::TYPE, M::NAME)
    }

    /// Registers a type by id and name (used by bindings for other languages).
    pub fn register_raw(&mut self, id: MessageType, name: &str) -> Result<(), TypeRegistryError> {
        match self.by_id.get(&id) {
            Some(existing) if existing.name == name => Ok(()),
            Some(existing) => Err(TypeRegistryError::DuplicateId {
                id,
                existing: existing.name.clone(),
                new: name.to_string(),
            }),
            None => {
                self.by_id.insert(
                    id,
                    TypeInfo {
                        id,
                        name: name.to_string(),
                    },
                );
                Ok(())
            }
        }
    }

    /// Looks a type up by id.
    pub fn get(&self, id: MessageType) -> Option<&TypeInfo> {
        self.by_id.get(&id)
    }

    /// Looks a type up by name.
    pub fn by_name(&self, name: &str) -> Option<&TypeInfo> {
        self.by_id.values().find(|t| t.name == name)
    }

    /// All registered types, by id.
    pub fn iter(&self) -> impl Iterator<Item = &TypeInfo> {
        let mut v: Vec<_> = self.by_id.values().collect();
        v.sort_by_key(|t| t.id);
        v.into_iter()
    }
}

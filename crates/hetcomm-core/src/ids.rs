//! Newtype identifiers. Numeric ids are what travels on the wire; friendly names live in the
//! fleet configuration.

use std::fmt;

use serde::{Deserialize, Serialize};

/// A system (robot or virtual environment), as numbered in the fleet file.
#[derive(Clone, Copy, Debug, PartialEq, Eq, Hash, PartialOrd, Ord, Serialize, Deserialize)]
pub struct SystemId(pub u16);

/// A module (Sense, Plan, Act, …). Module ids are the same on every system.
#[derive(Clone, Copy, Debug, PartialEq, Eq, Hash, PartialOrd, Ord, Serialize, Deserialize)]
pub struct ModuleId(pub u16);

/// The stable numeric id of a user message type.
#[derive(Clone, Copy, Debug, PartialEq, Eq, Hash, PartialOrd, Ord, Serialize, Deserialize)]
pub struct MessageType(pub u32);

/// Message priority: a receiver sees higher priorities before lower ones already queued.
#[derive(Clone, Copy, Debug, PartialEq, Eq, Hash, PartialOrd, Ord, Serialize, Deserialize)]
pub struct Priority(pub u8);

impl Priority {
    /// The lowest priority.
    pub const LOWEST: Priority = Priority(0);
    /// The priority a message gets unless the sender says otherwise.
    pub const NORMAL: Priority = Priority(100);
    /// The highest priority.
    pub const HIGHEST: Priority = Priority(255);
}

impl Default for Priority {
    fn default() -> Self {
        Priority::NORMAL
    }
}

/// A module on a system: where a message comes from or goes to.
#[derive(Clone, Copy, Debug, PartialEq, Eq, Hash, PartialOrd, Ord, Serialize, Deserialize)]
pub struct Address {
    /// The system.
    pub system: SystemId,
    /// The module on that system.
    pub module: ModuleId,
}

impl From<(SystemId, ModuleId)> for Address {
    fn from((system, module): (SystemId, ModuleId)) -> Self {
        Address { system, module }
    }
}

/// The thesis's message id: the originating system and a sequence number unique within it
/// (for one incarnation of that system's process).
#[derive(Clone, Copy, Debug, PartialEq, Eq, Hash, PartialOrd, Ord, Serialize, Deserialize)]
pub struct MessageId {
    /// The system that created the message.
    pub origin: SystemId,
    /// Sequence number, starting at 1 for each incarnation.
    pub seq: u64,
}

macro_rules! display_as_number {
    ($($t:ty),*) => {$(
        impl fmt::Display for $t {
            fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
                fmt::Display::fmt(&self.0, f)
            }
        }
    )*};
}
display_as_number!(SystemId, ModuleId, MessageType, Priority);

impl fmt::Display for Address {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        write!(f, "({}, {})", self.system, self.module)
    }
}

impl fmt::Display for MessageId {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        write!(f, "({}, {})", self.origin, self.seq)
    }
}

//! # hetcomm-config — the framework manager's files
//!
//! Loads a TOML fleet file (and the thesis's legacy id / communication-table / Bluetooth
//! address files) into one validated [`Fleet`]. Every error carries file:line:column, the
//! offending value and a fix. Opens nothing: whether a transport kind is compiled in is decided
//! when the fleet is opened by the `hetcomm` facade.

pub mod model;

pub use model::*;

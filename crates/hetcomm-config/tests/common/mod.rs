//! The loaders as a hetcomm program calls them: knowing the kinds whose settings live in their
//! link crates (`udp` and `tcp` in `hetcomm-link-ip`, `ros1` in `hetcomm-link-ros1`, `bluetooth` in
//! `hetcomm-link-bluetooth`), so these
//! tests check a fleet file end to end, as `hetcomm validate` reads it.

#![allow(dead_code)] // each test file uses some of them

use std::path::Path;
use std::sync::OnceLock;

use hetcomm_config::{ConfigErrors, Fleet, Kinds};
use hetcomm_link::registry::Registry;

/// The kinds of the link crates these tests know.
pub fn kinds() -> &'static Kinds {
    static REGISTRY: OnceLock<Registry> = OnceLock::new();
    REGISTRY
        .get_or_init(|| {
            let mut registry = Registry::new();
            hetcomm_link::register_transports(&mut registry);
            hetcomm_link_ip::register_transports(&mut registry);
            // The transport alone: its bridge kind would lengthen every list of kinds.
            registry.register(hetcomm_link_ros1::factory::Ros1Factory);
            hetcomm_link_bluetooth::register_transports(&mut registry);
            registry
        })
        .kinds()
}

/// `hetcomm_config::load` with [`kinds`].
pub fn load(path: &Path) -> Result<Fleet, ConfigErrors> {
    hetcomm_config::load_with(path, kinds())
}

/// `hetcomm_config::parse_str` with [`kinds`].
pub fn parse_str(text: &str, origin: &str, base_dir: Option<&Path>) -> Result<Fleet, ConfigErrors> {
    hetcomm_config::parse_str_with(text, origin, base_dir, kinds())
}

/// `hetcomm_config::load_legacy` with [`kinds`].
pub fn load_legacy(
    ids: &Path,
    table: &Path,
    bluetooth: Option<&Path>,
) -> Result<Fleet, ConfigErrors> {
    hetcomm_config::load_legacy_with(ids, table, bluetooth, kinds())
}

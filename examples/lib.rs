//! Examples of hetcomm; see the `[[example]]` targets in this folder's Cargo.toml and
//! `examples/README.md`. The leader–follower demonstration is a library module so that the
//! `hetcomm demo` command and the tests run the very same rover code.

#[path = "leader_follower/mod.rs"]
pub mod leader_follower;

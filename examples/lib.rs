//! Examples of hetcomm; see the `[[example]]` targets in this folder's Cargo.toml and
//! `examples/README.md`.

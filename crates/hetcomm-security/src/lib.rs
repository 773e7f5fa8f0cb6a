//! # hetcomm-security — authenticated, encrypted frames between the router and every link
//!
//! One [`SecurityLayer`] goes over each network link of a system (UDP, TCP, ROS 1, Bluetooth,
//! …: anything that leaves the process), between the router and the link, so every link kind
//! gets the same protection and the router stays sans-IO:
//!
//! - **Keys** ([`keys`]): one X25519 key pair per system; the fleet file names every
//!   system's public key, each process holds only its own private key.
//! - **Sessions** ([`session`]): a Noise KK handshake (`Noise_KK_25519_AESGCM_SHA256`, by the
//!   `snow` crate, with `ring`'s AES-GCM and SHA-256 and curve25519-dalek's X25519) per pair of systems and link, with fresh ephemeral keys on both sides, so
//!   frames of an old session (before either side restarted) never open in a new one.
//! - **Frames** ([`envelope`]): every frame is sealed with AES-256-GCM (`ring`) under the
//!   session's key for its direction: the whole inner frame (header and payload) is encrypted,
//!   and the clear prefix (sender, receiver, session, counter) is authenticated. Frames the
//!   router lets wait to leave together are sealed together, as one data batch.
//! - **Freshness** ([`replay`]): a per-session replay window (RFC 6479), moved only by
//!   frames that authenticated.
//! - **The table on receipt** ([`Policy`]): an authentic frame whose inner header claims
//!   another origin or destination, or that the communication table does not put on this
//!   transport (an `X` pair), is dropped before the router sees it.
//!
//! Every refused frame is counted by reason in [`hetcomm_link::SecurityStats`] (the link's
//! stats). `docs/security.md` has the threat model; `docs/wire-format.md` the bytes.

pub mod conformance;
pub mod envelope;
pub mod keys;
mod layer;
pub mod replay;
pub mod session;

pub use keys::{KeyError, Keypair, PrivateKey, PublicKey};
pub use layer::{Handshakes, Policy, SecurityLayer, SimSessions};

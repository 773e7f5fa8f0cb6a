//! The `secured_frames` section of `docs/wire-vectors.json` (docs/wire-format.md, "Secured
//! frames"): fixed key pairs, one Noise KK handshake made with seeded randomness, its split
//! keys, data frames sealed with them, and frames a receiver refuses, with the verdict.
//!
//! * `committed_secured_vectors_match_the_generator`: the committed section is exactly what
//!   [`section`] produces from the real code (`session::initiate` / `respond` / `complete`,
//!   `Session::seal`), so the file cannot drift from the code.
//! * `handshake_matches_snow_with_the_stated_ephemeral_keys`: the stated ephemeral private keys
//!   are what the seeded randomness gives, and a Noise KK handshake run with them (by `snow`,
//!   with fixed ephemeral keys) writes the vector's messages and splits into the vector's keys.
//! * `split_keys_seal_the_data_vectors`: AES-256-GCM under the stated key, nonce and associated
//!   data gives each data vector's bytes, and opens them.
//! * `a_security_layer_gives_each_verdict`: each frame of `received`, fed to a real
//!   [`SecurityLayer`] (holding the vector's session: it is the one a simulation with
//!   [`SIM_SEED`] makes) after the frames named in `before`, is handed up or refused with
//!   exactly the stated counter.
//!
//! The section is generated here (hetcomm-core, which writes the rest of the file, cannot use
//! this crate); its generator copies the section through. After an intended change run
//! `cargo test -p hetcomm-security --test wire_vectors -- --ignored regenerate_secured_vectors`.

use std::collections::{HashMap, HashSet};
use std::path::PathBuf;
use std::sync::Arc;

use hetcomm_core::SystemId;
use hetcomm_link::conformance::CollectSink;
use hetcomm_link::layer::{LayerContext, LinkLayer};
use hetcomm_link::{Link, LinkCaps, LinkError, LinkStats, Peer, SecurityStats};
use hetcomm_security::envelope::{DirectionKey, DATA_HEADER_LEN, TAG_LEN};
use hetcomm_security::session::{self, Entropy};
use hetcomm_security::{Handshakes, Keypair, Policy, PrivateKey, SecurityLayer, SimSessions};
use serde_json::Value;

#[path = "wire_vectors/generate.rs"]
mod generate;

use generate::*;

/// The section as it stands in the file: `MARKER`, the section indented by two spaces, and
/// the file's closing brace.
fn section_text() -> String {
    let pretty = serde_json::to_string_pretty(&section()).expect("serializes");
    let indented = pretty.replace('\n', "\n  ");
    format!("{MARKER}{indented}\n}}\n")
}

fn committed() -> String {
    let path = vectors_path();
    std::fs::read_to_string(&path).unwrap_or_else(|e| panic!("cannot read {}: {e}", path.display()))
}

fn load() -> Value {
    serde_json::from_str(&committed()).expect("wire-vectors.json is valid JSON")
}

#[test]
fn committed_secured_vectors_match_the_generator() {
    let text = committed();
    let at = text
        .find(MARKER)
        .expect("docs/wire-vectors.json has no secured_frames section");
    assert!(
        text[at..] == section_text(),
        "the secured_frames section of docs/wire-vectors.json differs from what the generator \
         produces: if the change is intended, run `cargo test -p hetcomm-security --test \
         wire_vectors -- --ignored regenerate_secured_vectors` and review the diff"
    );
}

/// Rewrites the `secured_frames` section of `docs/wire-vectors.json` (the rest stays).
#[test]
#[ignore = "writes docs/wire-vectors.json; run on purpose after an intended change"]
fn regenerate_secured_vectors() {
    let text = committed();
    let rest = match text.find(MARKER) {
        Some(at) => &text[..at],
        None => text
            .strip_suffix("\n}\n")
            .expect("the file ends with its closing brace"),
    };
    std::fs::write(vectors_path(), format!("{rest}{}", section_text())).expect("writes");
    println!("wrote {}", vectors_path().display());
}

// ---------------------------------------------------------------------------------------------
// The checks, reading the committed file
// ---------------------------------------------------------------------------------------------

fn secured() -> Value {
    load()["secured_frames"].clone()
}

fn s<'a>(v: &'a Value, key: &str) -> &'a str {
    v[key]
        .as_str()
        .unwrap_or_else(|| panic!("{key} is not a string in {v}"))
}

fn n(v: &Value, key: &str) -> u64 {
    v[key]
        .as_u64()
        .unwrap_or_else(|| panic!("{key} is not an integer in {v}"))
}

fn ids(v: &Value, key: &str) -> Vec<SystemId> {
    v[key]
        .as_array()
        .unwrap_or_else(|| panic!("{key} is not a list in {v}"))
        .iter()
        .map(|x| SystemId(x.as_u64().expect("an id") as u16))
        .collect()
}

#[test]
fn keys_derive_from_the_stated_private_keys() {
    for v in secured()["systems"].as_array().expect("systems") {
        let private: [u8; 32] = unhex(s(v, "private_key_hex")).try_into().expect("32");
        let k = Keypair::from_private(PrivateKey(private)).expect("key");
        assert_eq!(hex(&k.public.0), s(v, "public_key_hex"));
        assert_eq!(k.public.to_string(), s(v, "public_key_base64"));
    }
}

#[test]
fn handshake_matches_snow_with_the_stated_ephemeral_keys() {
    let sec = secured();
    let h = &sec["handshake"];
    let (m1, m2, hash, k1, k2) = snow_handshake();
    let init = unhex(s(h, "initiation_hex"));
    let resp = unhex(s(h, "response_hex"));
    // 12 clear bytes: "HS", 1, type 1, sender, receiver, the initiator's index.
    assert_eq!(&init[..12], &unhex("485301010100020001000000")[..]);
    assert_eq!(&init[12..], &m1[..]);
    assert_eq!(init.len(), 12 + 32 + 8 + 16);
    // 16 clear bytes: "HS", 1, type 2, sender, receiver, the responder's index, the
    // initiator's index.
    assert_eq!(&resp[..16], &unhex("48530102020001000200000001000000")[..]);
    assert_eq!(&resp[16..], &m2[..]);
    assert_eq!(resp.len(), 16 + 32 + 16);
    assert_eq!(s(h, "handshake_hash_hex"), hex(&hash));
    assert_eq!(s(h, "key_initiator_to_responder_hex"), hex(&k1));
    assert_eq!(s(h, "key_responder_to_initiator_hex"), hex(&k2));
    assert_eq!(s(h, "prologue_hex"), hex(&prologue()));
    assert_eq!(
        s(h, "initiator_ephemeral_private_hex"),
        hex(&ephemeral(n(h, "initiator_seed")))
    );
    assert_eq!(
        s(h, "responder_ephemeral_private_hex"),
        hex(&ephemeral(n(h, "responder_seed")))
    );
    // And the real code, given the vector's initiation, answers with the vector's response.
    let (a, b) = (keypair(INITIATOR), keypair(RESPONDER));
    let answer = session::respond(
        (RESPONDER, &b),
        (INITIATOR, &a.public),
        &init,
        2,
        Entropy::Seeded(n(h, "responder_seed")),
    )
    .expect("responds");
    assert_eq!(answer.response, resp);
    assert_eq!(answer.timestamp, n(h, "timestamp"));
}

#[test]
fn split_keys_seal_the_data_vectors() {
    let sec = secured();
    let h = &sec["handshake"];
    let key_of = |name: &str| -> DirectionKey {
        let k: [u8; 32] = unhex(s(h, &format!("key_{name}_hex")))
            .try_into()
            .expect("32");
        DirectionKey::new(&k)
    };
    for v in sec["sealed"].as_array().expect("sealed") {
        let key = key_of(s(v, "key"));
        let counter = n(v, "counter");
        assert_eq!(s(v, "nonce_hex"), hex(&nonce(counter)), "{}", s(v, "name"));
        let inner = unhex(s(v, "inner_hex"));
        let mut out = Vec::new();
        let ids = (
            SystemId(n(v, "sender") as u16),
            SystemId(n(v, "receiver") as u16),
        );
        let index = n(v, "session_index") as u32;
        match n(v, "type") {
            3 => key.seal(&mut out, ids, index, counter, &inner, &[]),
            4 => key.seal_batch(&mut out, ids, index, counter, &inner),
            other => panic!("{}: type {other}", s(v, "name")),
        }
        assert_eq!(hex(&out), s(v, "secured_hex"), "{}", s(v, "name"));
        assert!(key.open(&mut out), "{}", s(v, "name"));
        assert_eq!(&out[DATA_HEADER_LEN..out.len() - TAG_LEN], &inner[..]);
    }
}

/// The link under the layer: takes what the layer sends.
struct NullLink;

impl Link for NullLink {
    fn caps(&self) -> LinkCaps {
        LinkCaps {
            max_frame: 1 << 20,
            mtu: 1 << 20,
            reliable: true,
            ordered: true,
            broadcast: false,
        }
    }
    fn send(&self, _to: SystemId, _frame: &[u8]) -> Result<(), LinkError> {
        Ok(())
    }
    fn stats(&self) -> LinkStats {
        LinkStats::default()
    }
}

/// A security layer for `receiver` as the vectors describe it, over a link that goes nowhere,
/// holding the simulation's sessions: its sink (what it hands up), its link (for the stats)
/// and the sink it reads frames from.
fn receiver_layer(
    receiver: &Value,
) -> (
    Arc<CollectSink>,
    Arc<dyn Link>,
    Arc<dyn hetcomm_link::FrameSink>,
) {
    let local = SystemId(n(receiver, "system") as u16);
    let keys: HashMap<SystemId, Keypair> = [INITIATOR, RESPONDER]
        .into_iter()
        .map(|id| (id, keypair(id)))
        .collect();
    let policy = Policy {
        local,
        keypair: keys[&local].clone(),
        peers: ids(receiver, "peers")
            .into_iter()
            .map(|p| (p, keys[&p].public))
            .collect(),
        data_from: ids(receiver, "data_from")
            .into_iter()
            .collect::<HashSet<_>>(),
        acks_from: ids(receiver, "acks_from")
            .into_iter()
            .collect::<HashSet<_>>(),
    };
    let layer = SecurityLayer::new(
        "udp",
        policy,
        Handshakes::InMemory(SimSessions::new(SIM_SEED, keys)),
    );
    let ctx = LayerContext::new(local).in_virtual_time();
    let up = CollectSink::new();
    let mut sink = None;
    let link = layer
        .wrap(&ctx, up.clone(), &mut |below| {
            sink = Some(below);
            Ok(Arc::new(NullLink))
        })
        .expect("wraps");
    (up, link, sink.expect("opened"))
}

#[test]
fn a_security_layer_gives_each_verdict() {
    let sec = secured();
    let sealed: HashMap<&str, Vec<u8>> = sec["sealed"]
        .as_array()
        .expect("sealed")
        .iter()
        .map(|v| (s(v, "name"), unhex(s(v, "secured_hex"))))
        .collect();
    let receivers = sec["receivers"].as_array().expect("receivers");
    let mut verdicts = HashSet::new();
    for v in sec["received"].as_array().expect("received") {
        let name = s(v, "name");
        let receiver = receivers
            .iter()
            .find(|r| n(r, "system") == n(v, "receiver"))
            .expect("a receiver");
        let (up, link, sink) = receiver_layer(receiver);
        let from = Peer::Unknown;
        for before in v["before"].as_array().expect("before") {
            sink.on_frame(&sealed[before.as_str().expect("a name")], from);
            assert_eq!(link.stats().security.rejected(), 0, "{name}: {before}");
        }
        let (handed, stats) = (up.frames().len(), link.stats().security);
        sink.on_frame(&unhex(s(v, "secured_hex")), from);
        let after = link.stats().security;
        let frames = up.frames();
        let verdict = s(v, "verdict");
        verdicts.insert(verdict.to_string());
        let new: Vec<&[u8]> = frames[handed..].iter().map(|f| &f.bytes[..]).collect();
        match verdict {
            "handed_up" => {
                // A data batch hands up several frames: `inner_hex` is all of them in order.
                assert!(!new.is_empty(), "{name}");
                assert_eq!(new.concat(), unhex(s(v, "inner_hex")), "{name}");
                let sender = if n(v, "receiver") == 1 {
                    RESPONDER
                } else {
                    INITIATOR
                };
                assert_eq!(frames[handed].from, Peer::System(sender), "{name}");
                assert_eq!(after.rejected(), stats.rejected(), "{name}");
            }
            "accepted_empty" => {
                assert!(new.is_empty(), "{name}");
                assert_eq!(after.rejected(), stats.rejected(), "{name}");
            }
            counter => {
                assert!(new.is_empty(), "{name}: handed up");
                let mut expect = stats;
                let field = match counter {
                    "rejected_auth" => &mut expect.rejected_auth,
                    "rejected_replay" => &mut expect.rejected_replay,
                    "rejected_table" => &mut expect.rejected_table,
                    "rejected_unknown_sender" => &mut expect.rejected_unknown_sender,
                    "rejected_no_session" => &mut expect.rejected_no_session,
                    other => panic!("{name}: unknown verdict {other}"),
                };
                *field += 1;
                assert_eq!(
                    SecurityStats {
                        handshakes: after.handshakes,
                        ..expect
                    },
                    after,
                    "{name}"
                );
            }
        }
    }
    // Every counter a frame can be refused under has a vector.
    for v in [
        "handed_up",
        "accepted_empty",
        "rejected_auth",
        "rejected_replay",
        "rejected_table",
        "rejected_unknown_sender",
        "rejected_no_session",
    ] {
        assert!(verdicts.contains(v), "no vector with verdict {v}");
    }
}

#[test]
fn the_simulation_makes_the_vector_sessions() {
    let made = handshake();
    let (a, b) = (keypair(INITIATOR), keypair(RESPONDER));
    let (si, _) = pair_seeds();
    let (sa, sb) =
        session::in_memory((INITIATOR, &a), (RESPONDER, &b), si).expect("in-memory sessions");
    let (mut x, mut y) = (Vec::new(), Vec::new());
    made.initiator
        .seal(&mut x, INITIATOR, RESPONDER, b"same", &[]);
    sa.seal(&mut y, INITIATOR, RESPONDER, b"same", &[]);
    assert_eq!(x, y);
    made.responder
        .seal(&mut x, RESPONDER, INITIATOR, b"back", &[]);
    sb.seal(&mut y, RESPONDER, INITIATOR, b"back", &[]);
    assert_eq!(x, y);
}

/// The byte-by-byte example in docs/wire-format.md ("Secured and unsecured on the links") is
/// the vector it names.
#[test]
fn the_documents_example_is_the_vector() {
    let doc = std::fs::read_to_string(
        PathBuf::from(env!("CARGO_MANIFEST_DIR")).join("../../docs/wire-format.md"),
    )
    .expect("reads docs/wire-format.md");
    let from = doc
        .find("For example (vector `secured_frames/sealed/header_only`)")
        .expect("the example");
    let block = &doc[from..];
    let block = &block[block.find("```text\n").expect("a text block") + 8..];
    let block = &block[..block.find("```").expect("the block's end")];
    let hex_of_block: String = block
        .lines()
        .map(|line| {
            // The hex columns, up to the comment after two spaces.
            let bytes = line.split("  ").next().unwrap_or("");
            bytes.replace(' ', "")
        })
        .collect();
    let sec = secured();
    let vector = sec["sealed"]
        .as_array()
        .expect("sealed")
        .iter()
        .find(|v| s(v, "name") == "header_only")
        .expect("header_only");
    assert_eq!(hex_of_block, s(vector, "secured_hex"));
}

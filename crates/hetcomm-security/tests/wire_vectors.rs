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

use hetcomm_core::wire;
use hetcomm_core::{
    payload, AckStatus, Address, FrameKind, Header, MessageType, ModuleId, Priority, SystemId, Time,
};
use hetcomm_link::conformance::CollectSink;
use hetcomm_link::layer::{LayerContext, LinkLayer};
use hetcomm_link::{Link, LinkCaps, LinkError, LinkStats, Peer, SecurityStats};
use hetcomm_security::envelope::{DirectionKey, DATA_HEADER_LEN, NOISE_PARAMS, TAG_LEN};
use hetcomm_security::session::{self, Entropy, Session};
use hetcomm_security::{Handshakes, Keypair, Policy, PrivateKey, SecurityLayer, SimSessions};
use rand::{RngCore, SeedableRng};
use serde::Serialize;
use serde_json::Value;

/// The seed of the simulation whose session between systems 1 and 2 the vectors use.
const SIM_SEED: u64 = 2026;
const INITIATOR: SystemId = SystemId(1);
const RESPONDER: SystemId = SystemId(2);
/// What introduces the section in the file (it is the file's last key).
const MARKER: &str = ",\n  \"secured_frames\": ";

fn vectors_path() -> PathBuf {
    PathBuf::from(env!("CARGO_MANIFEST_DIR")).join("../../docs/wire-vectors.json")
}

fn hex(bytes: &[u8]) -> String {
    bytes.iter().map(|b| format!("{b:02x}")).collect()
}

fn unhex(s: &str) -> Vec<u8> {
    assert!(s.len().is_multiple_of(2), "odd hex length");
    (0..s.len())
        .step_by(2)
        .map(|i| u8::from_str_radix(&s[i..i + 2], 16).expect("hex"))
        .collect()
}

/// The fixed key pair of system `id`: private key bytes `32 * (id - 1)`, `+ 1`, …, `+ 31`.
fn keypair(id: SystemId) -> Keypair {
    let first = 32 * (id.0 as u8 - 1);
    Keypair::from_private(PrivateKey(std::array::from_fn(|i| first + i as u8)))
        .expect("X25519 takes any 32 bytes")
}

/// The randomness `SimSessions` gives the handshake between systems 1 and 2 (initiator, lower
/// id first): `Entropy::Seeded` of these.
fn pair_seeds() -> (u64, u64) {
    let pair = SIM_SEED ^ ((INITIATOR.0 as u64) << 16) ^ ((RESPONDER.0 as u64) << 32);
    (pair, pair ^ 0x5eed)
}

/// The first 32 bytes of a seeded generator: the ephemeral private key it gives.
fn ephemeral(seed: u64) -> [u8; 32] {
    let mut e = [0; 32];
    rand_chacha::ChaCha20Rng::seed_from_u64(seed).fill_bytes(&mut e);
    e
}

fn prologue() -> Vec<u8> {
    let mut p = b"hetcomm-secure-v1".to_vec();
    p.extend_from_slice(&INITIATOR.0.to_le_bytes());
    p.extend_from_slice(&RESPONDER.0.to_le_bytes());
    p
}

fn addr(system: u16, module: u16) -> Address {
    Address {
        system: SystemId(system),
        module: ModuleId(module),
    }
}

/// A data frame from module 2 of `source` to module 4 of `destination`.
fn data_header(source: u16, destination: u16, seq: u64) -> Header {
    Header {
        kind: FrameKind::Data,
        flags: wire::FLAG_ACK_REQUESTED,
        priority: Priority::NORMAL,
        transport: b'U',
        source: addr(source, 2),
        destination: addr(destination, 4),
        incarnation: 0x0bad_cafe,
        seq,
        message_type: MessageType(7),
        timestamp: Time(1_750_000_000_000_000),
    }
}

fn ack_of(data: &Header) -> Header {
    Header {
        kind: FrameKind::Ack,
        flags: 0,
        source: data.destination,
        destination: data.source,
        ..*data
    }
}

fn systems_json(ids: &[SystemId]) -> Vec<SystemKeys> {
    ids.iter()
        .map(|&id| {
            let k = keypair(id);
            SystemKeys {
                system: id.0,
                private_key_hex: hex(&k.private.0),
                public_key_hex: hex(&k.public.0),
                public_key_base64: k.public.to_string(),
            }
        })
        .collect()
}

#[derive(Serialize)]
struct SystemKeys {
    system: u16,
    private_key_hex: String,
    public_key_hex: String,
    public_key_base64: String,
}

#[derive(Serialize)]
struct Handshake {
    initiator: u16,
    responder: u16,
    prologue_hex: String,
    initiator_index: u32,
    responder_index: u32,
    timestamp: u64,
    initiator_seed: u64,
    responder_seed: u64,
    initiator_ephemeral_private_hex: String,
    responder_ephemeral_private_hex: String,
    initiation_hex: String,
    response_hex: String,
    handshake_hash_hex: String,
    key_initiator_to_responder_hex: String,
    key_responder_to_initiator_hex: String,
}

#[derive(Serialize)]
struct Receiver {
    system: u16,
    peers: Vec<u16>,
    data_from: Vec<u16>,
    acks_from: Vec<u16>,
}

/// A frame sealed by the sender of one direction.
#[derive(Serialize)]
struct Sealed {
    name: String,
    description: String,
    sender: u16,
    receiver: u16,
    /// "initiator_to_responder" or "responder_to_initiator".
    key: &'static str,
    session_index: u32,
    counter: u64,
    nonce_hex: String,
    inner_hex: String,
    secured_hex: String,
}

/// A frame arriving at a receiver, and what the receiver does with it.
#[derive(Serialize)]
struct Received {
    name: String,
    description: String,
    receiver: u16,
    /// Names of `sealed` frames the receiver got first (each accepted).
    before: Vec<String>,
    secured_hex: String,
    /// "handed_up", "accepted_empty", or the `SecurityStats` counter it is refused under.
    verdict: &'static str,
    /// What the receiver hands up ("" unless `verdict` is "handed_up").
    inner_hex: String,
}

#[derive(Serialize)]
struct Section {
    description: &'static str,
    noise_protocol: &'static str,
    systems: Vec<SystemKeys>,
    handshake: Handshake,
    receivers: Vec<Receiver>,
    sealed: Vec<Sealed>,
    received: Vec<Received>,
}

/// Both sides' sessions from the vector handshake, made by the real code.
struct Made {
    initiation: Vec<u8>,
    response: Vec<u8>,
    initiator: Session,
    responder: Session,
}

fn handshake() -> Made {
    let (a, b) = (keypair(INITIATOR), keypair(RESPONDER));
    let (si, sr) = pair_seeds();
    let (initiation, pending) = session::initiate(
        (INITIATOR, &a),
        (RESPONDER, &b.public),
        1,
        1,
        Entropy::Seeded(si),
    )
    .expect("initiation");
    let answer = session::respond(
        (RESPONDER, &b),
        (INITIATOR, &a.public),
        &initiation,
        2,
        Entropy::Seeded(sr),
    )
    .expect("response");
    assert_eq!(answer.timestamp, 1);
    let initiator = pending.complete(&answer.response).expect("completes");
    Made {
        initiation,
        response: answer.response,
        initiator,
        responder: answer.session,
    }
}

/// The handshake as `snow` runs it with the stated ephemeral keys: (initiation's Noise
/// message, response's Noise message, handshake hash, key initiator→responder, key
/// responder→initiator).
fn snow_handshake() -> (Vec<u8>, Vec<u8>, Vec<u8>, [u8; 32], [u8; 32]) {
    let (a, b) = (keypair(INITIATOR), keypair(RESPONDER));
    let (si, sr) = pair_seeds();
    let (ei, er) = (ephemeral(si), ephemeral(sr));
    let prologue = prologue();
    let params: snow::params::NoiseParams = NOISE_PARAMS.parse().expect("params");
    let mut init = snow::Builder::new(params.clone())
        .local_private_key(&a.private.0)
        .and_then(|s| s.remote_public_key(&b.public.0))
        .and_then(|s| s.prologue(&prologue))
        .expect("builder")
        .fixed_ephemeral_key_for_testing_only(&ei)
        .build_initiator()
        .expect("initiator");
    let mut resp = snow::Builder::new(params)
        .local_private_key(&b.private.0)
        .and_then(|s| s.remote_public_key(&a.public.0))
        .and_then(|s| s.prologue(&prologue))
        .expect("builder")
        .fixed_ephemeral_key_for_testing_only(&er)
        .build_responder()
        .expect("responder");
    let mut m1 = vec![0; 256];
    let n = init
        .write_message(&1u64.to_le_bytes(), &mut m1)
        .expect("m1");
    m1.truncate(n);
    let mut buf = [0; 64];
    assert_eq!(resp.read_message(&m1, &mut buf).expect("read m1"), 8);
    let mut m2 = vec![0; 256];
    let n = resp.write_message(&[], &mut m2).expect("m2");
    m2.truncate(n);
    init.read_message(&m2, &mut buf).expect("read m2");
    let hash = init.get_handshake_hash().to_vec();
    assert_eq!(hash, resp.get_handshake_hash());
    let (k1, k2) = init.dangerously_get_raw_split();
    assert_eq!((k1, k2), resp.dangerously_get_raw_split());
    (m1, m2, hash, k1, k2)
}

fn nonce(counter: u64) -> [u8; 12] {
    let mut n = [0; 12];
    n[4..].copy_from_slice(&counter.to_le_bytes());
    n
}

/// Builds the section from the real code.
fn section() -> Section {
    let made = handshake();
    let (_, _, hash, k1, k2) = snow_handshake();
    let (si, sr) = pair_seeds();
    let (i, r) = (INITIATOR.0, RESPONDER.0);

    let mut sealed = Vec::new();
    let mut seal = |name: &str, description: &str, forward: bool, inner: &[u8]| -> Vec<u8> {
        let (session, from, to, key) = if forward {
            (
                &made.initiator,
                INITIATOR,
                RESPONDER,
                "initiator_to_responder",
            )
        } else {
            (
                &made.responder,
                RESPONDER,
                INITIATOR,
                "responder_to_initiator",
            )
        };
        let mut out = Vec::new();
        session.seal(&mut out, from, to, inner, &[]);
        let counter = u64::from_le_bytes(out[12..20].try_into().expect("8 bytes"));
        sealed.push(Sealed {
            name: name.into(),
            description: description.into(),
            sender: from.0,
            receiver: to.0,
            key,
            session_index: session.peer_index,
            counter,
            nonce_hex: hex(&nonce(counter)),
            inner_hex: hex(inner),
            secured_hex: hex(&out),
        });
        out
    };

    let header_only_h = data_header(i, r, 1);
    let header_only = wire::encode(&header_only_h, &[]);
    let with_payload_h = data_header(i, r, 2);
    let with_payload = wire::encode(
        &with_payload_h,
        &payload::encode(&("STOP", 255u8, [1.5f64, -2.0])).expect("encodes"),
    );
    let large = wire::encode(&data_header(i, r, 3), &vec![0xa5; 1000]);
    let ack = wire::encode(&ack_of(&with_payload_h), &[AckStatus::Delivered as u8]);

    let s_empty = seal(
        "empty",
        "An empty inner frame (counter 0). It authenticates and takes its counter, but there \
         is nothing to hand up. (The reference never sends one.)",
        true,
        &[],
    );
    let s_header = seal(
        "header_only",
        "A data frame of 48 bytes (header, empty payload) from (1, 2) to (2, 4); counter 1.",
        true,
        &header_only,
    );
    let s_payload = seal(
        "header_and_payload",
        "A data frame with a MessagePack payload (48 + 20 bytes); counter 2.",
        true,
        &with_payload,
    );
    let s_large = seal(
        "large",
        "A data frame with 1000 payload bytes; counter 3.",
        true,
        &large,
    );
    let s_ack = seal(
        "ack_back",
        "The acknowledgement of header_and_payload, from system 2 back to system 1: the other \
         direction, its own key and counter (0), system 1's session index.",
        false,
        &ack,
    );
    let s_spoofed_source = seal(
        "spoofed_inner_source",
        "Authentic (sealed by system 1) but the inner header claims source system 5; \
         counter 4.",
        true,
        &wire::encode(&data_header(5, r, 4), &[]),
    );
    let s_other_destination = seal(
        "other_inner_destination",
        "Authentic, but the inner header is for system 3; counter 5.",
        true,
        &wire::encode(&data_header(i, 3, 5), &[]),
    );
    let s_ack_not_allowed = seal(
        "ack_from_initiator",
        "Authentic, but an acknowledgement from system 1, which system 2 sends no messages to \
         on this transport; counter 6.",
        true,
        &wire::encode(
            &ack_of(&data_header(r, i, 9)),
            &[AckStatus::Delivered as u8],
        ),
    );
    let s_data_not_allowed = seal(
        "data_from_responder",
        "Authentic, but a data frame from system 2 to system 1, which the table does not \
         route on this transport; counter 1 of the other direction.",
        false,
        &wire::encode(&data_header(r, i, 1), &[]),
    );

    let changed = |frame: &[u8], at: usize, to: u8| {
        let mut f = frame.to_vec();
        f[at] = to;
        f
    };
    let flipped = |frame: &[u8], at: usize| {
        let mut f = frame.to_vec();
        f[at] ^= 0x01;
        f
    };
    let received = vec![
        rx("accept_empty", "", r, &[], &s_empty, "accepted_empty", &[]),
        rx(
            "accept_header_only",
            "",
            r,
            &["empty"],
            &s_header,
            "handed_up",
            &header_only,
        ),
        rx(
            "accept_header_and_payload",
            "",
            r,
            &["empty", "header_only"],
            &s_payload,
            "handed_up",
            &with_payload,
        ),
        rx("accept_large", "", r, &[], &s_large, "handed_up", &large),
        rx("accept_ack_back", "", i, &[], &s_ack, "handed_up", &ack),
        rx(
            "late_but_new",
            "Counter 1 after counter 3: older than the newest, but within the window and not \
             seen before.",
            r,
            &["large"],
            &s_header,
            "handed_up",
            &header_only,
        ),
        rx(
            "unsecured_frame",
            "A plain hetcomm frame (\"HC\"): not a secured frame.",
            r,
            &[],
            &header_only,
            "rejected_auth",
            &[],
        ),
        rx(
            "bad_version",
            "header_only with version 2.",
            r,
            &[],
            &changed(&s_header, 2, 2),
            "rejected_auth",
            &[],
        ),
        rx(
            "bad_type",
            "header_only with type 4.",
            r,
            &[],
            &changed(&s_header, 3, 4),
            "rejected_auth",
            &[],
        ),
        rx(
            "wrong_receiver",
            "header_only with receiver 3: refused before anything is decrypted.",
            r,
            &[],
            &changed(&s_header, 6, 3),
            "rejected_table",
            &[],
        ),
        rx(
            "unknown_sender",
            "header_only with sender 9, a system without a public key here.",
            r,
            &[],
            &changed(&s_header, 4, 9),
            "rejected_unknown_sender",
            &[],
        ),
        rx(
            "unknown_session",
            "header_only with session index 3, which the receiver does not have.",
            r,
            &[],
            &changed(&s_header, 8, 3),
            "rejected_no_session",
            &[],
        ),
        rx(
            "flipped_counter",
            "header_only with the lowest counter bit flipped (the clear bytes are the \
             associated data).",
            r,
            &[],
            &flipped(&s_header, 12),
            "rejected_auth",
            &[],
        ),
        rx(
            "flipped_ciphertext",
            "header_only with the first ciphertext byte flipped.",
            r,
            &[],
            &flipped(&s_header, DATA_HEADER_LEN),
            "rejected_auth",
            &[],
        ),
        rx(
            "flipped_tag",
            "header_only with the last tag byte flipped.",
            r,
            &[],
            &flipped(&s_header, s_header.len() - 1),
            "rejected_auth",
            &[],
        ),
        rx(
            "truncated",
            "The first 35 bytes of empty: shorter than the 36 bytes of any data frame.",
            r,
            &[],
            &s_empty[..35],
            "rejected_auth",
            &[],
        ),
        rx(
            "replayed",
            "header_only again after it was accepted.",
            r,
            &["header_only"],
            &s_header,
            "rejected_replay",
            &[],
        ),
        rx(
            "replayed_older",
            "header_only again after it and two newer frames were accepted.",
            r,
            &["header_only", "header_and_payload", "large"],
            &s_header,
            "rejected_replay",
            &[],
        ),
        rx(
            "reflected",
            "ack_back turned back to system 2: sender and receiver swapped and system 2's own \
             session index, so it reaches authentication, where system 2's key for frames from \
             system 1 does not open it.",
            r,
            &[],
            &{
                let mut f = changed(&s_ack, 4, i as u8);
                f[6] = r as u8;
                f[8] = 2;
                f
            },
            "rejected_auth",
            &[],
        ),
        rx(
            "spoofed_inner_source",
            "",
            r,
            &[],
            &s_spoofed_source,
            "rejected_table",
            &[],
        ),
        rx(
            "other_inner_destination",
            "",
            r,
            &[],
            &s_other_destination,
            "rejected_table",
            &[],
        ),
        rx(
            "ack_from_initiator",
            "",
            r,
            &[],
            &s_ack_not_allowed,
            "rejected_table",
            &[],
        ),
        rx(
            "data_from_responder",
            "",
            i,
            &[],
            &s_data_not_allowed,
            "rejected_table",
            &[],
        ),
    ];

    let description_of = |name: &str| -> String {
        sealed
            .iter()
            .find(|s| s.name == name)
            .map(|s| s.description.clone())
            .unwrap_or_default()
    };
    let received = received
        .into_iter()
        .map(|mut v| {
            if v.description.is_empty() {
                let of = v.name.trim_start_matches("accept_");
                v.description = description_of(of);
            }
            v
        })
        .collect();

    Section {
        description: "Secured frames between systems 1 and 2 (docs/wire-format.md, \"Secured \
                      frames\"): their fixed key pairs, the Noise KK handshake a simulation with \
                      seed 2026 makes for them, its split keys, frames sealed in that session, \
                      and what a receiver holding it does with each frame of `received`",
        noise_protocol: NOISE_PARAMS,
        systems: systems_json(&[INITIATOR, RESPONDER]),
        handshake: Handshake {
            initiator: i,
            responder: r,
            prologue_hex: hex(&prologue()),
            initiator_index: 1,
            responder_index: 2,
            timestamp: 1,
            initiator_seed: si,
            responder_seed: sr,
            initiator_ephemeral_private_hex: hex(&ephemeral(si)),
            responder_ephemeral_private_hex: hex(&ephemeral(sr)),
            initiation_hex: hex(&made.initiation),
            response_hex: hex(&made.response),
            handshake_hash_hex: hex(&hash),
            key_initiator_to_responder_hex: hex(&k1),
            key_responder_to_initiator_hex: hex(&k2),
        },
        receivers: vec![
            Receiver {
                system: r,
                peers: vec![i],
                data_from: vec![i],
                acks_from: vec![],
            },
            Receiver {
                system: i,
                peers: vec![r],
                data_from: vec![],
                acks_from: vec![r],
            },
        ],
        sealed,
        received,
    }
}

fn rx(
    name: &str,
    description: &str,
    receiver: u16,
    before: &[&str],
    secured: &[u8],
    verdict: &'static str,
    inner: &[u8],
) -> Received {
    Received {
        name: name.into(),
        description: description.into(),
        receiver,
        before: before.iter().map(|s| s.to_string()).collect(),
        secured_hex: hex(secured),
        verdict,
        inner_hex: hex(inner),
    }
}

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
        key.seal(
            &mut out,
            ids,
            n(v, "session_index") as u32,
            counter,
            &inner,
            &[],
        );
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
    let sink = layer.wrap_sink(&ctx, up.clone());
    let link = layer.wrap_link(&ctx, Arc::new(NullLink)).expect("wraps");
    (up, link, sink)
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
                assert_eq!(new, [&unhex(s(v, "inner_hex"))[..]], "{name}");
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

//! The generator of the `secured_frames` section: everything in it comes from the real code
//! (`session::initiate` / `respond` / `complete`, `Session::seal`) and, for the split keys and
//! the handshake hash, from `snow` run with the ephemeral keys the seeded randomness gives.

use std::path::PathBuf;

use hetcomm_core::wire;
use hetcomm_core::{
    payload, AckStatus, Address, FrameKind, Header, MessageType, ModuleId, Priority, SystemId, Time,
};
use hetcomm_security::envelope::{DATA_HEADER_LEN, NOISE_PARAMS};
use hetcomm_security::session::{self, Entropy, Session};
use hetcomm_security::{Keypair, PrivateKey};
use rand::{RngCore, SeedableRng};
use serde::Serialize;

/// The seed of the simulation whose session between systems 1 and 2 the vectors use.
pub const SIM_SEED: u64 = 2026;
pub const INITIATOR: SystemId = SystemId(1);
pub const RESPONDER: SystemId = SystemId(2);
/// What introduces the section in the file (it is the file's last key).
pub const MARKER: &str = ",\n  \"secured_frames\": ";

pub fn vectors_path() -> PathBuf {
    PathBuf::from(env!("CARGO_MANIFEST_DIR")).join("../../docs/wire-vectors.json")
}

pub fn hex(bytes: &[u8]) -> String {
    bytes.iter().map(|b| format!("{b:02x}")).collect()
}

pub fn unhex(s: &str) -> Vec<u8> {
    assert!(s.len().is_multiple_of(2), "odd hex length");
    (0..s.len())
        .step_by(2)
        .map(|i| u8::from_str_radix(&s[i..i + 2], 16).expect("hex"))
        .collect()
}

/// The fixed key pair of system `id`: private key bytes `32 * (id - 1)`, `+ 1`, …, `+ 31`.
pub fn keypair(id: SystemId) -> Keypair {
    let first = 32 * (id.0 as u8 - 1);
    Keypair::from_private(PrivateKey(std::array::from_fn(|i| first + i as u8)))
        .expect("X25519 takes any 32 bytes")
}

/// The randomness `SimSessions` gives the handshake between systems 1 and 2 (initiator, lower
/// id first): `Entropy::Seeded` of these.
pub fn pair_seeds() -> (u64, u64) {
    let pair = SIM_SEED ^ ((INITIATOR.0 as u64) << 16) ^ ((RESPONDER.0 as u64) << 32);
    (pair, pair ^ 0x5eed)
}

/// The first 32 bytes of a seeded generator: the ephemeral private key it gives.
pub fn ephemeral(seed: u64) -> [u8; 32] {
    let mut e = [0; 32];
    rand_chacha::ChaCha20Rng::seed_from_u64(seed).fill_bytes(&mut e);
    e
}

pub fn prologue() -> Vec<u8> {
    let mut p = b"hetcomm-secure-v1".to_vec();
    p.extend_from_slice(&INITIATOR.0.to_le_bytes());
    p.extend_from_slice(&RESPONDER.0.to_le_bytes());
    p
}

pub fn addr(system: u16, module: u16) -> Address {
    Address {
        system: SystemId(system),
        module: ModuleId(module),
    }
}

/// A data frame from module 2 of `source` to module 4 of `destination`.
pub fn data_header(source: u16, destination: u16, seq: u64) -> Header {
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

pub fn ack_of(data: &Header) -> Header {
    Header {
        kind: FrameKind::Ack,
        flags: 0,
        source: data.destination,
        destination: data.source,
        ..*data
    }
}

pub fn systems_json(ids: &[SystemId]) -> Vec<SystemKeys> {
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
pub struct SystemKeys {
    system: u16,
    private_key_hex: String,
    public_key_hex: String,
    public_key_base64: String,
}

#[derive(Serialize)]
pub struct Handshake {
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
pub struct Receiver {
    system: u16,
    peers: Vec<u16>,
    data_from: Vec<u16>,
    acks_from: Vec<u16>,
}

/// A frame sealed by the sender of one direction.
#[derive(Serialize)]
pub struct Sealed {
    name: String,
    description: String,
    sender: u16,
    receiver: u16,
    /// "initiator_to_responder" or "responder_to_initiator".
    key: &'static str,
    /// 3 (a data message) or 4 (a data batch: `inner_hex` is then its records).
    #[serde(rename = "type")]
    kind: u8,
    session_index: u32,
    counter: u64,
    nonce_hex: String,
    inner_hex: String,
    secured_hex: String,
}

/// A frame arriving at a receiver, and what the receiver does with it.
#[derive(Serialize)]
pub struct Received {
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
pub struct Section {
    description: &'static str,
    noise_protocol: &'static str,
    systems: Vec<SystemKeys>,
    handshake: Handshake,
    receivers: Vec<Receiver>,
    sealed: Vec<Sealed>,
    received: Vec<Received>,
}

/// Both sides' sessions from the vector handshake, made by the real code.
pub struct Made {
    pub initiation: Vec<u8>,
    pub response: Vec<u8>,
    pub initiator: Session,
    pub responder: Session,
}

pub fn handshake() -> Made {
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

/// What [`snow_handshake`] gives: (initiation's Noise message, response's Noise message,
/// handshake hash, key initiator→responder, key responder→initiator).
pub type SnowHandshake = (Vec<u8>, Vec<u8>, Vec<u8>, [u8; 32], [u8; 32]);

/// The handshake as `snow` runs it with the stated ephemeral keys.
pub fn snow_handshake() -> SnowHandshake {
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

pub fn nonce(counter: u64) -> [u8; 12] {
    let mut n = [0; 12];
    n[4..].copy_from_slice(&counter.to_le_bytes());
    n
}

/// Builds the section from the real code.
pub fn section() -> Section {
    let made = handshake();
    let (_, _, hash, k1, k2) = snow_handshake();
    let (si, sr) = pair_seeds();
    let (i, r) = (INITIATOR.0, RESPONDER.0);

    let mut sealed = Vec::new();
    // A data message, or with `batch` a data batch whose records are `inner`.
    let mut seal_kind =
        |name: &str, description: &str, forward: bool, inner: &[u8], batch: bool| -> Vec<u8> {
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
            if batch {
                session.seal_batch(&mut out, from, to, inner);
            } else {
                session.seal(&mut out, from, to, inner, &[]);
            }
            let counter = u64::from_le_bytes(out[12..20].try_into().expect("8 bytes"));
            sealed.push(Sealed {
                name: name.into(),
                description: description.into(),
                sender: from.0,
                receiver: to.0,
                key,
                kind: out[3],
                session_index: session.peer_index,
                counter,
                nonce_hex: hex(&nonce(counter)),
                inner_hex: hex(inner),
                secured_hex: hex(&out),
            });
            out
        };
    let mut seal = |name: &str, description: &str, forward: bool, inner: &[u8]| {
        seal_kind(name, description, forward, inner, false)
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
    let batch_frames = [
        wire::encode(&data_header(i, r, 10), &[]),
        wire::encode(&data_header(i, r, 11), &[0x5a; 7]),
    ];
    let mut records = Vec::new();
    for f in &batch_frames {
        hetcomm_security::envelope::push_record(&mut records, f, &[]);
    }
    let s_batch = seal_kind(
        "batch",
        "A data batch (type 4) of two data frames, sealed once (counter 7): the first of 48 \
         bytes, the second with a 7-byte payload, each behind its length (u32 little-endian).",
        true,
        &records,
        true,
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
            "header_only with type 5.",
            r,
            &[],
            &changed(&s_header, 3, 5),
            "rejected_auth",
            &[],
        ),
        rx(
            "data_as_batch",
            "header_only with type 4 (a data batch): the type is authenticated.",
            r,
            &[],
            &changed(&s_header, 3, 4),
            "rejected_auth",
            &[],
        ),
        rx(
            "accept_batch",
            "Both frames of the batch are handed up (inner_hex: the two, one after the other).",
            r,
            &[],
            &s_batch,
            "handed_up",
            &batch_frames.concat(),
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

pub fn rx(
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
